"""somtorch.disparity.resize.resize_scene on the embedded scene and a synthetic one."""

from __future__ import annotations

import pytest
import torch

from somtorch.disparity.resize import resize_scene
from somtorch.disparity import Camera, load_scene, scene_from_arrays


def test_upsampling_to_the_paper_size_scales_disparity_with_the_width():
    s = load_scene("motorcycle")
    r = resize_scene(s, 1264, 720)
    assert (r.height, r.width) == (720, 1264) and r.image.shape == (3, 720, 1264)
    sx = 1264 / s.width
    # nearest-neighbour: every resampled disparity is an original one times sx (no invented depths)
    orig = torch.unique(s.disparity[s.valid] * sx)
    got = torch.unique(r.disparity[r.valid])
    assert bool(torch.isin(got, orig).all())
    assert abs(r.valid.float().mean() - s.valid.float().mean()) < 0.005
    assert r.camera is None  # 741x500 -> 1264x720 changes the aspect ratio by 17 %


def test_same_aspect_keeps_a_scaled_camera_and_objects():
    d = torch.arange(40 * 60, dtype=torch.float32).reshape(40, 60) % 7 + 1
    obj = torch.zeros(40, 60, dtype=torch.int64)
    obj[10:20, 10:30] = 1
    cam = Camera(focal_px=100.0, cx=29.5, cy=19.5, baseline=0.1)
    s = scene_from_arrays(d, objects=obj, camera=cam, name="syn")
    r = resize_scene(s, 120, 80)
    assert r.camera.focal_px == pytest.approx(200.0) and r.camera.cx == pytest.approx(59.5)
    assert r.camera.cy == pytest.approx(39.5)
    assert int(r.objects.sum()) == 4 * int(obj.sum()) and [o.id for o in r.object_info] == [1]
    assert torch.equal(r.disparity[::2, ::2], 2 * d)
    assert resize_scene(s, 60, 40) is s


@pytest.mark.parametrize("w, h", [(0, 10), (10, -1)])
def test_bad_sizes_are_rejected(w, h):
    s = scene_from_arrays(torch.ones(4, 4))
    with pytest.raises(ValueError, match="width|height"):
        resize_scene(s, w, h)
