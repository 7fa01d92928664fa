"""Ground-plane detection on synthetic planes: found where it is the support surface, refused where
it is not (too flat, seen at the top, or with the scene behind it)."""

from __future__ import annotations

import pytest
import torch

from somtorch.config import GroundConfig
from somtorch.evaluation import ground_object_share
from somtorch.disparity.scene import scene_from_arrays
from somtorch.tasks.ground import fit_ground_plane, view_rim

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


def test_a_support_plane_may_have_the_floor_behind_its_edges_a_position_plane_may_not():
    # a table top seen from above fills 3/4 of the view, the floor beyond its edges lies behind
    # it: the support rule verifies it (most of the view, nothing standing on it is large), and a
    # support surface need not hide what lies beyond its edges; the position rule's floor must
    ys = torch.arange(H, dtype=torch.float32)[:, None].expand(H, W)
    xs = torch.arange(W)[None, :].expand(H, W)
    table = (ys >= 15) & (xs >= 10) & (xs < W - 10)
    d = torch.where(table, 20.0 + 0.06 * ys, torch.full((H, W), 5.0)).contiguous()
    valid = torch.ones(H, W, dtype=torch.bool)
    g = fit_ground_plane(d, valid, GroundConfig())
    assert g is not None and g.support and abs(g.inlier_frac - float(table.float().mean())) < 0.01
    behind = (d < g.disparity(H, W) - g.tol) & (g.disparity(H, W) > g.tol)
    assert float(behind.float().mean()) > GroundConfig().max_below_frac  # more than a floor may hide
    pos = fit_ground_plane(d, valid, GroundConfig(rule="position", min_slope_frac=0.0))
    assert pos is None or not bool((pos.mask & table).any())  # the floor, if any; never the table top


def test_a_fronto_parallel_wall_and_a_disabled_search_give_no_plane():
    valid = torch.ones(H, W, dtype=torch.bool)
    # by position, a plane of constant disparity is a wall, not a floor ...
    assert fit_ground_plane(torch.full((H, W), 20.0), valid, GroundConfig(rule="position")) is None
    # ... by what it supports it may be a floor seen straight down (disparity cannot tell the two):
    # the default rule (either) takes it, holding everything, with nothing standing on it
    g = fit_ground_plane(torch.full((H, W), 20.0), valid, GroundConfig())
    assert g is not None and g.support and g.inlier_frac == 1.0
    assert fit_ground_plane(_floor(), valid, GroundConfig(rule="none")) is None


def test_the_best_plane_that_passes_the_tests_is_found_not_the_best_plane_refused():
    # a ramp over the left 70 % of the image, up to its top row, holds more of the lower half than
    # the floor at the right: it is the best hypothesis by inliers but fails the top and behind
    # tests (position rule). The search with the tests as constraints finds the floor.
    ys = torch.arange(H, dtype=torch.float32)[:, None].expand(H, W)
    xs = torch.arange(W)[None, :].expand(H, W)
    d = torch.where(ys > 44, 0.5 * (ys - 40), torch.full((H, W), 2.0))
    ramp = xs < int(0.7 * W)
    d = torch.where(ramp, 0.3 * ys + 20.0, d).contiguous()
    valid = torch.ones(H, W, dtype=torch.bool)
    slope = 0.25  # the ramp spans 0.7 of the range over the image height: let it be a hypothesis
    g = fit_ground_plane(d, valid, GroundConfig(rule="position", min_slope_frac=slope))
    assert g is not None and abs(g.b - 0.5) < 0.01 and abs(g.a) < 0.01
    assert not bool(g.mask[ramp].any()) and bool(g.mask[110, W - 5])


