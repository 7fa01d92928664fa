"""Tests of somtorch.geometry.pointcloud: real kornia, real Open3D, real files."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from somtorch.geometry import (
    PointCloud,
    depth_to_points,
    disparity_to_depth,
    disparity_to_point_cloud,
    intrinsics_matrix,
    read_ply,
    write_ply,
)
from somtorch.validation import DataFileError

F, B, CX, CY = 200.0, 0.1, 29.5, 19.5  # synthetic camera: focal (px), baseline (m), principal point (px)
H, W = 40, 60


def _plane_disparity(alpha: float = 0.0, beta: float = 0.0, gamma: float = 16.0,
                     dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Disparity affine in the pixel coordinates, d = αx + βy + γ: the image of a plane. Shape (H, W)."""
    y, x = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    return alpha * x + beta * y + gamma


def _all_valid() -> torch.Tensor:
    return torch.ones(H, W, dtype=torch.bool)


def _random_cloud(n: int = 500, seed: int = 0, colors: bool = True) -> PointCloud:
    g = torch.Generator().manual_seed(seed)
    pix = torch.stack([torch.randint(0, H, (n,), generator=g), torch.randint(0, W, (n,), generator=g)], dim=1)
    return PointCloud(torch.rand(n, 3, generator=g) * torch.tensor([2.0, 1.0, 5.0]),
                      torch.rand(n, 3, generator=g) if colors else None, pix)


# ---------------------------------------------------------------------------- depth


def test_disparity_to_depth_matches_hand_computed_values():
    d = torch.tensor([[10.0, 20.0, float("nan")], [0.0, -5.0, -6.0]])
    valid = torch.tensor([[True, True, False], [True, True, True]])
    depth, ok = disparity_to_depth(d, valid, focal_px=100.0, baseline=0.5, doffs=5.0)
    # Z = 0.5 * 100 / (d + 5): 50/15, 50/25, (NaN, invalid on input), 50/5, d+doffs = 0 and < 0 → invalid
    assert ok.tolist() == [[True, True, False], [True, False, False]]
    torch.testing.assert_close(depth[ok], torch.tensor([50 / 15, 2.0, 10.0]))
    assert torch.all(depth[~ok] == 0)


def test_disparity_to_depth_batched_keeps_dtype_and_gradients_are_finite():
    d = torch.tensor([[[4.0, 0.0]], [[8.0, 2.0]]], dtype=torch.float64, requires_grad=True)  # (2, 1, 2)
    depth, ok = disparity_to_depth(d, torch.ones(2, 1, 2, dtype=torch.bool), focal_px=10.0, baseline=2.0)
    assert depth.shape == (2, 1, 2) and depth.dtype == torch.float64
    assert ok.tolist() == [[[True, False]], [[True, True]]]
    depth.sum().backward()
    assert torch.isfinite(d.grad).all()
    torch.testing.assert_close(d.grad[0, 0, 0], torch.tensor(-20.0 / 16, dtype=torch.float64))  # -fB/d²
    assert d.grad[0, 0, 1] == 0


def test_intrinsics_matrix():
    K = intrinsics_matrix(100.0, 3.0, 2.0, fy_px=120.0, dtype=torch.float64)
    assert K.dtype == torch.float64
    assert K.tolist() == [[100.0, 0.0, 3.0], [0.0, 120.0, 2.0], [0.0, 0.0, 1.0]]


# ---------------------------------------------------------------------------- unprojection


def test_fronto_parallel_plane_reconstructs_at_fb_over_d_with_expected_extent():
    d = _plane_disparity(gamma=16.0)
    cloud = disparity_to_point_cloud(d, _all_valid(), focal_px=F, cx=CX, cy=CY, baseline=B)
    z = F * B / 16.0
    assert len(cloud) == H * W and cloud.points.dtype == torch.float64
    torch.testing.assert_close(cloud.points[:, 2], torch.full((H * W,), z, dtype=torch.float64))
    x, y = cloud.points[:, 0], cloud.points[:, 1]
    assert float(x.min()) == pytest.approx((0 - CX) * z / F)
    assert float(x.max()) == pytest.approx((W - 1 - CX) * z / F)
    assert float(y.min()) == pytest.approx((0 - CY) * z / F)
    assert float(y.max()) == pytest.approx((H - 1 - CY) * z / F)
    # each point sits on the ray of its own pixel
    px = cloud.pixels.to(torch.float64)
    torch.testing.assert_close(x, (px[:, 1] - CX) * z / F)
    torch.testing.assert_close(y, (px[:, 0] - CY) * z / F)


