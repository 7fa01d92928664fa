"""The registry of task-level baselines: methods that return obstacle boxes without a SOM.

A task baseline is a function ``fn(disparity, valid, camera=None) -> list[Obstacle]`` that returns
its detections **best first**: the runners (``experiments.real_scenes``, ``experiments.validate``,
``experiments.study``) keep the first box, reduce the map around it with the pipeline's tolerance
(:func:`~somtorch.tasks.reduction.reduce_map`) and score it like a SOM member. An empty list means
"nothing found": the runners then keep the whole map and flag the run ``no_object``, as the
pipeline's fail-safe does.

Register a new baseline once, where it is implemented::

    from somtorch.tasks.baselines import Obstacle, register_task_baseline

    def my_boxes(disparity, valid, camera=None):
        ...
        return [Obstacle(box=(x0, y0, x1, y1), disparity=d_med, pixels=n)]

    register_task_baseline("mine", my_boxes, needs_camera=False, deterministic=True)

``needs_camera=True``: the baseline needs a metric camera (a :class:`~somtorch.disparity.camera.Camera`
whose baseline is in m or mm); where a scene has none, the runners skip it (a logged line, no row).
``deterministic=False``: the result may change from one call to the next (e.g. a network on a GPU);
the runners still run it once per frame, and the rows say ``deterministic: false``.
``left_out=fn_of(camera)``: a trained baseline's fold without a generator camera's frames; the
validation's leave-one-dataset-out uses it for a dataset taken with that camera (:meth:`TaskBaseline.without`).

The built-in baselines (``uv_disparity``, ``dsw``, ``plane_components``, ``plane_components_o3d``,
``learned``) register when :mod:`somtorch.tasks.baselines` is imported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from somtorch.validation import SomtorchError, check_tensor

__all__ = ["TASK_BASELINES", "Box", "Obstacle", "TaskBaseline", "TaskBaselineError", "get_task_baseline",
           "register_task_baseline", "task_baseline_names"]

Box = tuple[int, int, int, int]


class TaskBaselineError(SomtorchError, ValueError):
    """A task baseline cannot run on this input (unknown name, too few valid pixels, no metric camera)."""


@dataclass(frozen=True)
class Obstacle:
    """One baseline detection: its box ``(x0, y0, x1, y1)`` inclusive, median disparity (px) and pixel count."""

    box: Box
    disparity: float
    pixels: int


BaselineFn = Callable[..., list[Obstacle]]


@dataclass(frozen=True)
class TaskBaseline:
    """A registered task baseline (see the module docstring).

    Attributes:
        name: its name in ``methods=`` / ``baselines=``.
        fn: ``fn(disparity, valid, camera=None) -> list[Obstacle]``, best first.
        needs_camera: needs a metric camera; skipped on scenes without one.
        deterministic: the same input always gives the same boxes.
        left_out: for a trained baseline, ``left_out(camera) -> fn``: the function of the model
            trained without that generator camera's frames (the leave-one-dataset-out fold of a
            dataset taken with it); None for a baseline that learns nothing.
        identity: for a trained baseline, ``identity() -> str``: what its function is now (the key
            of the model it loads), part of a study job's config hash so that a job scored with
            another model is run again, not skipped; None for a baseline that is its code.
    """

    name: str
    fn: BaselineFn
    needs_camera: bool = False
    deterministic: bool = True
    left_out: Callable[[str], BaselineFn] | None = None
    identity: Callable[[], str] | None = None

    def without(self, camera: str | None) -> TaskBaseline:
        """The baseline of the fold that leaves out ``camera``'s frames (itself when it learns
        nothing or ``camera`` is None)."""
        if self.left_out is None or camera is None:
            return self
        return TaskBaseline(self.name, self.left_out(camera), self.needs_camera, self.deterministic)

    def applies(self, camera: Any) -> bool:
        """True unless the baseline needs a metric camera and ``camera`` is not one."""
        return not self.needs_camera or (camera is not None and camera.baseline_m is not None)

    def __call__(self, disparity: torch.Tensor, valid: torch.Tensor, camera: Any = None) -> list[Obstacle]:
        """The detections, best first.

        Raises:
            TaskBaselineError: the baseline needs a metric camera and ``camera`` is not one.

        Shape:
            ``disparity`` float ``(H, W)`` in px, ``valid`` bool ``(H, W)``.
        """
        if not self.applies(camera):
            raise TaskBaselineError(f"task baseline {self.name!r} needs a metric camera (baseline in m or mm); "
                                    f"got {camera!r}")
        return self.fn(disparity, valid, camera)


TASK_BASELINES: dict[str, TaskBaseline] = {}


def register_task_baseline(name: str, fn: BaselineFn, *, needs_camera: bool = False,
                           deterministic: bool = True,
                           left_out: Callable[[str], BaselineFn] | None = None,
                           identity: Callable[[], str] | None = None) -> TaskBaseline:
    """Register ``fn`` as the task baseline ``name`` (see the module docstring); returns its entry.

    Raises:
        ValueError: ``name`` is empty, ``"som"`` (the pipeline's name in ``methods=``) or already
            registered with another function.
    """
    if not isinstance(name, str) or not name.isidentifier() or name == "som":
        raise ValueError(f"task baseline name must be an identifier other than 'som'; got {name!r}")
    old = TASK_BASELINES.get(name)
    if old is not None and old.fn is not fn:
        raise ValueError(f"task baseline {name!r} is already registered (by {old.fn.__module__}.{old.fn.__qualname__})")
    entry = TaskBaseline(name, fn, bool(needs_camera), bool(deterministic), left_out, identity)
    TASK_BASELINES[name] = entry
    return entry


def task_baseline_names() -> list[str]:
    """The registered names, in registration order."""
    return list(TASK_BASELINES)


def get_task_baseline(name: str) -> TaskBaseline:
    """The entry of ``name``.

    Raises:
        TaskBaselineError: unknown name; the message lists the registered ones.
    """
    if name not in TASK_BASELINES:
        raise TaskBaselineError(f"unknown task baseline {name!r}; registered: {', '.join(TASK_BASELINES)}")
    return TASK_BASELINES[name]


def map_arrays(disparity: torch.Tensor, valid: torch.Tensor, min_valid: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """``(d, v)`` as float64 / bool numpy arrays, checked (shapes, dtype, at least ``min_valid`` valid pixels).

    Raises:
        TaskBaselineError: fewer than ``min_valid`` finite valid pixels.

    Shape:
        ``disparity``, ``valid`` ``(H, W)``; both outputs ``(H, W)``.
    """
    check_tensor("disparity", disparity, ndim=2)
    check_tensor("valid", valid, ndim=2, dtype=torch.bool)
    if disparity.shape != valid.shape:
        raise ValueError(f"disparity {tuple(disparity.shape)} and valid {tuple(valid.shape)} differ in shape")
    d = disparity.detach().cpu().numpy().astype(np.float64)
    v = valid.detach().cpu().numpy() & np.isfinite(d)
    if v.sum() < min_valid:
        raise TaskBaselineError(f"the map has {int(v.sum())} valid pixels; a baseline needs at least {min_valid}")
    return d, v
