"""Task-level baselines for step 1c: obstacle boxes without a SOM, one registry for all of them.

* :mod:`.registry` — :func:`register_task_baseline`, :data:`TASK_BASELINES`, :class:`Obstacle`;
* :mod:`.classical` — ``uv_disparity`` (Labayrade et al. 2002) and ``dsw`` (Müller et al. 2018);
* :mod:`.plane_components` — ``plane_components`` (issue 31: the support plane, then depth-connected
  components) and its Open3D route ``plane_components_o3d``;
* :mod:`.learned` — ``learned`` (issue 32: a small U-Net trained on generated frames only).

Importing this package registers the built-in baselines.
"""

from __future__ import annotations

from .registry import (TASK_BASELINES, Obstacle, TaskBaseline, TaskBaselineError, get_task_baseline,
                       register_task_baseline, task_baseline_names)
from .classical import dsw_boxes, uv_disparity_boxes  # noqa: E402  (registers uv_disparity, dsw)
from .plane_components import (PlaneComponentsParams, plane_components_boxes,  # noqa: E402  (registers both)
                               plane_components_o3d_boxes)
from .learned import learned_boxes  # noqa: E402  (registers learned)

__all__ = ["TASK_BASELINES", "Obstacle", "PlaneComponentsParams", "TaskBaseline", "TaskBaselineError", "dsw_boxes",
           "get_task_baseline", "learned_boxes", "plane_components_boxes", "plane_components_o3d_boxes", "register_task_baseline",
           "task_baseline_names", "uv_disparity_boxes"]