def test_tilted_plane_stays_planar():
    d = _plane_disparity(alpha=0.08, beta=-0.05, gamma=12.0)  # affine disparity = a plane in space
    cloud = disparity_to_point_cloud(d, _all_valid(), focal_px=F, cx=CX, cy=CY, baseline=B)
    z = cloud.points[:, 2]
    assert float(z.max() - z.min()) > 0.5 * float(z.mean())  # really tilted, not nearly fronto-parallel
    centred = cloud.points - cloud.points.mean(dim=0)
    s = torch.linalg.svdvals(centred)  # plane fit: smallest singular value = residual
    assert float(s[-1] / s[0]) < 1e-10


def test_point_count_equals_valid_count_and_pixels_are_the_valid_ones():
    g = torch.Generator().manual_seed(1)
    valid = torch.rand(H, W, generator=g) > 0.3
    d = _plane_disparity(gamma=10.0, dtype=torch.float32)
    d[~valid] = float("nan")  # values at invalid pixels are never read
    cloud = disparity_to_point_cloud(d, valid, focal_px=F, cx=CX, cy=CY, baseline=B)
    assert len(cloud) == int(valid.sum())
    assert torch.equal(cloud.pixels, valid.nonzero())
    assert cloud.points.dtype == torch.float32 and torch.isfinite(cloud.points).all()


def test_depth_to_points_agrees_with_the_pinhole_formula():
    g = torch.Generator().manual_seed(2)
    depth = 1 + torch.rand(H, W, generator=g, dtype=torch.float64)
    valid = torch.rand(H, W, generator=g) > 0.5
    K = intrinsics_matrix(F, CX, CY, fy_px=1.5 * F, dtype=torch.float64)
    cloud = depth_to_points(depth, valid, K)
    y, x = valid.nonzero().unbind(1)
    z = depth[y, x]
    expected = torch.stack([(x - CX) * z / F, (y - CY) * z / (1.5 * F), z], dim=1)
    torch.testing.assert_close(cloud.points, expected)


def test_colours_come_from_the_right_pixels():
    g = torch.Generator().manual_seed(3)
    image = torch.randint(0, 256, (3, H, W), generator=g, dtype=torch.uint8)
    valid = torch.rand(H, W, generator=g) > 0.5
    cloud = disparity_to_point_cloud(_plane_disparity(dtype=torch.float32), valid, focal_px=F, cx=CX, cy=CY,
                                     baseline=B, image=image)
    y, x = cloud.pixels.unbind(1)
    torch.testing.assert_close(cloud.colors * 255, image[:, y, x].T.float())
    assert cloud.colors.min() >= 0 and cloud.colors.max() <= 1
    # a float image in [0, 1] is taken as is; a grey (H, W) image becomes three equal channels
    grey = torch.rand(H, W, generator=g)
    cloud = disparity_to_point_cloud(_plane_disparity(dtype=torch.float32), valid, focal_px=F, cx=CX, cy=CY,
                                     baseline=B, image=grey)
    torch.testing.assert_close(cloud.colors, grey[y, x].unsqueeze(1).expand(-1, 3))


# ---------------------------------------------------------------------------- PointCloud methods


def test_len_and_nbytes():
    cloud = _random_cloud(100)
    assert len(cloud) == 100 and cloud.nbytes == 100 * 3 * 4 * 2
    assert PointCloud(cloud.points).nbytes == 100 * 3 * 4


def test_voxel_downsample_reduces_keeps_centroid_and_matches_open3d():
    cloud = _random_cloud(3000, seed=4)
    down = cloud.voxel_downsample(0.25)
    assert 0 < len(down) < len(cloud) and down.pixels is None
    # each output point is the mean of its voxel, so the count-weighted centroid is the input centroid
    counts = _voxel_counts(cloud.points, 0.25)
    torch.testing.assert_close((down.points * counts[:, None]).sum(0) / counts.sum(), cloud.points.mean(0))
    torch.testing.assert_close((down.colors * counts[:, None]).sum(0) / counts.sum(), cloud.colors.mean(0))
    # Open3D (same grid anchoring) as the oracle: the same set of points and colours
    ref = cloud.to_open3d().voxel_down_sample(0.25)
    ours = np.concatenate([down.points.numpy(), down.colors.numpy()], axis=1).astype(np.float64)
    theirs = np.concatenate([np.asarray(ref.points), np.asarray(ref.colors)], axis=1)
    assert ours.shape == theirs.shape
    np.testing.assert_allclose(ours[np.lexsort(ours.T[::-1])], theirs[np.lexsort(theirs.T[::-1])], atol=1e-5)
    # deterministic
    again = cloud.voxel_downsample(0.25)
    assert torch.equal(again.points, down.points) and torch.equal(again.colors, down.colors)


def _voxel_counts(points: torch.Tensor, size: float) -> torch.Tensor:
    cell = torch.floor((points - (points.amin(0) - size / 2)) / size).long()
    return torch.unique(cell, dim=0, return_counts=True)[1].to(points.dtype)


