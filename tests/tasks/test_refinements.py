"""Refinements of the object areas and the input: box refinement, segment merging, speckles."""

from __future__ import annotations

import pytest
import torch

from somtorch.disparity.filters import remove_speckles
from somtorch.tasks.objects import AreaConfig, ObjectArea, find_object_areas, neuron_stats, select_areas
from somtorch.tasks.context import MapContext
from somtorch.tasks.detect import find_objects, kept_areas
from somtorch.tasks.refine import box_purity, merge_adjacent, refine_box, solidity
from somtorch.tasks.reduction import valid_integral


def _area(neurons, box, mean_d=50.0, contrast=40.0):
    return ObjectArea(neurons=neurons, pixels=1, box=box, mean_disparity=mean_d, contrast=contrast, area_frac=0.1)


def test_refine_box_drops_a_stray_fragment_but_keeps_the_body():
    labels = torch.full((100, 100), 1, dtype=torch.long)
    labels[20:60, 30:70] = 0  # the object's segment: a 40x40 block ...
    labels[95:97, 2:4] = 0  # ... plus a 2x2 stray fragment far away (0.25 % of its pixels)
    area = _area([0], (2, 20, 69, 96))
    tight = refine_box(area, labels, coverage=0.99, quantile=0.0)
    assert tight.box == (30, 20, 69, 59)
    assert tight.segment_box == (2, 20, 69, 96)
    # coverage 1.0 keeps every piece: the paper's box of all segment pixels
    assert refine_box(area, labels, coverage=1.0, quantile=0.0, drop_specks=False) is area


def test_refine_box_quantile_ignores_a_thin_protrusion():
    labels = torch.full((200, 200), 1, dtype=torch.long)
    labels[100:180, 40:160] = 0  # 9,600 px body
    labels[95:100, 100] = 0  # a 1-px wide, 5 px long antenna on top (0.05 % of the pixels), connected
    area = _area([0], (40, 95, 159, 179))
    assert refine_box(area, labels, coverage=1.0, quantile=0.0, drop_specks=False) is area
    trimmed = refine_box(area, labels, coverage=1.0, quantile=0.001)  # 0.1 % = 9.6 px per side
    assert trimmed.box == (40, 100, 159, 179)  # the antenna is cut, a body edge (80 or 120 px) is not
    assert refine_box(area, labels, coverage=1.0, quantile=0.0001).box == area.box  # 1 px: kept


def test_the_box_edges_are_numpys_inverted_cdf_quantiles_of_the_kept_pixels():
    # refine_box reads the quantile edges off the mask's column and row sums; they must be the order
    # statistics numpy.quantile(..., method="inverted_cdf") picks from every pixel's coordinate,
    # including its index arithmetic at n·q whole or fractional, one pixel, and q = 0 (min / max)
    import numpy as np

    from somtorch.tasks.refine import _quantile_edges

    rng = np.random.default_rng(7)
    checked = 0
    for t in range(400):
        h, w = (int(v) for v in rng.integers(1, 70, 2))
        mask = rng.random((h, w)) < [0.002, 0.05, 0.5, 0.999][t % 4]
        if t % 7 == 0:
            mask[:] = False
            mask[int(rng.integers(0, h)), int(rng.integers(0, w))] = True
        if not mask.any():
            continue
        ys, xs = np.nonzero(mask)
        for q in (0.0, 0.001, 0.005, 0.01, 0.25, 1 / 3, 0.5):
            for coords, counts in ((xs, mask.sum(0)), (ys, mask.sum(1))):
                want = (coords.min(), coords.max()) if q == 0 else \
                    np.quantile(coords, [q, 1 - q], method="inverted_cdf")
                assert _quantile_edges(counts, q) == tuple(int(v) for v in want), (t, q)
                checked += 1
    assert checked > 4000
    # counts in the thousands per coordinate: n·q far from whole numbers and exactly on them
    for n_each in (1, 3, 999, 1000, 4096):
        counts = np.full(37, n_each)
        coords = np.repeat(np.arange(37), n_each)
        for q in (0.001, 0.01, 0.1):
            assert _quantile_edges(counts, q) == tuple(
                int(v) for v in np.quantile(coords, [q, 1 - q], method="inverted_cdf"))


