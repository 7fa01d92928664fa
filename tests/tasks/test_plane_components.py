"""The ``plane_components`` baselines (issue 31, item 1) on maps whose answer is known, and on bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from somtorch.disparity.camera import Camera
from somtorch.tasks.baselines import (PlaneComponentsParams, TaskBaselineError, get_task_baseline,
                                      plane_components_boxes, plane_components_o3d_boxes)
from somtorch.tasks.baselines.plane_components import support_plane

H, W = 240, 320
BOX = (100, 60, 179, 149)  # x0, y0, x1, y1 of the box standing on the plane


def _grid():
    return torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")


def _box_on_tilted_plane():
    """A ground plane tilted in both image directions (d rises down the image and to the right) and a
    box of constant disparity standing on it, nearer than the ground behind it."""
    ys, xs = _grid()
    d = 10.0 + 0.12 * ys + 0.02 * xs
    x0, y0, x1, y1 = BOX
    d[y0:y1 + 1, x0:x1 + 1] = 45.0
    return d.float(), torch.ones(H, W, dtype=torch.bool)


def test_a_box_on_a_tilted_plane_is_the_box():
    d, v = _box_on_tilted_plane()
    plane, coef = support_plane(d.double().numpy(), v.numpy())
    assert plane is not None and coef == pytest.approx((0.02, 0.12, 10.0), abs=1e-3)
    assert plane.sum() == H * W - (BOX[2] - BOX[0] + 1) * (BOX[3] - BOX[1] + 1)  # every ground pixel, no box pixel
    found = plane_components_boxes(d, v)
    assert [o.box for o in found] == [BOX]
    assert found[0].disparity == pytest.approx(45.0) and found[0].pixels == 80 * 90


def test_without_a_plane_the_components_are_ranked_by_pixels_times_disparity():
    # six fronto-parallel blobs on an invalid background: each holds 1/6 < 20 % of the valid pixels
    d = torch.zeros(H, W)
    v = torch.zeros(H, W, dtype=torch.bool)
    # (disparities far apart: no tilted plane's band of 0.5 px crosses enough of three blobs to hold 20 %)
    blobs = [((10, 10, 59, 59), 8.0), ((100, 10, 149, 59), 40.0), ((200, 10, 249, 59), 16.0),
             ((10, 120, 59, 169), 64.0), ((100, 120, 149, 169), 24.0), ((200, 120, 249, 169), 32.0)]
    for (x0, y0, x1, y1), disp in blobs:
        d[y0:y1 + 1, x0:x1 + 1] = disp
        v[y0:y1 + 1, x0:x1 + 1] = True
    assert support_plane(d.double().numpy(), v.numpy())[0] is None
    found = plane_components_boxes(d, v)
    assert [o.box for o in found] == [b for b, _ in sorted(blobs, key=lambda t: -t[1])]  # equal sizes: nearest first


def test_a_depth_step_splits_what_touches_and_a_smooth_slope_does_not():
    # two touching fronto-parallel halves 3 px apart (3 > max(1, 5 % of 21.5)): two components; a
    # smooth non-planar ramp (steps under 0.3 px) beside them, > 10 px away in depth, is one
    ys, xs = _grid()
    d = 40.0 + 6.0 * torch.sin(xs / 20.0)  # smooth, not a plane: no band of 0.5 px holds 20 %
    d[:, :100] = 20.0
    d[:120, :100] = 23.0
    d = d.float()
    v = torch.ones(H, W, dtype=torch.bool)
    boxes = {o.box for o in plane_components_boxes(d, v, params=PlaneComponentsParams(plane_min_share=1.0))}
    assert {(0, 0, 99, 119), (0, 120, 99, 239), (100, 0, 319, 239)} == boxes


def test_one_component_covering_everything_is_flagged_empty():
    ys, xs = _grid()
    bowl = (20.0 + 0.0004 * ((xs - 160) ** 2 + (ys - 120) ** 2)).float()  # smooth, curved: no plane, one piece
    v = torch.ones(H, W, dtype=torch.bool)
    assert support_plane(bowl.double().numpy(), v.numpy())[0] is None
    assert plane_components_boxes(bowl, v) == []  # the whole map: nothing to point at


@pytest.mark.parametrize("kind", ["streaky_sgbm", "smooth_8bit"])
def test_hard_maps_never_crash(kind):
    d, v = _box_on_tilted_plane()
    g = torch.Generator().manual_seed(0)
    if kind == "streaky_sgbm":  # horizontal streaks of invalid pixels and speckle noise, as SGBM leaves
        v = v & (torch.rand(H, 1, generator=g) > 0.3) & (torch.rand(H, W, generator=g) > 0.4)
        d = d + 3.0 * (torch.rand(H, W, generator=g) > 0.95)
    else:  # depth saved as 8 bits: blurred, quantised to 1/255 of the range
        k = torch.ones(1, 1, 9, 9) / 81.0
        d = torch.nn.functional.conv2d(d[None, None], k, padding=4)[0, 0]
        d = torch.round((d - d.min()) / (d.max() - d.min()) * 255.0) / 255.0 * 50.0
    found = plane_components_boxes(d, v)
    assert isinstance(found, list)
    for o in found:
        assert 0 <= o.box[0] <= o.box[2] < W and 0 <= o.box[1] <= o.box[3] < H and o.pixels > 0
    assert [o.pixels * o.disparity for o in found] == sorted((o.pixels * o.disparity for o in found), reverse=True)


def test_bad_input_is_a_clear_error():
    d, v = _box_on_tilted_plane()
    with pytest.raises(TaskBaselineError, match="0 valid pixels"):
        plane_components_boxes(d, torch.zeros_like(v))
    with pytest.raises(TaskBaselineError, match="valid pixels"):
        plane_components_boxes(torch.full((H, W), math.nan), v)
    with pytest.raises(ValueError, match="shape"):
        plane_components_boxes(d, v[:10])


def test_deterministic_to_the_byte():
    d, v = _box_on_tilted_plane()
    d = d + 0.3 * torch.rand(H, W, generator=torch.Generator().manual_seed(1))  # RANSAC has ties to break
    a = plane_components_boxes(d, v)
    b = get_task_baseline("plane_components")(d.clone(), v.clone())
    assert a == b and get_task_baseline("plane_components").deterministic


CAM = Camera(focal_px=300.0, cx=160.0, cy=120.0, baseline=0.1)


def test_open3d_route_finds_the_box_on_a_metric_camera():
    pytest.importorskip("open3d")
    d, v = _box_on_tilted_plane()
    entry = get_task_baseline("plane_components_o3d")
    assert entry.needs_camera and not entry.applies(None)
    found = entry(d, v, CAM)
    x0, y0, x1, y1 = found[0].box  # the points are a pixel stride apart: the box within one stride
    assert abs(x0 - BOX[0]) <= 1 and abs(y0 - BOX[1]) <= 1 and abs(x1 - BOX[2]) <= 1 and abs(y1 - BOX[3]) <= 1
    assert found[0].disparity == pytest.approx(45.0)
    assert entry(d, v, CAM) == found  # Open3D's RANSAC is seeded
    with pytest.raises(TaskBaselineError, match="metric camera"):
        plane_components_o3d_boxes(d, v, Camera(focal_px=300.0, cx=160.0, cy=120.0, baseline=1.0,
                                                baseline_unit="unit"))


def test_open3d_route_on_a_real_calibrated_scene(shared_data):
    pytest.importorskip("open3d")
    from experiments.datasets import frames, load_frame

    spec, = frames(None, ["motorcycle_q"])
    scene = load_frame(spec, shared_data)
    assert scene.camera is not None and scene.camera.baseline_m is not None
    found = plane_components_o3d_boxes(scene.disparity, scene.valid, scene.camera)
    xy = plane_components_boxes(scene.disparity, scene.valid)
    assert found and xy
    main = scene.main_object_mask.numpy()
    ys, xs = np.nonzero(main)
    for o in (found[0], xy[0]):  # both routes point at the main object's area
        cx, cy = (o.box[0] + o.box[2]) / 2, (o.box[1] + o.box[3]) / 2
        assert xs.min() <= cx <= xs.max() and ys.min() <= cy <= ys.max(), (o, spec.name)