def test_a_real_floor_near_a_threshold_is_found_whatever_the_ransac_seed(shared_data):
    # the OAK-D toy's floor: its share of pixels behind the best plane lies at 0.10-0.17 over seeds
    # (max_below_frac 0.1), so the plain search found it for some seeds only
    from somtorch.disparity.loading import load_scene

    scene = load_scene(shared_data / "oakd_stereodemo" / "toy")
    found = [fit_ground_plane(scene.disparity, scene.valid, seed=s) for s in range(6)]
    assert all(g is not None for g in found)
    assert max(g.inlier_frac for g in found) - min(g.inlier_frac for g in found) < 0.03
    assert all(0.1 < g.b < 0.15 for g in found)  # the same floor (0.125 px per row)


def test_the_plane_has_the_same_bits_at_one_and_two_threads():
    ys = torch.arange(H, dtype=torch.float32)[:, None].expand(H, W)
    d = (_floor() + 0.3 * torch.sin(ys * 0.7)).contiguous()  # a floor with ripples: many near-band pixels
    valid = torch.ones(H, W, dtype=torch.bool)
    before = torch.get_num_threads()
    try:
        planes = []
        for n in (1, 2):
            torch.set_num_threads(n)
            g = fit_ground_plane(d, valid, GroundConfig())
            planes.append((g.a, g.b, g.c, g.mask.clone()))
    finally:
        torch.set_num_threads(before)
    assert planes[0][:3] == planes[1][:3] and torch.equal(planes[0][3], planes[1][3])


def test_noise_sigma_measures_per_pixel_noise_and_ignores_gradients_and_edges():
    from somtorch.tasks.ground import noise_sigma

    g = torch.Generator().manual_seed(0)
    d = _floor() + 0.3 * torch.arange(W, dtype=torch.float32)[None, :]  # tilted in x too
    d[50:100, 60:100] += 20.0  # a box: depth edges
    valid = torch.ones(H, W, dtype=torch.bool)
    assert noise_sigma(d, valid) < 0.01  # a noise-free map
    noisy = d + 0.5 * torch.randn(H, W, generator=g)
    assert abs(noise_sigma(noisy, valid) - 0.5) < 0.05
    stripes = valid.clone()
    stripes[:, ::2] = False  # no two horizontal neighbours valid: read two pixels apart
    assert abs(noise_sigma(noisy, stripes) - 0.5) < 0.05
    sparse = torch.zeros_like(valid)
    sparse[:, ::3] = True  # no two valid pixels within two columns: nothing to measure
    assert noise_sigma(noisy, sparse) == 0.0


def test_the_band_widens_with_the_noise_of_a_dense_floor():
    """A floor with 0.5 px of per-pixel noise (a dense sensor) and a 1 px band: with the band at
    least twice the noise, nearly all of it is ground; without, a third of it was left as speckle."""
    g = torch.Generator().manual_seed(1)
    d = 40.0 + 0.05 * torch.arange(H, dtype=torch.float32)[:, None].expand(H, W)  # from above: a small range
    box = torch.zeros(H, W, dtype=torch.bool)
    box[40:70, 60:100] = True
    d = torch.where(box, d + 8.0, d) + 0.5 * torch.randn(H, W, generator=g)
    valid = torch.ones(H, W, dtype=torch.bool)
    narrow = fit_ground_plane(d, valid, GroundConfig(rule="support", noise_band=0.0))
    wide = fit_ground_plane(d, valid, GroundConfig(rule="support"))
    floor = ~box
    assert narrow is not None and wide is not None
    assert float(narrow.mask[floor].float().mean()) < 0.75
    assert float(wide.mask[floor].float().mean()) > 0.94 and not bool(wide.mask[box].any())
    assert abs(wide.tol - 2 * 0.5) < 0.1  # noise_band × the measured noise


def test_quantum_is_the_maps_disparity_resolution():
    from somtorch.tasks.ground import quantum

    g = torch.Generator().manual_seed(3)
    d = 5.0 + 40.0 * torch.rand(5000, generator=g, dtype=torch.float64)
    assert quantum(torch.round(d)) == 1.0  # an integer map
    assert quantum(torch.round(d * 16) / 16) == 1 / 16  # OpenCV's SGBM
    assert quantum(d) < 0.05  # floating point
    assert quantum(torch.full((10,), 7.0)) == 0.0


