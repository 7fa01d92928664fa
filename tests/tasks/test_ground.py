"""Ground-plane detection on synthetic planes: found where it is the support surface, refused where
it is not (too flat, seen at the top, or with the scene behind it)."""

from __future__ import annotations

import torch

from somtorch.config import GroundConfig
from somtorch.evaluation import ground_object_share
from somtorch.disparity.scene import scene_from_arrays
from somtorch.tasks.ground import fit_ground_plane

H, W = 120, 160


def _floor(b: float = 0.5, horizon: int = 40) -> torch.Tensor:
    """A floor: disparity 0 at the horizon row, growing by ``b`` px per row below it; a far wall above."""
    ys = torch.arange(H, dtype=torch.float32)[:, None].expand(H, W)
    return torch.where(ys > horizon + 4, b * (ys - horizon), torch.full((H, W), 2.0)).contiguous()


def test_a_floor_with_an_object_standing_on_it_is_found_and_leaves_the_object_out():
    d = _floor()
    obj = torch.zeros(H, W, dtype=torch.bool)
    obj[50:100, 60:100] = True  # a box standing on the floor at row 100: disparity of its base row
    d[obj] = 0.5 * (100 - 40)
    valid = torch.ones(H, W, dtype=torch.bool)
    g = fit_ground_plane(d, valid, GroundConfig())
    assert g is not None and abs(g.b - 0.5) < 0.01 and abs(g.a) < 0.01
    assert bool(g.mask[110, 10]) and not bool(g.mask[10, 10])  # floor in, wall out
    objects = obj.long()
    scene = scene_from_arrays(d, valid, objects=objects)
    assert ground_object_share(g, scene) < 0.1  # only the base rows of the box touch the band


def test_a_plane_with_the_scene_behind_it_is_not_the_support_surface():
    # the lower half alternates 8-px columns of a slanted surface and a far background: half of the
    # pixels where the "plane" is in view lie behind it, which a floor would hide
    d = _floor()
    ys = torch.arange(H)[:, None].expand(H, W)
    xs = torch.arange(W)[None, :].expand(H, W)
    behind = (ys > 50) & ((xs // 8) % 2 == 1)
    d[behind] = 1.0
    valid = torch.ones(H, W, dtype=torch.bool)
    assert fit_ground_plane(d, valid, GroundConfig(max_below_frac=1.0)) is not None  # the old rule accepts it
    assert fit_ground_plane(d, valid, GroundConfig()) is None
    assert fit_ground_plane(d, valid, GroundConfig(max_below_frac=0.6)) is not None


def test_a_fronto_parallel_wall_and_a_disabled_search_give_no_plane():
    valid = torch.ones(H, W, dtype=torch.bool)
    assert fit_ground_plane(torch.full((H, W), 20.0), valid, GroundConfig()) is None
    assert fit_ground_plane(_floor(), valid, GroundConfig(enabled=False)) is None


def test_the_slope_check_keeps_vertical_surfaces_crossing_the_band_out_of_the_mask():
    d = _floor()
    d[60:100, 60:100] = 0.5 * (80 - 40)  # a box whose disparity equals the floor's at row 80
    valid = torch.ones(H, W, dtype=torch.bool)
    plain = fit_ground_plane(d, valid, GroundConfig())
    sloped = fit_ground_plane(d, valid, GroundConfig(slope_rows=0.03))
    assert plain is not None and sloped is not None
    box = torch.zeros(H, W, dtype=torch.bool)
    box[60:100, 60:100] = True
    assert int((plain.mask & box).sum()) > int((sloped.mask & box).sum())
    assert bool(sloped.mask[110, 10])  # the floor itself stays