def test_refine_box_leaves_out_pieces_flat_on_the_ground_plane():
    labels = torch.full((120, 160), 1, dtype=torch.long)
    residual = torch.full((120, 160), 5.0)  # |disparity - ground plane| in px
    labels[30:70, 40:80] = 0  # the object: well off the plane
    labels[100:110, 100:150] = 0  # a floor streak with the object's disparity, on the plane
    residual[100:110, 100:150] = 0.3
    area = _area([0], (40, 30, 149, 109))
    kept = refine_box(area, labels, coverage=1.0, quantile=0.0, ground_residual=residual, clutter_band=1.0)
    assert kept.box == (40, 30, 79, 69)
    assert kept.ground_clutter_pieces == 1
    # a band narrower than the streak's residual keeps it; no plane keeps it
    assert refine_box(area, labels, coverage=1.0, quantile=0.0, ground_residual=residual, clutter_band=0.2) \
        .box == area.box
    assert refine_box(area, labels, coverage=1.0, quantile=0.0, ground_residual=None, clutter_band=1.0,
                      drop_specks=False) is area
    # an area lying wholly on the plane is left as it is (nothing would remain)
    flat = torch.full((120, 160), 0.1)
    assert refine_box(area, labels, coverage=1.0, quantile=0.0, ground_residual=flat, clutter_band=1.0).box == area.box


def _stats_of(labels, disp):
    return neuron_stats(labels, disp, int(labels.max()) + 1)


def test_merge_adjacent_joins_a_touching_segment_of_similar_depth_only():
    # background 10 px; the object: segment 0 (50 px) and its front part, segment 1 (56 px);
    # segment 2 touches segment 0 but lies at the background's depth; segment 3 (54 px) is near but
    # does not touch the object
    disp = torch.full((60, 90), 10.0)
    labels = torch.full((60, 90), 4, dtype=torch.long)
    labels[10:30, 10:30], disp[10:30, 10:30] = 0, 50.0
    labels[30:45, 10:30], disp[30:45, 10:30] = 1, 56.0
    labels[10:30, 30:40], disp[10:30, 30:40] = 2, 12.0
    labels[10:30, 60:80], disp[10:30, 60:80] = 3, 54.0
    stats = _stats_of(labels, disp)
    kept = [_area([0], (10, 10, 29, 29), mean_d=50.0, contrast=40.0)]
    merged = merge_adjacent(kept, stats, ratio=0.75)
    assert len(merged) == 1
    assert merged[0].neurons == [0, 1]
    assert merged[0].box == (10, 10, 29, 44)
    assert merged[0].pixels == 400 + 300
    assert abs(merged[0].mean_disparity - (50 * 400 + 56 * 300) / 700) < 1e-9
    assert merged[0].merged_segments == 1
    # ratio 0 is off; a ratio too small for the 6 px step joins nothing
    assert merge_adjacent(kept, stats, ratio=0.0) is kept
    assert merge_adjacent(kept, stats, ratio=0.1)[0] is kept[0]


def test_merge_adjacent_drops_a_kept_area_absorbed_by_a_better_one():
    disp = torch.full((40, 60), 10.0)
    labels = torch.full((40, 60), 2, dtype=torch.long)
    labels[5:20, 5:25], disp[5:20, 5:25] = 0, 50.0
    labels[20:35, 5:25], disp[20:35, 5:25] = 1, 52.0
    stats = _stats_of(labels, disp)
    first = _area([0], (5, 5, 24, 19), mean_d=50.0, contrast=40.0)
    second = _area([1], (5, 20, 24, 34), mean_d=52.0, contrast=42.0)
    merged = merge_adjacent([first, second], stats, ratio=0.75)
    assert [a.neurons for a in merged] == [[0, 1]]
    assert merged[0].rank == 0


def test_remove_speckles_drops_small_islands_only():
    disp = torch.full((100, 100), 20.0) + torch.linspace(0, 10, 100)[None, :]  # smooth plane
    disp[50:53, 50:53] = 90.0  # a 9-pixel speckle
    disp[10:40, 60:90] = 70.0  # a 900-pixel object
    valid = torch.ones(100, 100, dtype=torch.bool)
    out = remove_speckles(disp, valid, max_size_frac=0.005, max_diff_frac=0.02)  # speckles < 50 px
    assert not out[50:53, 50:53].any()
    assert out[10:40, 60:90].all()
    assert int((~out).sum()) == 9
    assert torch.equal(remove_speckles(disp, valid, max_size_frac=0.0), valid)  # 0 = off
    assert not remove_speckles(disp, ~valid).any()  # nothing valid stays nothing