def test_crop_keeps_only_masked_pixels_and_matches_the_mask_argument():
    g = torch.Generator().manual_seed(5)
    valid = torch.rand(H, W, generator=g) > 0.2
    mask = torch.zeros(H, W, dtype=torch.bool)
    mask[5:20, 10:40] = True
    kw = dict(focal_px=F, cx=CX, cy=CY, baseline=B)
    d = _plane_disparity(0.02, 0.01, 9.0, dtype=torch.float32)
    cropped = disparity_to_point_cloud(d, valid, **kw).crop(mask)
    assert len(cropped) == int((valid & mask).sum())
    assert mask[cropped.pixels[:, 0], cropped.pixels[:, 1]].all()
    direct = disparity_to_point_cloud(d, valid, mask=mask, **kw)
    assert torch.equal(direct.points, cropped.points) and torch.equal(direct.pixels, cropped.pixels)


def test_crop_needs_pixels_and_a_big_enough_mask():
    cloud = _random_cloud(50)
    with pytest.raises(ValueError, match="pixels=None"):
        cloud.voxel_downsample(0.5).crop(torch.ones(H, W, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"mask has shape \(4, 4\)"):
        cloud.crop(torch.ones(4, 4, dtype=torch.bool))


def test_open3d_round_trip():
    cloud = _random_cloud(200)
    back = PointCloud.from_open3d(cloud.to_open3d())
    torch.testing.assert_close(back.points, cloud.points)
    torch.testing.assert_close(back.colors, cloud.colors)
    assert back.pixels is None


# ---------------------------------------------------------------------------- PLY files


@pytest.mark.parametrize("binary", [True, False])
def test_write_read_ply_round_trip(tmp_path, binary):
    cloud = _random_cloud(300)
    path = write_ply(cloud, tmp_path / "cloud.ply", binary=binary)
    assert path.read_bytes().startswith(b"ply\nformat " + (b"binary_little_endian" if binary else b"ascii"))
    back = read_ply(path)
    # binary: float32 exactly; ascii: Open3D prints 6 significant digits (%g)
    tol = dict(rtol=0.0, atol=0.0) if binary else dict(rtol=5e-6, atol=1e-7)
    torch.testing.assert_close(back.points, cloud.points, **tol)
    torch.testing.assert_close(back.colors, cloud.colors, rtol=0, atol=0.5 / 255 + 1e-7)  # stored as uchar
    assert torch.equal(back.pixels, cloud.pixels)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cloud.ply"]  # no temporary file left


def test_write_ply_without_colours_overwrites_and_keeps_permissions(tmp_path):
    target = tmp_path / "c.ply"
    write_ply(_random_cloud(10), target)
    target.chmod(0o640)
    cloud = PointCloud(torch.rand(20, 3, dtype=torch.float64))
    write_ply(cloud, target)
    back = read_ply(target)
    assert len(back) == 20 and back.colors is None and back.pixels is None
    assert target.stat().st_mode & 0o777 == 0o640


def test_write_ply_is_atomic_when_the_final_move_fails(tmp_path):
    (tmp_path / "taken.ply").mkdir()  # a directory holds the name: os.replace fails after the data is written
    with pytest.raises(IsADirectoryError):
        write_ply(_random_cloud(10), tmp_path / "taken.ply")
    assert [p.name for p in tmp_path.iterdir()] == ["taken.ply"]
    assert (tmp_path / "taken.ply").is_dir() and not any((tmp_path / "taken.ply").iterdir())


def test_write_ply_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_ply(_random_cloud(5), tmp_path / "missing" / "c.ply")
    with pytest.raises(ValueError, match=r"\.ply"):
        write_ply(_random_cloud(5), tmp_path / "c.txt")
    with pytest.raises(ValueError, match="empty"):
        write_ply(PointCloud(torch.zeros(0, 3)), tmp_path / "c.ply")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("binary", [True, False])
def test_read_ply_rejects_truncated_files(tmp_path, binary):
    path = write_ply(_random_cloud(400), tmp_path / "c.ply", binary=binary)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(DataFileError, match="truncated") as info:
        read_ply(path)
    assert str(info.value).startswith(str(path))


def test_read_ply_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="PLY file not found"):
        read_ply(tmp_path / "nope.ply")
    (tmp_path / "text.ply").write_text("hello\n")
    with pytest.raises(DataFileError, match="not a PLY file"):
        read_ply(tmp_path / "text.ply")
    (tmp_path / "nohead.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\n")
    with pytest.raises(DataFileError, match="end_header"):
        read_ply(tmp_path / "nohead.ply")


# ---------------------------------------------------------------------------- validation