def test_the_band_holds_the_terraces_of_an_integer_floor():
    """A floor seen from above stored as whole pixels is a flight of flat terraces, each pixel up to
    0.5 px off the plane: a band of 0.5 px (the noise term ignoring the rounding) leaves about a
    tenth of the floor as terrace edges; the rounding's variance (q²/12) widens it to 2/√12 px."""
    ys = torch.arange(240, dtype=torch.float32)[:, None].expand(240, 320)
    xs = torch.arange(320, dtype=torch.float32)[None, :].expand(240, 320)
    d = 18.9 + 0.003 * ys + 0.001 * xs
    box = torch.zeros(240, 320, dtype=torch.bool)
    box[80:140, 100:180] = True
    d = torch.round(torch.where(box, d + 8.0, d))
    valid = torch.ones(240, 320, dtype=torch.bool)
    rounding_ignored = fit_ground_plane(d, valid, GroundConfig(noise_band=0.0))
    plane = fit_ground_plane(d, valid)
    assert rounding_ignored is not None and plane is not None
    assert float(rounding_ignored.mask[~box].float().mean()) < 0.95
    assert float(plane.mask[~box].float().mean()) > 0.98 and not bool(plane.mask[box].any())
    # at least the rounding's band; the terraces' own spread (uniform, ±0.5 px) widens it a little
    assert 2 / 12 ** 0.5 - 1e-6 <= plane.tol < 0.7


def test_a_map_of_pure_noise_is_not_cut_by_a_band_as_wide_as_its_noise():
    """Uniform noise over 1-60 px: neighbours differ as much as the whole map (measured noise ~17 px),
    so the noise term is dropped; a 34 px band would have held most pixels and cut them all."""
    from somtorch.tasks.ground import noise_sigma

    g = torch.Generator().manual_seed(2)
    d = 1.0 + 59.0 * torch.rand(H, W, generator=g)
    valid = torch.ones(H, W, dtype=torch.bool)
    assert noise_sigma(d, valid) > 10
    for rule in ("support", "either"):
        plane = fit_ground_plane(d, valid, GroundConfig(rule=rule))
        assert plane is None or (plane.tol < 2.0 and plane.inlier_frac < 0.2), (rule, plane)


def test_the_view_rim_is_where_the_valid_view_ends_not_the_image_border():
    # an SGBM map has no disparity in its left columns: the rim runs along the first valid column
    valid = torch.ones(6, 8, dtype=torch.bool)
    valid[:, :3] = False
    valid[2, 5] = False  # a hole inside the view is not its rim
    rim = view_rim(valid)
    expected = torch.zeros(6, 8, dtype=torch.bool)
    expected[0, 3:] = expected[-1, 3:] = True
    expected[:, 3] = expected[:, -1] = True
    assert torch.equal(rim, expected)
    assert not view_rim(torch.zeros(4, 4, dtype=torch.bool)).any()


def _blotches(h: int, w: int, sigma: float, scale: float, seed: int) -> torch.Tensor:
    """Gaussian noise smoothed over ``scale`` px (a filtered dense sensor's error), ``sigma`` px per pixel."""
    import torch.nn.functional as F

    r = int(3 * scale)
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float32) / scale) ** 2)
    k = k / k.sum()
    n = torch.randn(1, 1, h + 2 * r, w + 2 * r, generator=torch.Generator().manual_seed(seed))
    n = F.conv2d(F.conv2d(n, k.view(1, 1, -1, 1)), k.view(1, 1, 1, -1))[0, 0]
    return sigma * n / n.std()