def test_box_purity_is_the_share_of_the_boxs_valid_pixels_that_are_the_areas_own():
    labels = torch.zeros(40, 40, dtype=torch.long)
    labels[10:20, 10:30] = 1  # 200 px of the area ...
    valid = torch.ones(40, 40, dtype=torch.bool)
    valid[10:20, 20:30] = False  # ... of which 100 have no disparity (and count in neither)
    labels[~valid] = -1
    ii = valid_integral(valid)
    assert box_purity(_area([1], (10, 10, 29, 19)), labels, ii) == 1.0
    assert box_purity(_area([1], (10, 10, 29, 29)), labels, ii) == 100 / (100 + 10 * 20)
    own = labels == 1  # the caller's mask of the area's pixels gives the same share
    assert box_purity(_area([1], (10, 10, 29, 29)), labels, ii, own) == 100 / (100 + 10 * 20)


def _speckles_and_object():
    # background (segment 0) at 10 px; a compact object (segment 1) at 40 px; an area of isolated
    # speckles (segment 2, every 6th pixel of a 60 x 30 region) at 90 px: more contrast than the object
    h, w = 60, 80
    disp = torch.full((h, w), 10.0)
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[20:40, 10:30], disp[20:40, 10:30] = 1, 40.0
    labels[0:60:6, 50:80:6], disp[0:60:6, 50:80:6] = 2, 90.0
    stats = neuron_stats(labels, disp, 3)
    areas = find_object_areas(torch.tensor([10.0, 40.0, 90.0]), None, stats, AreaConfig())
    return labels, disp, stats, areas


def _ctx(labels, disp, valid=None, cfg=None):
    valid = torch.ones_like(labels, dtype=torch.bool) if valid is None else valid
    return MapContext.build(disp, valid, labels >= 0, None, cfg or AreaConfig())


def test_kept_areas_skips_a_speckle_area_whose_box_is_mostly_other_pixels():
    labels, disp, stats, areas = _speckles_and_object()
    ctx = _ctx(labels, disp)
    ranked = select_areas(areas, stats, AreaConfig(max_areas=3))
    assert ranked[0].neurons == [2]  # the speckles rank first by contrast x size
    kept = kept_areas(areas, stats, labels, AreaConfig(), ctx)
    assert [a.neurons for a in kept] == [[1]]
    assert kept[0].box == (10, 20, 29, 39) and kept[0].purity == 1.0
    assert 0 < kept[0].confidence < 1  # ranked below the speckles
    # without the test (min_purity 0, the paper's behaviour) the speckles are kept
    off = kept_areas(areas, stats, labels, AreaConfig(min_purity=0.0, min_solidity=0.0), ctx)
    assert [a.neurons for a in off] == [[2]] and off[0].purity < 0.05 and off[0].confidence == 1.0
    # the paper's rule keeps its nearest area (the speckles) even where it fails the checks ...
    cfg = AreaConfig(rule="paper")
    assert [a.neurons for a in kept_areas(areas, stats, labels, cfg, ctx)] == [[2]]
    # ... the salient rule, a single candidate allowed, nothing: find_objects keeps the whole map, flagged
    cfg = AreaConfig(max_areas=1)
    assert kept_areas(areas, stats, labels, cfg, ctx) == []
    found = find_objects(labels, torch.tensor([10.0, 40.0, 90.0]), None, ctx, cfg)
    assert found.no_object and len(found.kept) == 1
    assert found.kept[0].box == (0, 0, labels.shape[1] - 1, labels.shape[0] - 1) and found.kept[0].confidence == 0.0
    # when something passes, find_objects is kept_areas with the statistics computed for it
    found = find_objects(labels, torch.tensor([10.0, 40.0, 90.0]), None, ctx, AreaConfig())
    assert not found.no_object and [(a.neurons, a.box) for a in found.kept] == [(a.neurons, a.box) for a in kept]


