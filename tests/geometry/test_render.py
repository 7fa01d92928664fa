"""Tests of somtorch.geometry.render: real PNG files, real Open3D probe (no mocks)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from somtorch.geometry import (
    PointCloud,
    disparity_to_point_cloud,
    open3d_rendering_available,
    render_point_cloud,
    start_open3d_probe,
)
from somtorch.geometry.render import MAX_SCATTER_POINTS


def _scene(colors: bool = True) -> PointCloud:
    """A tilted coloured plane in front of the camera (about 1 m away)."""
    h, w = 60, 80
    y, x = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32),
                          indexing="ij")
    d = 20.0 + 0.1 * x - 0.05 * y
    image = torch.stack([x / w, y / h, torch.full_like(x, 0.3)])  # (3, H, W) float in [0, 1]
    return disparity_to_point_cloud(d, torch.ones(h, w, dtype=torch.bool), focal_px=200.0, cx=w / 2, cy=h / 2,
                                    baseline=0.1, image=image if colors else None)


def _pixels(path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float64)


def _assert_not_blank(path, width, height):
    img = _pixels(path)
    assert img.shape == (height, width, 3)
    assert img.std() > 10.0  # not a flat image
    assert (img.min(axis=2) < 200).mean() > 0.01  # some non-white (drawn) pixels


def test_matplotlib_backend_writes_a_non_blank_png(tmp_path):
    path = tmp_path / "cloud.png"
    assert render_point_cloud(_scene(), path, width=320, height=240, backend="matplotlib") == "matplotlib"
    _assert_not_blank(path, 320, 240)
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.png"]


def test_views_differ_and_uncoloured_clouds_are_coloured_by_depth(tmp_path):
    cloud = _scene(colors=False)
    front = render_point_cloud(cloud, tmp_path / "front.png", width=200, height=150, backend="matplotlib")
    oblique = render_point_cloud(cloud, tmp_path / "oblique.png", width=200, height=150, backend="matplotlib",
                                 view="oblique")
    assert front == oblique == "matplotlib"
    a, b = _pixels(tmp_path / "front.png"), _pixels(tmp_path / "oblique.png")
    _assert_not_blank(tmp_path / "oblique.png", 200, 150)
    assert np.abs(a - b).mean() > 1.0
    colourful = np.ptp(a, axis=2) > 30  # viridis is not grey
    assert colourful.mean() > 0.01


def test_large_clouds_are_subsampled(tmp_path):
    g = torch.Generator().manual_seed(0)
    cloud = PointCloud(torch.rand(3 * MAX_SCATTER_POINTS, 3, generator=g) + torch.tensor([0.0, 0.0, 2.0]))
    used = render_point_cloud(cloud, tmp_path / "big.png", width=160, height=120, backend="matplotlib")
    assert used == "matplotlib"
    _assert_not_blank(tmp_path / "big.png", 160, 120)


def test_auto_uses_open3d_exactly_when_the_probe_says_it_works(tmp_path):
    available, reason = open3d_rendering_available()
    assert isinstance(reason, str) and reason
    used = render_point_cloud(_scene(), tmp_path / "auto.png", width=240, height=180, backend="auto")
    assert used == ("open3d" if available else "matplotlib")
    _assert_not_blank(tmp_path / "auto.png", 240, 180)


def test_explicit_open3d_backend_renders_or_says_why_not(tmp_path):
    available, reason = open3d_rendering_available()
    path = tmp_path / "o3d.png"
    if available:
        assert render_point_cloud(_scene(), path, width=240, height=180, backend="open3d") == "open3d"
        _assert_not_blank(path, 240, 180)
    else:
        with pytest.raises(RuntimeError, match="not available") as info:
            render_point_cloud(_scene(), path, backend="open3d")
        assert reason in str(info.value) and "backend='matplotlib'" in str(info.value)
        assert not any(tmp_path.iterdir())


def test_probe_is_cached_and_the_environment_overrides_it(monkeypatch):
    open3d_rendering_available()
    hits = open3d_rendering_available.cache_info().hits
    open3d_rendering_available()
    assert open3d_rendering_available.cache_info().hits == hits + 1
    probe = open3d_rendering_available.__wrapped__  # the uncached function
    monkeypatch.setenv("SOMTORCH_OPEN3D_RENDER", "0")
    assert probe() == (False, "set by SOMTORCH_OPEN3D_RENDER=0")
    monkeypatch.setenv("SOMTORCH_OPEN3D_RENDER", "1")
    assert probe()[0] is True


def test_render_is_atomic_when_the_final_move_fails(tmp_path):
    (tmp_path / "taken.png").mkdir()
    with pytest.raises(IsADirectoryError):
        render_point_cloud(_scene(), tmp_path / "taken.png", width=100, height=80, backend="matplotlib")
    assert [p.name for p in tmp_path.iterdir()] == ["taken.png"]


def test_render_errors(tmp_path):
    with pytest.raises(ValueError, match="valid names: auto, matplotlib, open3d"):
        render_point_cloud(_scene(), tmp_path / "a.png", backend="vtk")
    with pytest.raises(ValueError, match="valid names: front, oblique"):
        render_point_cloud(_scene(), tmp_path / "a.png", view="top")
    with pytest.raises(ValueError, match="empty"):
        render_point_cloud(PointCloud(torch.zeros(0, 3)), tmp_path / "a.png")
    with pytest.raises(ValueError, match=r"\.png"):
        render_point_cloud(_scene(), tmp_path / "a.jpg")
    with pytest.raises(ValueError, match="width must be a positive integer"):
        render_point_cloud(_scene(), tmp_path / "a.png", width=0)
    assert not any(tmp_path.iterdir())


def _drawn_share(path) -> float:
    """Share of the image covered by drawn points (viridis: coloured; panes and labels are grey)."""
    return float((np.ptp(_pixels(path), axis=2) > 40).mean())


def test_stray_points_do_not_squash_the_cloud_into_a_corner(tmp_path):
    """1.5 % of the points far away to the side and above, at the depth of the rest (mismatches, a
    far wall through a gap): the view frames the rest."""
    g = torch.Generator().manual_seed(0)
    bulk = torch.rand(20_000, 3, generator=g) * torch.tensor([1.0, 0.6, 0.8]) + torch.tensor([0.0, 0.0, 1.0])
    stray = torch.rand(300, 3, generator=g) * torch.tensor([3.0, 3.0, 0.8]) + torch.tensor([4.0, -6.0, 1.0])
    path = tmp_path / "stray.png"
    render_point_cloud(PointCloud(torch.cat([bulk, stray])), path, width=400, height=300, backend="matplotlib",
                       view="oblique")
    assert _drawn_share(path) > 0.15  # 0.30 framed; 0.02 when the strays set the axes


def test_grey_image_colours_are_replaced_by_depth(tmp_path):
    """A mono camera's grey levels say nothing a reader can see in a cloud: depth colours it."""
    cloud = _scene(colors=False)
    grey = PointCloud(cloud.points, torch.full((len(cloud), 3), 0.5))
    render_point_cloud(grey, tmp_path / "grey.png", width=200, height=150, backend="matplotlib")
    assert (np.ptp(_pixels(tmp_path / "grey.png"), axis=2) > 30).mean() > 0.01


