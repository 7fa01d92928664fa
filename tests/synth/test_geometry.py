"""Ray casting against analytic answers: depths, disparities, silhouettes, the stereo warp."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from somtorch.synth.cameras import Pose
from somtorch.synth.geometry import intersect

LEVEL = Pose(0.0, 0.0, 1.0, 0.0)  # horizontal camera at 1 m, looking along +Y (camera z = world Y)


@pytest.mark.parametrize("depth", [0.45, 1.3, 4.0])
def test_fronto_parallel_plane_has_disparity_fB_over_Z(builder, render, textured, depth):
    builder.rect((0.0, depth, 1.0), (50.0, 0.0, 0.0), (0.0, 0.0, 50.0), 0, textured())
    pair, cam, _ = render(builder, LEVEL)
    expected = cam.focal_px * cam.baseline_m / depth
    assert torch.isfinite(pair.disp_left).all()
    torch.testing.assert_close(pair.disp_left, torch.full_like(pair.disp_left, expected), rtol=1e-5, atol=0)
    torch.testing.assert_close(pair.disp_right, torch.full_like(pair.disp_right, expected), rtol=1e-5, atol=0)


@pytest.mark.parametrize("kind", ["sphere", "cylinder", "cone", "box"])
def test_nearest_point_of_each_shape_on_the_optical_axis(builder, textured, kind):
    """The centre pixel's depth is the shape's front at the axis: centre depth minus its radius."""
    zc, r = 2.0, 0.3
    mat = textured()
    if kind == "sphere":
        builder.sphere((0.0, zc, 1.0), r, 1, mat)
        front = zc - r
    elif kind == "cylinder":  # upright: the axis ray hits the side at zc - r
        builder.cylinder(0.0, zc, 0.5, r, 1.0, 1, mat)
        front = zc - r
    elif kind == "cone":  # base at 0.4, apex at 1.6: radius at height 1 is r * (1.6 - 1) / 1.2
        builder.cone(0.0, zc, 0.4, r, 1.2, 1, mat)
        front = zc - r * 0.6 / 1.2
    else:
        builder.box((0.0, zc, 1.0), (0.6, 2 * r, 0.6), 1, mat)
        front = zc - r
    origin = torch.tensor([0.0, 0.0, 1.0])
    rays = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.5], [0.0, -1.0, 0.0]])  # axis; above the top; away
    t = intersect(builder.prims[0], origin, rays)
    assert abs(float(t[0]) - front) < 1e-5 * front
    assert float(t[1]) >= 1e29 and float(t[2]) >= 1e29  # misses


def test_box_instance_mask_is_its_projected_silhouette(builder, render, textured):
    builder.box((0.2, 1.6, 0.9), (0.7, 0.5, 0.4), 1, textured(), yaw=math.radians(33))
    pose = Pose(0.0, 0.0, 1.4, 12.0, 4.0)
    pair, cam, layout = render(builder, pose, 0.5)
    mask = (pair.prim_left == 0).numpy()
    corners = layout.prims[0].corners()  # (8, 3) world
    pc = (corners - pose.centre()) @ pose.rotation()  # camera frame
    uv = np.stack([cam.focal_px * pc[:, 0] / pc[:, 2] + cam.cx, cam.focal_px * pc[:, 1] / pc[:, 2] + cam.cy], 1)
    hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
    drawn = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(drawn, hull, 1, lineType=cv2.LINE_8, shift=4)
    drawn = drawn.astype(bool)
    iou = (mask & drawn).sum() / (mask | drawn).sum()
    assert mask.sum() > 5000 and iou > 0.97, iou
    kernel, d8 = np.ones((3, 3)), drawn.astype(np.uint8)
    band = cv2.dilate(d8, kernel) & ~cv2.erode(d8, kernel)
    assert not ((mask ^ drawn) & ~band.astype(bool)).any(), "mismatches away from the silhouette's boundary"


def _warp_right_to_left(right: torch.Tensor, disp: torch.Tensor) -> torch.Tensor:
    """Sample the right image at ``x - d`` (bilinear), ``(H, W, C)``."""
    h, w, _ = right.shape
    xs = torch.arange(w, dtype=torch.float32)[None, :] - torch.where(torch.isfinite(disp), disp, 0)
    x0 = xs.floor().clamp(0, w - 2).long()
    a = (xs - x0).clamp(0, 1)[..., None]
    rows = torch.arange(h)[:, None].expand(h, w)
    return right[rows, x0] * (1 - a) + right[rows, x0 + 1] * a


def test_right_view_warped_by_gt_disparity_matches_left(builder, render, textured):
    builder.ground(textured(1, 0.6))
    for i, (x, y) in enumerate([(-0.4, 1.6), (0.3, 2.2), (0.0, 1.2)]):
        builder.box_on(x, y, 0.0, (0.3, 0.3, 0.5 + 0.2 * i), i + 1, textured(2 + i), yaw=0.3 * i)
    pair, cam, _ = render(builder, Pose(0.0, 0.0, 0.9, 20.0), 0.5)
    d = pair.disp_left
    h, w = d.shape
    xr = torch.arange(w)[None, :] - torch.where(torch.isfinite(d), d, 0)
    inside = torch.isfinite(d) & (xr >= 0) & (xr <= w - 2)
    # unoccluded: the right view's GT disparity at x - d agrees (left-right consistency of the GT)
    back = pair.disp_right[torch.arange(h)[:, None].expand(h, w), xr.round().clamp(0, w - 1).long()]
    visible = inside & ((back - d).abs() < 0.5)
    assert visible.float().mean() > 0.8
    warped = _warp_right_to_left(pair.rgb_right, d)
    err = (warped - pair.rgb_left).abs().amax(-1)[visible]
    assert float(err.median()) < 0.01 and float(err.quantile(0.9)) < 0.04
    # and the check can fail: shifting by one extra pixel breaks it
    off = (_warp_right_to_left(pair.rgb_right, d + 1.0) - pair.rgb_left).abs().amax(-1)[visible]
    assert float(off.median()) > 2 * float(err.median()) + 0.005


@pytest.mark.parametrize("kind", ["cylinder", "cone"])
def test_normals_of_sides_and_caps(builder, textured, kind):
    """Side at half height: horizontal (cylinder) or tilted up by the half angle (cone); bottom cap: -Z."""
    from somtorch.synth.geometry import to_local, unit_normal

    (builder.cylinder if kind == "cylinder" else builder.cone)(0.0, 2.0, 0.0, 0.3, 1.0, 1, textured())
    prim = builder.prims[0]

    def normal_at(origin, direction):
        o, d = torch.tensor(origin), torch.tensor([direction])
        t = intersect(prim, o, d)
        return t, unit_normal(prim, to_local(prim, o + t[:, None] * d, d)[0])[0]

    _, n = normal_at([0.0, 0.0, 0.5], [0.0, 1.0, 0.0])
    tilt = 0.0 if kind == "cylinder" else math.atan(0.3)  # cone: radius 0.3 over height 1
    torch.testing.assert_close(n, torch.tensor([0.0, -math.cos(tilt), math.sin(tilt)]), atol=1e-5, rtol=0)
    t, n = normal_at([0.05, 2.05, -1.0], [0.0, 0.0, 1.0])  # from below, looking up at the base
    assert abs(float(t[0]) - 1.0) < 1e-5
    torch.testing.assert_close(n, torch.tensor([0.0, 0.0, -1.0]), atol=1e-5, rtol=0)