def test_every_ranked_candidate_carries_what_became_of_it():
    labels, disp, stats, areas = _speckles_and_object()
    ctx = _ctx(labels, disp)
    trace = []
    kept = kept_areas(areas, stats, labels, AreaConfig(), ctx, trace=trace)
    assert [c.area.neurons for c in trace] == [a.neurons for a in select_areas(areas, stats, AreaConfig())]
    assert [c.rank for c in trace] == list(range(len(trace))) and trace[0].score > trace[1].score
    # the speckles first, refused by the purity check (its figure and the threshold named), the object kept
    assert trace[0].area.neurons == [2] and trace[0].verdict.startswith("refused: purity 0.")
    assert "< min_purity 0.15" in trace[0].verdict
    assert trace[1].area.neurons == [1] and trace[1].verdict == "kept" and [a.neurons for a in kept] == [[1]]
    assert [c.outcome for c in trace] == ["refused", "kept"]
    # one area allowed and it fails: the rest is not tried, and find_objects says so in its fallback too
    found = find_objects(labels, torch.tensor([10.0, 40.0, 90.0]), None, ctx, AreaConfig(max_areas=1))
    assert found.no_object and [c.verdict.split(":")[0] for c in found.candidates] == ["refused"]
    # the trace records and never decides: the kept areas are the same with and without it
    assert [(a.neurons, a.box) for a in kept_areas(areas, stats, labels, AreaConfig(), ctx)] == \
        [(a.neurons, a.box) for a in kept]


def test_a_candidate_over_the_keep_budget_is_skipped_with_the_share_it_would_take():
    h, w = 120, 160
    disp = torch.full((h, w), 10.0)
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[10:110, 5:75], disp[10:110, 5:75] = 1, 40.0  # a large object: 36 % of the map
    labels[60:100, 100:140], disp[60:100, 100:140] = 2, 38.0  # a smaller one
    stats = neuron_stats(labels, disp, 3)
    areas = find_object_areas(torch.tensor([10.0, 40.0, 38.0]), None, stats, AreaConfig())
    ctx = _ctx(labels, disp)
    trace = []
    kept = kept_areas(areas, stats, labels, AreaConfig(keep_budget=0.4), ctx, trace=trace)
    assert [a.neurons for a in kept] == [[1]]  # the first area is always kept; the second breaks the budget
    verdicts = {tuple(c.area.neurons): c.verdict for c in trace}
    assert verdicts[(1,)] == "kept"
    assert verdicts[(2,)].startswith("skipped: the kept boxes would hold ") and verdicts[(2,)].endswith(
        "% of the valid pixels > keep_budget 40 %")
    share = int(verdicts[(2,)].split("hold ")[1].split(" %")[0])
    assert 40 < share <= 60
    trace = []  # with room for both, both are kept, and the trace says so
    assert len(kept_areas(areas, stats, labels, AreaConfig(keep_budget=1.0), ctx, trace=trace)) == 2
    assert [c.verdict for c in trace] == ["kept", "kept"]


def test_kept_areas_keeps_further_areas_up_to_max_areas_with_their_relative_score():
    # two compact objects of similar contrast and size: both kept with max_areas=2
    h, w = 120, 160
    disp = torch.full((h, w), 10.0)
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[20:60, 10:50], disp[20:60, 10:50] = 1, 40.0
    labels[60:100, 100:140], disp[60:100, 100:140] = 2, 38.0
    stats = neuron_stats(labels, disp, 3)
    areas = find_object_areas(torch.tensor([10.0, 40.0, 38.0]), None, stats, AreaConfig())
    ctx = _ctx(labels, disp)
    one = kept_areas(areas, stats, labels, AreaConfig(max_areas=1), ctx)
    assert [a.neurons for a in one] == [[1]]
    assert [a.neurons for a in kept_areas(areas, stats, labels, AreaConfig(), ctx)] == [[1], [2]]  # the default
    two = kept_areas(areas, stats, labels, AreaConfig(max_areas=2), ctx)
    assert [a.neurons for a in two] == [[1], [2]] and [a.rank for a in two] == [0, 1]
    assert two[0].confidence == 1.0 and 0.5 <= two[1].confidence < 1.0  # its score over the best one's


