"""The u-v-disparity and DSW baselines on synthetic maps whose obstacle is known."""

from __future__ import annotations

import pytest
import torch

from somtorch.tasks.baselines import dsw_boxes, uv_disparity_boxes


def _street(h=120, w=160, d_obj=40.0):
    """A ground plane (disparity rising down the image from the horizon), a far wall at the
    horizon and one box obstacle standing on the ground."""
    rows = torch.arange(h, dtype=torch.float32)[:, None].expand(h, w)
    horizon = 40
    d = torch.where(rows > horizon, (rows - horizon) * 0.6, torch.full_like(rows, 2.0))
    d = d.clone()
    y0, y1, x0, x1 = 50, 95, 60, 100  # the obstacle's foot is at row 95: ground d there = 33
    d[y0:y1 + 1, x0:x1 + 1] = d_obj
    valid = torch.ones(h, w, dtype=torch.bool)
    return d, valid, (x0, y0, x1, y1)


def _iou(a, b):
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0]) + 1)
    iy = max(0, min(a[3], b[3]) - max(a[1], b[1]) + 1)
    inter = ix * iy
    area = lambda r: (r[2] - r[0] + 1) * (r[3] - r[1] + 1)  # noqa: E731
    return inter / (area(a) + area(b) - inter)


def test_uv_disparity_finds_the_obstacle_and_not_the_ground():
    d, valid, truth = _street()
    found = uv_disparity_boxes(d, valid)
    assert found, "no obstacle found"
    best = max(found, key=lambda o: o.pixels * o.disparity)
    assert _iou(best.box, truth) > 0.8, (best, truth)
    assert best.disparity == pytest.approx(40.0)
    # the ground is never an obstacle: no detection reaches the bottom rows outside the box columns
    assert all(not (o.box[3] >= 110 and o.box[0] < 50) for o in found)


def test_dsw_seeds_on_the_nearest_object_sized_window():
    d, valid, truth = _street()
    found = dsw_boxes(d, valid, baseline=0.25, sizes=(0.25,))  # 0.25 m at d = 40, B = 0.25 m: 40 px
    assert found and found[0].disparity == pytest.approx(40.0, abs=2.0)
    assert _iou(found[0].box, truth) > 0.8, (found[0], truth)
    assert [o.disparity for o in found] == sorted((o.disparity for o in found), reverse=True)


def test_baselines_are_deterministic_and_check_inputs():
    d, valid, _ = _street()
    assert uv_disparity_boxes(d, valid) == uv_disparity_boxes(d.clone(), valid.clone())
    with pytest.raises(ValueError, match="valid pixels"):
        uv_disparity_boxes(d, torch.zeros_like(valid))
    with pytest.raises(ValueError, match="shape"):
        dsw_boxes(d, valid[:10], baseline=0.1)
    with pytest.raises(ValueError, match="baseline"):
        dsw_boxes(d, valid, baseline=0.0)


def test_registry_serves_the_builtins_best_first():
    from somtorch.disparity.camera import Camera
    from somtorch.tasks.baselines import get_task_baseline, task_baseline_names

    assert {"uv_disparity", "dsw"} <= set(task_baseline_names())
    d, valid, truth = _street()
    uv = get_task_baseline("uv_disparity")
    assert uv.deterministic and not uv.needs_camera and uv.applies(None)
    first = uv(d, valid)[0]  # the registry's order: most pixels x disparity first
    assert _iou(first.box, truth) > 0.8
    dsw = get_task_baseline("dsw")
    assert dsw.needs_camera and not dsw.applies(None)
    assert not dsw.applies(Camera(focal_px=100.0, cx=80.0, cy=60.0, baseline=1.0, baseline_unit="unit"))
    metric = Camera(focal_px=100.0, cx=80.0, cy=60.0, baseline=250.0, baseline_unit="mm")
    assert dsw(d, valid, metric)[0].disparity == pytest.approx(40.0, abs=2.0)
    with pytest.raises(ValueError, match="metric camera"):
        dsw(d, valid)


def test_registry_errors_name_the_valid_choices():
    from somtorch.tasks.baselines import (TASK_BASELINES, TaskBaselineError, get_task_baseline,
                                          register_task_baseline)

    with pytest.raises(TaskBaselineError, match="hough.*uv_disparity.*dsw"):
        get_task_baseline("hough")
    with pytest.raises(ValueError, match="already registered"):
        register_task_baseline("uv_disparity", lambda d, v, camera=None: [])
    with pytest.raises(ValueError, match="identifier"):
        register_task_baseline("som", lambda d, v, camera=None: [])

    def whole(d, v, camera=None):
        return []

    try:
        entry = register_task_baseline("test_whole_map", whole, deterministic=False)
        assert get_task_baseline("test_whole_map") is entry and not entry.deterministic
        assert entry(*_street()[:2]) == []
    finally:
        TASK_BASELINES.pop("test_whole_map", None)
