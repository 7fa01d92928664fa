"""An object's place and size in 3-D (``somtorch.geometry.extent``) on scenes rendered exactly for a
pinhole stereo camera: a square facing the camera, a floor seen from above with a box on it; and the
same read from a pipeline run (``somtorch.outputs.object_extents``, metrics.json's point-cloud
entry)."""

from __future__ import annotations

import math

import pytest
import torch

from somtorch.config import PipelineConfig
from somtorch.disparity.camera import Camera
from somtorch.disparity.scene import scene_from_arrays
from somtorch.geometry import disparity_plane_3d, object_extent
from somtorch.outputs import object_extents
from somtorch.pipeline import run_pipeline
from somtorch.tasks.ground import fit_ground_plane
from tests.tasks.test_ground_pitch import BASELINE_M, FOCAL_PX, HEIGHT_M, H, W, exact_plane, render

F, B = FOCAL_PX, BASELINE_M  # focal length (px), baseline (m)
CX, CY = (W - 1) / 2, (H - 1) / 2
BOX = (-0.15, 0.15, 0.55, 0.85, 0.25)  # (x0, x1, z0, z1, tall), metres: a box 25 cm tall


def floor_with_box(pitch_deg: float, box: tuple[float, float, float, float, float]):
    """The ground-pitch tests' exact floor (``HEIGHT_M`` below the camera, pitched down by
    ``pitch_deg``; their camera: ``FOCAL_PX``, ``BASELINE_M``, principal point at the centre) with
    the box ``(x0, x1, z0, z1, tall)`` standing on it: ``(disparity, valid, box pixels)``."""
    d, valid, objects = render(pitch_deg, [box])
    return d, valid, objects == 1


def floor_plane(pitch_deg: float) -> tuple[float, float, float]:
    """That floor's exact plane (a, b, c) in (x, y, d)."""
    b, c = exact_plane(pitch_deg)
    return 0.0, b, c


def test_a_square_facing_the_camera_reads_its_size_and_depth():
    d = torch.full((H, W), F * B / 4.0)  # a wall 4 m away
    ys, xs = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    square = ((xs - CX).abs() < 45) & ((ys - CY).abs() < 45)  # 90 × 90 px about the centre, 2 m away
    d[square] = F * B / 2.0
    ext = object_extent(d, square, focal_px=F, cx=CX, cy=CY, baseline=B, percentiles=(0.0, 100.0))
    assert ext.points == 90 * 90
    assert ext.centroid == pytest.approx((0.0, 0.0, 2.0), abs=1e-6)  # (a float32 map)
    assert ext.size == pytest.approx((89 * 2.0 / F, 89 * 2.0 / F, 0.0), abs=1e-6)
    # by default the extent is read between the 2nd and 98th percentiles: 96 % of a uniform side
    robust = object_extent(d, square, focal_px=F, cx=CX, cy=CY, baseline=B)
    assert robust.size[0] == pytest.approx(0.96 * ext.size[0], rel=0.02)
    assert robust.height is None


def test_a_few_stray_pixels_do_not_stretch_the_robust_extent():
    d = torch.full((H, W), F * B / 2.0)
    obj = torch.zeros(H, W, dtype=torch.bool)
    obj[40:120, 50:150] = True
    d[40, 50] = F * B / 0.5  # one stray match at 0.5 m instead of 2 m (an occluding edge's mismatch)
    exact = object_extent(d, obj, focal_px=F, cx=CX, cy=CY, baseline=B, percentiles=(0.0, 100.0))
    robust = object_extent(d, obj, focal_px=F, cx=CX, cy=CY, baseline=B)
    assert exact.size[2] == pytest.approx(1.5)
    assert robust.size[2] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("pitch", [30.0, 60.0, 90.0])
def test_a_disparity_plane_is_the_3d_plane_of_the_floor_it_was_fitted_to(pitch):
    th = math.radians(pitch)
    n, k = disparity_plane_3d(floor_plane(pitch), focal_px=F, cx=CX, cy=CY, baseline=B)
    assert n == pytest.approx((0.0, math.cos(th), math.sin(th)), abs=1e-12)  # the floor's up, camera frame
    assert k == pytest.approx(HEIGHT_M, rel=1e-12)  # the camera's height above it


def test_a_box_on_the_floor_reads_its_height_above_the_ground_plane():
    d, valid, box = floor_with_box(50.0, BOX)
    ext = object_extent(d, box, focal_px=F, cx=CX, cy=CY, baseline=B, plane=floor_plane(50.0))
    assert ext.height == pytest.approx(0.25, abs=1e-3)  # its top face, seen from above
    fitted = fit_ground_plane(d, valid)  # the pipeline's plane, fitted to the float32 map
    assert fitted is not None
    ext = object_extent(d, box, focal_px=F, cx=CX, cy=CY, baseline=B, plane=(fitted.a, fitted.b, fitted.c))
    assert ext.height == pytest.approx(0.25, rel=0.02)


def test_a_pipeline_run_reports_each_kept_area_in_3d():
    d, valid, box = floor_with_box(50.0, BOX)
    scene = scene_from_arrays(d, valid, objects=box.long(),
                              camera=Camera(focal_px=F, cx=CX, cy=CY, baseline=B, baseline_unit="m"), name="box")
    result = run_pipeline(scene, PipelineConfig(), metrics=False)
    assert result.ground is not None and result.members[0].kept
    got = object_extents(scene, result)
    assert len(got) == len(result.members[0].kept)
    main = got[0]
    assert main["unit"] == "m"
    assert main["height_above_plane"] == pytest.approx(0.25, rel=0.05)
    truth = object_extent(d, box, focal_px=F, cx=CX, cy=CY, baseline=B)
    assert main["size_xyz"] == pytest.approx(list(truth.size), rel=0.1, abs=0.01)
    assert main["centroid_xyz"] == pytest.approx(list(truth.centroid), abs=0.02)
    # without a camera there is nothing to measure in 3-D
    bare = scene_from_arrays(d, valid, name="bare")
    assert object_extents(bare, run_pipeline(bare, PipelineConfig(), metrics=False)) == []


def test_bad_input_is_named():
    d = torch.full((H, W), 10.0)
    with pytest.raises(ValueError, match="mask must have the shape of disparity"):
        object_extent(d, torch.ones(H, W + 1, dtype=torch.bool), focal_px=F, cx=CX, cy=CY, baseline=B)
    with pytest.raises(ValueError, match="percentiles"):
        object_extent(d, torch.ones(H, W, dtype=torch.bool), focal_px=F, cx=CX, cy=CY, baseline=B,
                      percentiles=(98.0, 2.0))
    with pytest.raises(ValueError, match="at infinity"):
        disparity_plane_3d((0.0, 0.0, 0.0), focal_px=F, cx=CX, cy=CY, baseline=B)
    nothing = torch.zeros(H, W, dtype=torch.bool)
    assert object_extent(d, nothing, focal_px=F, cx=CX, cy=CY, baseline=B) is None