def test_solidity_is_one_for_a_solid_region_and_zero_for_streaks_and_speckles():
    h, w = 200, 300  # square side: 2 % of 200 = 4 px, rounded up to 5 (odd)
    block = torch.zeros(h, w, dtype=torch.bool)
    block[40:100, 50:150] = True
    assert solidity(block) == 1.0
    streaks = torch.zeros(h, w, dtype=torch.bool)
    streaks[0:60:4, 100:250] = True  # 1 px high lines, 4 px apart (SGBM on a ceiling)
    assert solidity(streaks) == 0.0
    speckles = torch.zeros(h, w, dtype=torch.bool)
    speckles[::6, ::6] = True
    assert solidity(speckles) == 0.0
    assert solidity(torch.zeros(h, w, dtype=torch.bool)) == 0.0
    both = block | streaks
    assert solidity(both) == pytest.approx(float(block.sum()) / float(both.sum()))
    sampled = both[::2, ::2]  # on every 2nd pixel: the square counted in samples (2, rounded up to 3)
    assert solidity(both, stride=2) == pytest.approx(float(block[::2, ::2].sum()) / float(sampled.sum()))
    # a larger square (10 % of 200 = 20 px, 21) does not fit into an 18 px high bar
    bar = torch.zeros(h, w, dtype=torch.bool)
    bar[40:58, 20:280] = True
    assert solidity(bar) == 1.0 and solidity(bar, size=0.1) == 0.0


def _streaks_and_object():
    # background (segment 0) at 10 px; a compact object (segment 1) at 40 px; 1 px high streaks
    # (segment 2) at 90 px with no disparity between them, so their box is all their own valid pixels
    h, w = 120, 160
    disp = torch.full((h, w), 10.0)
    valid = torch.ones(h, w, dtype=torch.bool)
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[60:100, 20:60], disp[60:100, 20:60] = 1, 40.0
    valid[0:30, 80:150] = False
    labels[0:30, 80:150] = -1
    labels[0:30:3, 80:150], disp[0:30:3, 80:150], valid[0:30:3, 80:150] = 2, 90.0, True
    stats = neuron_stats(labels, disp, 3)
    areas = find_object_areas(torch.tensor([10.0, 40.0, 90.0]), None, stats, AreaConfig())
    return labels, valid, stats, areas


def test_kept_areas_skips_thin_streaks_by_their_solidity():
    labels, valid, stats, areas = _streaks_and_object()
    disp = torch.where(labels == 2, 90.0, torch.where(labels == 1, 40.0, 10.0))
    ctx = _ctx(labels, disp, valid)
    ranked = select_areas(areas, stats, AreaConfig(max_areas=3))
    assert ranked[0].neurons == [2]  # the streaks rank first
    kept = kept_areas(areas, stats, labels, AreaConfig(), ctx)
    assert [a.neurons for a in kept] == [[1]] and kept[0].solidity > 0.9
    # the purity test alone does not catch them: their box holds no other valid pixel
    off = kept_areas(areas, stats, labels, AreaConfig(min_solidity=0.0), ctx)
    assert [a.neurons for a in off][0] == [2]  # kept first (the object may follow within the budget)
    assert off[0].purity == 1.0 and off[0].solidity == 0.0


def test_refine_box_drops_a_band_of_speckles_but_keeps_thin_parts_of_a_solid_piece():
    labels = torch.full((120, 160), 1, dtype=torch.long)
    labels[40:100, 60:120] = 0  # the object: a solid block ...
    labels[100:118, 70:72] = 0  # ... with a 2-px leg attached to it
    g = torch.Generator().manual_seed(0)
    band = torch.rand(6, 160, generator=g) < 0.3  # a sparse band of specks along the top border
    labels[:6][band] = 0
    area = _area([0], (0, 0, 159, 117))
    plain = refine_box(area, labels, coverage=1.0, quantile=0.0, drop_specks=False)
    assert plain.box[1] == 0  # the specks drag the box to the border
    clean = refine_box(area, labels, coverage=1.0, quantile=0.0, drop_specks=True)
    assert clean.box == (60, 40, 119, 117)  # the leg stays: it belongs to the solid piece
    # nothing solid at all: the area is left as it is
    specks = torch.full((50, 50), 1, dtype=torch.long)
    specks[::4, ::4] = 0
    sp = _area([0], (0, 0, 48, 48))
    assert refine_box(sp, specks, coverage=1.0, quantile=0.0, drop_specks=True).box == (0, 0, 48, 48)