def test_validation_messages_name_the_argument_and_the_shapes():
    d, v = _plane_disparity(dtype=torch.float32), _all_valid()
    kw = dict(focal_px=F, cx=CX, cy=CY, baseline=B)
    with pytest.raises(ValueError, match=r"disparity must have 2 dimensions; got shape \(1, 40, 60\)"):
        disparity_to_point_cloud(d[None], v[None], **kw)
    with pytest.raises(ValueError, match=r"disparity must have 2 or 3 dimensions"):
        disparity_to_depth(d[0], v[0], focal_px=F, baseline=B)
    with pytest.raises(ValueError, match=r"focal_px must be finite and > 0; got 0"):
        disparity_to_point_cloud(d, v, **{**kw, "focal_px": 0.0})
    with pytest.raises(ValueError, match=r"baseline must be finite and > 0; got -0.1"):
        disparity_to_point_cloud(d, v, **{**kw, "baseline": -0.1})
    with pytest.raises(ValueError, match=r"valid must have the shape of disparity.*\(40, 60\).*\(40, 59\)"):
        disparity_to_depth(d, v[:, 1:], focal_px=F, baseline=B)
    with pytest.raises(TypeError, match="valid has dtype torch.uint8"):
        disparity_to_depth(d, v.to(torch.uint8), focal_px=F, baseline=B)
    with pytest.raises(ValueError, match=r"image must have the spatial size.*\(40, 60\).*\(3, 30, 60\)"):
        disparity_to_point_cloud(d, v, image=torch.zeros(3, 30, 60, dtype=torch.uint8), **kw)
    with pytest.raises(ValueError, match=r"permute\(2, 0, 1\)"):
        disparity_to_point_cloud(d, v, image=torch.zeros(H, W, 3, dtype=torch.uint8), **kw)
    with pytest.raises(ValueError, match="divide by 255"):
        disparity_to_point_cloud(d, v, image=torch.full((3, H, W), 200.0), **kw)
    with pytest.raises(ValueError, match=r"mask must have the spatial size.*\(40, 60\).*\(40, 61\)"):
        disparity_to_point_cloud(d, v, mask=torch.ones(H, W + 1, dtype=torch.bool), **kw)
    bad = d.clone()
    bad[3, 4] = float("inf")
    with pytest.raises(ValueError, match=r"NaN or inf at 1 pixel\(s\) marked valid, first at \(3, 4\)"):
        disparity_to_depth(bad, v, focal_px=F, baseline=B)
    with pytest.raises(ValueError, match=r"K must be a \(3, 3\)"):
        depth_to_points(d, v, torch.eye(4))
    with pytest.raises(ValueError, match="colors must have one row per point"):
        PointCloud(torch.zeros(5, 3), torch.zeros(4, 3))


def test_importing_geometry_does_not_import_open3d():
    code = "import sys, somtorch.geometry; print('open3d' in sys.modules, 'matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


# ---------------------------------------------------------------------------- a real scene


def test_middlebury_motorcycle_reconstructs_to_a_plausible_cloud():
    data = pytest.importorskip("skimage.data")
    left, _, disp = data.stereo_motorcycle()  # quarter-size Middlebury 2014; NaN = no ground truth
    disparity = torch.from_numpy(np.ascontiguousarray(disp))
    valid = torch.isfinite(disparity)
    image = torch.from_numpy(np.ascontiguousarray(left)).permute(2, 0, 1)  # (3, H, W) uint8
    # calibration of the down-sampled pair, from skimage's docstring; baseline in metres
    cloud = disparity_to_point_cloud(disparity, valid, focal_px=994.978, cx=311.193, cy=254.877,
                                     baseline=0.193001, doffs=31.086, image=image)
    assert len(cloud) == int(valid.sum()) == 343274
    z = cloud.points[:, 2]
    # Z = fB / (d + doffs) for d in [7.2, 59.9] px: 2.1–5.0 m
    assert 1.5 < float(z.min()) and float(z.max()) < 6.0
    width = float(cloud.points[:, 0].max() - cloud.points[:, 0].min())
    assert 1.0 < width < 5.0  # a motorcycle scene a few metres wide
    reduced = cloud.voxel_downsample(0.02)
    assert 0 < len(reduced) < len(cloud) / 4 and reduced.nbytes < cloud.nbytes / 4


def test_ply_header_carries_the_units_comment(tmp_path):
    pytest.importorskip("open3d")
    from somtorch.geometry import write_ply
    from somtorch.geometry.ply import read_ply

    cloud = PointCloud(torch.rand(5, 3), colors=torch.rand(5, 3))
    path = write_ply(cloud, tmp_path / "c.ply", comment="x y z in m (the baseline's unit)")
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "comment x y z in m (the baseline's unit)" in header.splitlines()
    back = read_ply(path)
    assert torch.allclose(back.points, cloud.points)  # the body is untouched
    with pytest.raises(ValueError, match="one line"):
        write_ply(cloud, tmp_path / "d.ply", comment="two\nlines")
