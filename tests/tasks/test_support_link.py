"""The depth-continuity link of step 1c (``CONTINUOUS_SHARE``) on hand-built maps.

On a map whose ground plane the support test verified, touching segments also link where their
common boundary is depth-continuous, if both stand above the plane's clutter band and each lies in
one image island of the segmented pixels (``somtorch.tasks.detect.linkable_segments``).
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from somtorch.config import AreaConfig
from somtorch.config.objects import CONTINUITY_STEP_FRAC, CONTINUITY_STEP_PX, CONTINUOUS_SHARE
from somtorch.tasks.baselines.plane_components import PlaneComponentsParams
from somtorch.tasks.context import MapContext
from somtorch.tasks.detect import find_objects, linkable_segments
from somtorch.tasks.ground import GroundPlane
from somtorch.tasks.objects import continuous_pairs, find_object_areas, neuron_stats, pair_continuity

H, W, FLOOR_D = 60, 80, 5.0


def test_continuous_pair_counts_match_a_pixel_by_pixel_reference():
    g = torch.Generator().manual_seed(5)
    h, w, k = 15, 19, 5
    labels = torch.where(torch.rand(h, w, generator=g) > 0.1, torch.randint(0, k, (h, w), generator=g), -1)
    disp = 10 + torch.randint(0, 4, (h, w), generator=g).double() * 0.6  # steps of 0, 0.6 … 1.8 px
    stats = neuron_stats(labels, disp, k, continuity=pair_continuity(disp))
    want = torch.zeros(k, k, dtype=torch.float64)
    for y in range(h):
        for x in range(w):
            for yy, xx in ((y, x + 1), (y + 1, x)):
                if yy >= h or xx >= w:
                    continue
                a, b = int(labels[y, x]), int(labels[yy, xx])
                da, db = float(disp[y, x]), float(disp[yy, xx])
                if a >= 0 and b >= 0 and a != b and abs(da - db) <= max(1.0, 0.05 * (da + db) / 2):
                    want[a, b] += 1
                    want[b, a] += 1
    assert torch.equal(stats.continuous, want)
    assert torch.equal(stats.boundary, neuron_stats(labels, disp, k).boundary)  # one bincount for both
    assert bool((stats.continuous <= stats.boundary).all())
    assert neuron_stats(labels, disp, k).continuous is None  # only when asked for
    assert pair_continuity(disp).shape == (h * (w - 1) + (h - 1) * w,)
    with pytest.raises(ValueError, match="pair_continuity"):
        neuron_stats(labels, disp, k, continuity=pair_continuity(disp[:, 1:]))


def test_the_continuity_rule_is_the_baselines_step_rule_declared_once():
    p = PlaneComponentsParams()
    assert (p.step_px, p.step_frac) == (CONTINUITY_STEP_PX, CONTINUITY_STEP_FRAC)
    d = torch.tensor([100.0, 100.0, 10.0, 10.0])
    e = torch.tensor([104.9, 105.3, 11.0, 11.1])  # 5 % of the mean: 5.12 and 5.13 px; at 10 px the 1 px floor
    assert continuous_pairs(d, e).tolist() == [True, False, True, False]


def _staircase(steps: int = 4, rows: int = 5):
    """A ramp of ``steps`` segments (``rows`` rows each, disparity rising 1 px a row, so continuous at
    every boundary while the segments' means differ by ``rows`` px) on a floor that holds the rest
    of the map (not segmented, far behind)."""
    labels = torch.full((H, W), -1, dtype=torch.long)
    for i in range(steps):
        labels[20 + i * rows: 20 + (i + 1) * rows, 20:60] = i
    return labels, _ramp_disparity(labels)


def _ramp_disparity(labels: torch.Tensor) -> torch.Tensor:
    disp = torch.full((H, W), FLOOR_D, dtype=torch.float64)
    ys = torch.arange(H, dtype=torch.float64)[:, None].expand(H, W)
    on = labels >= 0
    disp[on] = 20.0 + (ys[on] - 20)
    return disp


def _run(labels, disp, cfg: AreaConfig, support: bool = True):
    valid = torch.ones(H, W, dtype=torch.bool)
    segmented = labels >= 0
    ground = GroundPlane(0.0, 0.0, FLOOR_D, 0.5, valid & ~segmented, float((~segmented).float().mean()), support)
    ctx = MapContext.build(disp, valid, segmented, ground, cfg)
    k = int(labels.max()) + 1
    ref = torch.stack([disp[labels == n].mean() for n in range(k)])
    return find_objects(labels, ref.float(), None, ctx, cfg), ctx


def _groups(result) -> set[frozenset[int]]:
    return {frozenset(a.neurons) for a in result.areas}


def test_a_ramp_on_a_support_verified_floor_is_one_area_not_one_per_step():
    labels, disp = _staircase()
    cfg = AreaConfig()
    linked, ctx = _run(labels, disp, cfg)
    assert _groups(linked) == {frozenset({0, 1, 2, 3})}
    assert linked.kept[0].box == (20, 20, 59, 39)  # the whole ramp is kept
    # the steps' mean disparities differ by 5 px, far beyond the similarity tolerance: without the
    # continuity link, or where the plane was not verified by what it supports, each is its own area
    stats = neuron_stats(labels, disp, 4, continuity=pair_continuity(disp))
    ref = torch.stack([disp[labels == n].mean() for n in range(4)])
    off = find_object_areas(ref, None, stats, cfg)
    assert {frozenset(a.neurons) for a in off} == {frozenset({i}) for i in range(4)}
    forward, ctx_fwd = _run(labels, disp, cfg, support=False)
    assert _groups(forward) == {frozenset({i}) for i in range(4)} and ctx_fwd.islands is None


def test_an_occluding_edge_does_not_link():
    labels, disp = _staircase()
    disp[labels >= 2] += 6.0  # a step of 7 px at the 1–2 boundary (an occluding edge), 1 px at 2–3
    result, _ = _run(labels, disp, AreaConfig())
    assert _groups(result) == {frozenset({0, 1}), frozenset({2, 3})}


def test_segments_straddling_two_islands_or_lying_on_the_floor_do_not_link_by_continuity():
    # two ramps side by side, split by a column of floor (two image islands), and one segment (6)
    # across the top of both: continuous with the top step of each ramp
    labels = torch.full((H, W), -1, dtype=torch.long)
    for i in range(3):
        labels[25 + 5 * i: 30 + 5 * i, 20:40] = i
        labels[25 + 5 * i: 30 + 5 * i, 41:60] = 3 + i
    labels[20:25, 20:60] = 6
    labels[:, 40] = -1
    disp = _ramp_disparity(labels)
    cfg = AreaConfig()
    result, ctx = _run(labels, disp, cfg)
    ok = linkable_segments(labels, neuron_stats(labels, disp, 7, continuity=pair_continuity(disp)), ctx, cfg)
    assert ok.tolist() == [True] * 6 + [False]  # half of neuron 6 lies in each island
    assert _groups(result) == {frozenset({0, 1, 2}), frozenset({3, 4, 5}), frozenset({6})}  # not chained
    # a segment within the clutter band of the plane (left-over floor) may not link either
    low_labels, low_disp = _staircase()
    low_disp[low_labels == 0] = FLOOR_D + 1.0  # 1 px above the floor: inside 3 × the 0.5 px band
    _, low_ctx = _run(low_labels, low_disp, cfg)
    low_stats = neuron_stats(low_labels, low_disp, 4, continuity=pair_continuity(low_disp))
    low = linkable_segments(low_labels, low_stats, low_ctx, cfg)
    assert low.tolist() == [False, True, True, True]


def test_the_paper_rule_never_links_by_continuity():
    labels, disp = _staircase()
    cfg = dataclasses.replace(AreaConfig(), rule="paper", similarity=0.1)
    _, ctx = _run(labels, disp, cfg)
    assert ctx.islands is None


def test_a_boundary_is_continuous_when_most_of_its_pixel_pairs_are():
    # two segments side by side on a support-verified floor; the top rows of segment 1 step away
    # from segment 0 by 8 px (an occluding edge), the bottom rows run on: the share of continuous
    # pairs along their common boundary decides the link, at CONTINUOUS_SHARE
    for rows_continuous, linked in ((12, True), (8, False)):
        labels = torch.full((H, W), -1, dtype=torch.long)
        labels[20:40, 20:40], labels[20:40, 40:60] = 0, 1
        disp = torch.full((H, W), FLOOR_D, dtype=torch.float64)
        disp[20:40, 20:40] = 20.0
        disp[20:40, 40:60] = 20.5 + 8.0  # dissimilar means: no similarity link
        disp[40 - rows_continuous:40, 40:60] = 20.5
        share = rows_continuous / 20
        assert (share >= CONTINUOUS_SHARE) == linked
        result, _ = _run(labels, disp, AreaConfig())
        assert (frozenset({0, 1}) in _groups(result)) == linked, share


def test_object_mode_names_the_link_and_ranking_used_and_why():
    from somtorch.tasks.context import object_mode

    mask = torch.zeros(H, W, dtype=torch.bool)
    supported = GroundPlane(0.0, 0.1, 1.0, 0.5, mask, 0.44, support=True, rim_frac=0.77)
    positioned = dataclasses.replace(supported, support=False, inlier_frac=0.32, rim_frac=0.53)
    mode, why = object_mode(supported, AreaConfig())
    assert mode == "support" and "44%" in why and "77%" in why
    mode, why = object_mode(positioned, AreaConfig())
    assert mode == "contrast" and "position only" in why and "32%" in why
    assert object_mode(None, AreaConfig())[0] == "contrast"
    assert object_mode(supported, AreaConfig(rule="paper"))[0] == "paper"
    # the context's continuity link follows the same verdict
    disp = torch.full((H, W), 10.0)
    valid = torch.ones(H, W, dtype=torch.bool)
    ctx = MapContext.build(disp, valid, valid, supported, AreaConfig())
    assert ctx.islands is not None and ctx.continuity is not None
    ctx = MapContext.build(disp, valid, valid, positioned, AreaConfig())
    assert ctx.islands is None and ctx.continuity is None


def test_what_lies_beneath_a_verified_support_is_no_candidate():
    """On a support-verified floor (the plane at FLOOR_D), a large patch *beneath* it (a lower floor
    seen past a table's edge: 40 x 30 px, 3 px behind the plane) outranks a small object standing on it
    by size x nearness; it lies beneath the support, so it is no candidate and the object is kept. On a
    map whose plane was verified by its position only, nothing changes (the contrast ranking)."""
    from somtorch.tasks.detect import standing_areas

    labels = torch.full((H, W), -1, dtype=torch.long)
    disp = torch.full((H, W), FLOOR_D + 10.0, dtype=torch.float64)  # the floor: FLOOR_D + 10 px
    labels[5:15, 60:70], disp[5:15, 60:70] = 0, FLOOR_D + 14.0  # an object 4 px above it
    labels[25:55, 5:45], disp[25:55, 5:45] = 1, FLOOR_D + 7.0  # beneath it by 3 px
    valid = torch.ones(H, W, dtype=torch.bool)
    segmented = labels >= 0
    ground = GroundPlane(0.0, 0.0, FLOOR_D + 10.0, 0.5, valid & ~segmented, float((~segmented).float().mean()), True)
    cfg = AreaConfig()
    ctx = MapContext.build(disp, valid, segmented, ground, cfg)
    assert ctx.clutter_band == 1.5 and ctx.ground_height is not None
    ref = torch.tensor([FLOOR_D + 14.0, FLOOR_D + 7.0])
    result = find_objects(labels, ref.float(), None, ctx, cfg)
    stats = result.stats
    by_size = sorted(result.areas, key=lambda a: -a.area_frac * a.mean_disparity)
    assert by_size[0].neurons == [1]  # size x nearness alone would rank the patch beneath first
    assert [a.neurons for a in standing_areas(result.areas, labels, stats, ctx)] == [[0]]
    assert result.kept[0].neurons == [0] and result.kept[0].box == (60, 5, 69, 14)
    assert all(a.neurons != [1] for a in result.kept)
    # and metrics.json says why: the object kept, the patch counted as left out beneath the support
    ranked = [(c.area.neurons, c.rank, c.verdict) for c in result.candidates if c.rank is not None]
    assert ranked == [([0], 0, "kept")]
    assert result.unranked.get("beneath the verified support") == 1
    assert [(c.area.neurons, c.verdict) for c in result.candidates if c.rank is None] == \
        [([1], "left out: it lies beneath the verified support")]  # it would have outranked the object
    # within the clutter band beneath the plane it still counts as standing on it (left-over floor
    # is the clutter filter's business, not this one's)
    shallow = torch.where(labels == 1, FLOOR_D + 9.0, disp)
    ctx2 = MapContext.build(shallow, valid, segmented, ground, cfg)
    assert len(standing_areas(result.areas, labels, stats, ctx2)) == 2
    # a plane verified by its position only: no height, every area a candidate
    positioned = dataclasses.replace(ground, support=False)
    ctx3 = MapContext.build(disp, valid, segmented, positioned, cfg)
    assert ctx3.ground_height is None and len(standing_areas(result.areas, labels, stats, ctx3)) == 2