def test_probe_started_ahead_gives_the_same_answer(monkeypatch):
    from somtorch.geometry import render

    monkeypatch.delenv("SOMTORCH_OPEN3D_RENDER", raising=False)
    open3d_rendering_available.cache_clear()
    start_open3d_probe()
    assert render._started is not None  # running in the background
    start_open3d_probe()  # a second start while one runs: the same probe, not another
    ahead = render._started
    answer = open3d_rendering_available()
    assert render._started is None and ahead.returncode is not None  # read and reaped
    assert answer == open3d_rendering_available.__wrapped__()  # the same as a probe run on the spot
    start_open3d_probe()  # the answer is known: nothing starts
    assert render._started is None
    open3d_rendering_available.cache_clear()
    monkeypatch.setenv("SOMTORCH_OPEN3D_RENDER", "0")
    start_open3d_probe()  # the environment decides: no probe
    assert render._started is None
    assert open3d_rendering_available() == (False, "set by SOMTORCH_OPEN3D_RENDER=0")
    open3d_rendering_available.cache_clear()
    monkeypatch.delenv("SOMTORCH_OPEN3D_RENDER")
    start_open3d_probe()
    unread = render._started
    render._stop_probe()  # at exit: a probe nobody read is killed and reaped
    assert render._started is None and unread.returncode is not None