def test_a_floor_whose_noise_is_correlated_is_banded_by_its_own_spread():
    """A floor seen from above with 0.5 px of noise correlated over ~4 px: neighbours differ by far
    less than that, so the neighbour reading misses it and a band from it left a third of the floor
    as blotches. The band is noise_band × the spread of the plane's own pixels about it."""
    from somtorch.tasks.ground import noise_sigma

    h, w = 240, 320
    d = 40.0 + 0.05 * torch.arange(h, dtype=torch.float32)[:, None].expand(h, w)
    box = torch.zeros(h, w, dtype=torch.bool)
    box[80:140, 100:180] = True
    d = torch.where(box, d + 8.0, d) + _blotches(h, w, 0.5, 4.0, seed=5)
    valid = torch.ones(h, w, dtype=torch.bool)
    assert noise_sigma(d, valid) < 0.15  # the neighbour reading sees a fraction of the 0.5 px
    plane = fit_ground_plane(d, valid)
    assert plane is not None and plane.support
    assert abs(plane.tol - 2 * 0.5) < 0.15
    floor = ~box
    assert float(plane.mask[floor].float().mean()) > 0.93 and not bool(plane.mask[box].any())
    residual = (d - plane.disparity(h, w)).abs()
    assert float((residual[floor] < 0.5).float().mean()) < 0.75  # what the 0.5 px band held


