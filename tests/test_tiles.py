"""Divide and conquer: tiles cover the map, objects cut by a border are reassembled."""

from __future__ import annotations

import pytest
import torch

from somtorch.config import PipelineConfig, with_overrides
from somtorch.disparity.scene import scene_from_arrays
from somtorch.tiles import crop_scene, run_tiled, tile_windows


def _scene(h=120, w=160):
    """A background plane and one box spanning the centre, i.e. all four tiles of a 2 x 2 grid."""
    g = torch.Generator().manual_seed(0)
    d = 10.0 + 0.5 * torch.rand(h, w, generator=g)
    obj = torch.zeros(h, w, dtype=torch.int64)
    obj[35:85, 50:110] = 1
    d[obj == 1] = 40.0 + 0.5 * torch.rand(int((obj == 1).sum()), generator=g)
    return scene_from_arrays(d, objects=obj, name="box")


def test_windows_cover_the_map_and_overlap():
    wins = tile_windows(100, 90, (2, 3), 0.1)
    cover = torch.zeros(100, 90, dtype=torch.int64)
    for y0, y1, x0, x1 in wins:
        cover[y0:y1, x0:x1] += 1
    assert len(wins) == 6 and bool((cover >= 1).all()) and int(cover.max()) >= 2
    assert tile_windows(100, 90, (1, 1), 0.2) == [(0, 100, 0, 90)]
    for bad in [((0, 1), 0.1), ((2, 2), 0.5), ((200, 1), 0.0)]:
        with pytest.raises(ValueError):
            tile_windows(100, 90, *bad)


def test_crop_keeps_pixels_objects_and_shifts_the_camera():
    sc = _scene()
    part = crop_scene(sc, 30, 90, 40, 120)
    assert part.disparity.shape == (60, 80) and torch.equal(part.disparity, sc.disparity[30:90, 40:120])
    assert torch.equal(part.objects, sc.objects[30:90, 40:120]) and [o.id for o in part.object_info] == [1]
    assert crop_scene(sc, 0, 10, 0, 10).object_info == []  # no object in this corner


def test_an_object_across_all_tiles_is_reassembled_into_one_box():
    sc = _scene()
    cfg = with_overrides(PipelineConfig(), {"ensemble": 2, "ground.rule": "none"})
    res = run_tiled(sc, cfg, tiles=(2, 2), overlap=0.1)
    assert len(res.windows) == 4 and len(res.members) == 2
    for m in res.members:
        top = m.kept[0]
        assert len(top.tiles) == 4  # pieces of all four tiles joined
        x0, y0, x1, y1 = top.box
        assert x0 <= 52 and y0 <= 37 and x1 >= 107 and y1 >= 82  # the whole object (2 px slack)
        assert m.score.identified_fraction == pytest.approx(1.0) and m.score.useful_hit
    assert set(res.timings) == {"tiles", "merge", "total"} and len(res.tile_seconds) == 4


def test_worker_processes_give_the_same_boxes():
    sc = _scene()
    cfg = with_overrides(PipelineConfig(), {"ensemble": 1, "ground.rule": "none"})
    here = run_tiled(sc, cfg, tiles=(1, 2), workers=0)
    pool = run_tiled(sc, cfg, tiles=(1, 2), workers=2)
    assert [a.box for a in here.members[0].kept] == [a.box for a in pool.members[0].kept]