def test_kept_areas_reads_each_candidates_window_with_the_whole_maps_result():
    """kept_areas refines and checks each candidate on the window of its segments (widened by half
    the solidity square where the map goes on) instead of the whole map: boxes, purity and solidity
    must be those of the whole-map computation, for areas inside the image and at its border (where
    OpenCV's opening treats the outside as part of the mask)."""
    from dataclasses import replace

    from somtorch.tasks.detect import _window
    from somtorch.tasks.objects import label_mask
    from somtorch.tasks.refine import _opened_share, solidity_square

    h, w = 90, 120
    labels = torch.full((h, w), 3, dtype=torch.long)  # the background
    labels[30:60, 40:70] = 0  # a block with a 2 px thin line along the top of its box, running on to
    labels[28:30, 40:80] = 0  # the box's right edge: the opening removes the line on the whole map
    labels[0:30, 0:12] = 1  # an area at the image's corner, and one with specks in its box
    labels[70:85, 90:110] = 2
    labels[72:84:3, 92:108:4] = -1
    disp = torch.full((h, w), 5.0, dtype=torch.float64)
    disp[labels == 0], disp[labels == 1], disp[labels == 2] = 30.0, 20.0, 40.0
    valid = labels >= 0
    cfg = AreaConfig(min_purity=0.0, min_solidity=0.0, keep_budget=1.0, merge=0.0)
    ctx = MapContext.build(disp, valid, valid, None, cfg)
    stats = neuron_stats(labels, disp, 4)
    areas = [a for a in find_object_areas(stats.mean_d, None, stats, cfg) if 3 not in a.neurons]
    kept = kept_areas(areas, stats, labels, cfg, ctx)
    assert sorted(a.neurons for a in kept) == [[0], [1], [2]]
    square = solidity_square(labels.shape, cfg.solidity_size, 1)
    for a in kept:
        own = label_mask(labels, a.neurons)
        full = refine_box(replace(a, box=a.segment_box or a.box), labels, coverage=cfg.box_coverage,
                          quantile=cfg.box_quantile, mask=own)
        assert a.box == full.box
        assert a.purity == box_purity(a, labels, ctx.integral, own)
        assert a.solidity == _opened_share(own, square)
    line = next(a for a in kept if a.neurons == [0])
    assert line.solidity < 1.0  # the line is opened away (on the box alone it would not be)
    x0, y0, x1, y1 = 40, 28, 79, 59
    assert _opened_share(label_mask(labels[y0:y1 + 1, x0:x1 + 1], [0]), square) > line.solidity
    win, origin = _window((0, 0, 11, 29), (h, w), 4)
    assert origin == (0, 0) and (win[0].stop, win[1].stop) == (34, 16)


def test_the_keep_budget_counts_each_box_with_the_reductions_margins():
    """A further area is kept only if the union of the boxes *as the reduced map keeps them* (each
    widened by the reduction's margins) fits the budget: two boxes holding 25 % of a 200 x 200 map
    fit a 28 % budget bare, but not with a margin of 1.5 % of the diagonal on every side (31 %)."""
    from somtorch.config import ReductionConfig
    from somtorch.tasks.reduction import reduce_map

    h = w = 200
    disp = torch.full((h, w), 10.0)
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[20:80, 20:80], disp[20:80, 20:80] = 1, 60.0  # 9 % of the map, ranked first
    labels[100:180, 100:180], disp[100:180, 100:180] = 2, 40.0  # 16 %
    valid = torch.ones(h, w, dtype=torch.bool)
    cfg = AreaConfig(keep_budget=0.28)
    stats = neuron_stats(labels, disp, 3)
    areas = find_object_areas(torch.tensor([10.0, 60.0, 40.0]), None, stats, cfg)
    bare = MapContext.build(disp, valid, labels >= 0, None, cfg, ReductionConfig(tolerance_image=0.0))
    assert [a.neurons for a in kept_areas(areas, stats, labels, cfg, bare)] == [[1], [2]]
    ctx = MapContext.build(disp, valid, labels >= 0, None, cfg)  # the default margins
    kept = kept_areas(areas, stats, labels, cfg, ctx)
    assert [a.neurons for a in kept] == [[1]]
    both = reduce_map([(20, 20, 79, 79), (100, 100, 179, 179)], valid)  # what keeping both would keep
    assert both.kept_union > 0.28 * h * w > 0.25 * h * w
    # a margin in px shrinks with the stride of the map the object step reads; the shares do not
    half = MapContext.build(disp, valid, labels >= 0, None, cfg, ReductionConfig(tolerance_px=4.0), stride=2)
    assert half.margins == (2.0, 0.0, 0.015)