def _sampled_xy(g: torch.Generator, n: int = 20_000) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` pixel positions (x, y) drawn uniformly over a 320 × 240 map, float64."""
    x = 320 * torch.rand(n, generator=g, dtype=torch.float64)
    return x, 240 * torch.rand(n, generator=g, dtype=torch.float64)


def test_a_band_that_finds_no_peak_is_not_widened():
    """A dome (no plane: its pixels lie up to several px off any plane through them) and a floor of
    two surfaces whose spread runs past the depth-continuity step keep the band they started with;
    a plane with Gaussian noise converges at noise_band × its σ."""
    from somtorch.tasks.support_surface import own_band, truncated_sd

    assert abs(truncated_sd(2.0) - 0.8796) < 1e-4 and abs(truncated_sd(50.0) - 1.0) < 1e-9
    g = torch.Generator().manual_seed(7)
    x, y = _sampled_xy(g)
    coef = torch.tensor([0.0, 0.05, 40.0], dtype=torch.float64)
    flat = coef[1] * y + coef[2]
    noisy = torch.stack([x, y, flat + 0.6 * torch.randn(x.numel(), generator=g, dtype=torch.float64)], 1)
    assert abs(own_band(coef, noisy, 0.5, 2.0, 100.0) - 2 * 0.6) < 0.06
    dome = torch.stack([x, y, flat + 8.0 * ((x / 160 - 1) ** 2 + (y / 120 - 1) ** 2)], 1)
    assert own_band(coef, dome, 0.5, 2.0, 100.0) == 0.5
    assert own_band(coef, noisy, 0.5, 2.0, 1.0) == 0.5  # the map's range caps it too


def _bowl_floor(p: float, box: bool = True, small: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """A floor seen from above (50 px, nearer towards the bottom) with a parcel on it (a quarter of the
    view; ``small``: a tenth), every disparity × (1 + p (x̂² + ŷ² − 1)): a dense sensor's calibration
    residue, −p at the centre, +p at the corners."""
    h, w = 240, 320
    ys = torch.linspace(-1, 1, h)[:, None]
    xs = torch.linspace(-1, 1, w)[None, :]
    d = (50.0 + 0.02 * torch.arange(h, dtype=torch.float32)[:, None]).expand(h, w)
    parcel = torch.zeros(h, w, dtype=torch.bool)
    if box and small:
        parcel[90:150, 120:200] = True
    elif box:
        parcel[60:180, 90:230] = True
    return torch.where(parcel, d + 8.0, d) * (1 + p * (xs * xs + ys * ys - 1)), parcel


def test_a_floor_bent_by_a_calibration_residue_is_cut_by_its_own_bent_surface():
    """±0.75 px of bend: no plane holds 60 % of the pixels or of the rim, so before session 22 no
    support was found and the contrast rule ran; the bent surface holds the whole floor and no
    pixel of the parcel. A flat floor keeps its plane (no bend)."""
    from somtorch.tasks.ground import verify_plane

    d, parcel = _bowl_floor(0.015)
    h, w = d.shape
    valid = torch.ones(h, w, dtype=torch.bool)
    g = fit_ground_plane(d, valid)
    assert g is not None and g.support and g.bend != (0.0, 0.0, 0.0)
    assert float(g.mask[~parcel].float().mean()) > 0.99 and not bool(g.mask[parcel].any())
    assert float((d - g.disparity(h, w)).abs()[~parcel].max()) < g.tol  # it reports the surface it cut
    flat = verify_plane((g.a, g.b, g.c), d, valid, g.tol, GroundConfig())
    assert flat is None or not flat.support  # its plane part alone is no verified support
    assert g.as_dict()["bend"] == list(g.bend)  # reported in metrics.json
    level, _ = _bowl_floor(0.0)
    assert fit_ground_plane(level, valid).bend == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("p", [0.01, 0.02])
def test_a_bent_floor_whose_plane_passes_by_its_pixels_is_cut_whole_where_the_bend_closes_its_rim(p):
    """A smaller parcel. At ±0.5 px of bend (p = 0.01) RANSAC's plane holds 70 % of the pixels and
    passes the support test by them, but the bowl takes its rim (0.53 of it, 75 % of the floor cut
    before session 22's second rule). At ±1 px (0.02) the plane's own band widens first (0.71 px)
    and the plane so banded passes by its pixels (63 %) with 39 % of the rim: before session 23 it
    returned at once and cut 67 % of the floor. In both the bent surface passes the rim test the
    plane fails and replaces it: the whole floor is cut, not a disc of it whose rim chains into the
    parcel."""
    d, parcel = _bowl_floor(p, small=True)
    h, w = d.shape
    valid = torch.ones(h, w, dtype=torch.bool)
    g = fit_ground_plane(d, valid)
    assert g is not None and g.support and g.bend != (0.0, 0.0, 0.0) and g.rim_frac >= 0.99
    assert float(g.mask[~parcel].float().mean()) > 0.99 and not bool(g.mask[parcel].any())
    assert float((d - g.disparity(h, w)).abs()[~parcel].max()) < g.tol


def test_a_dome_is_no_bent_floor():
    """A surface that departs from its nearest plane by more than a depth edge (the object step's
    continuity step) is a thing, not a bent floor: a dome filling the view is never a support, while
    a sub-pixel bowl is fitted at the band it started with."""
    from somtorch.tasks.support_surface import own_surface

    x, y = _sampled_xy(torch.Generator().manual_seed(3))
    coef = torch.tensor([0.0, 0.02, 50.0], dtype=torch.float64)
    flat = coef[1] * y + coef[2]
    bowl = torch.stack([x, y, flat * (1 + 0.01 * ((x / 160 - 1) ** 2 + (y / 120 - 1) ** 2 - 1))], 1)
    band, bent = own_surface(coef, bowl, 0.5, 2.0, 100.0, 240, 320)
    assert band == 0.5 and float(bent[3:].abs().max()) > 0
    dome = torch.stack([x, y, flat + 8.0 * (1 - (x / 160 - 1) ** 2 - (y / 120 - 1) ** 2)], 1)
    assert own_surface(coef, dome, 0.5, 2.0, 100.0, 240, 320) is None
    row = torch.stack([x, torch.zeros_like(x), torch.full_like(x, 50.0)], 1)  # one row: no surface to fit
    assert own_surface(coef, row, 0.5, 2.0, 100.0, 240, 320) is None
    h, w = 240, 320
    yy = torch.arange(h, dtype=torch.float32)[:, None] / 120 - 1
    xx = torch.arange(w, dtype=torch.float32)[None, :] / 160 - 1
    ball = (50.0 + 8.0 * (1 - xx * xx - yy * yy)).expand(h, w).contiguous()
    found = fit_ground_plane(ball, torch.ones(h, w, dtype=torch.bool))
    assert found is None or not found.support
