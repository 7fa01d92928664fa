"""Tests of somtorch.tasks.objects on hand-built label maps (paper step 1c, Fig. 15).

A "block map" gives every neuron k = r·cols + c of an R×C SOM one B×B block of the image at block
(r, c), painted with the neuron's reference disparity, so segment statistics are known by hand.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from somtorch.core.grid import grid_sqdist
from somtorch.tasks.objects import (AreaConfig, ObjectArea, disparity_spread, find_object_areas, neuron_stats,
                                    select_areas, surround_pairs)

ROWS, COLS, B = 4, 7, 5
# the paper preset (conf/objects/paper.yaml): grid links, full-range spread, 10 % similarity, nearest area
PAPER = dict(rule="paper", similarity=0.1)


def _block_map(ref: torch.Tensor, rows: int = ROWS, cols: int = COLS, b: int = B
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Label map ``(rows·b, cols·b)`` with neuron r·cols+c on block (r, c), and its disparity map."""
    r = torch.arange(rows * b)[:, None] // b
    c = torch.arange(cols * b)[None, :] // b
    labels = (r * cols + c).long()
    return labels, ref.double()[labels]


def _areas(ref: torch.Tensor, cfg: AreaConfig, rows: int = ROWS, cols: int = COLS):
    labels, disp = _block_map(ref, rows, cols)
    stats = neuron_stats(labels, disp, rows * cols)
    return find_object_areas(ref, grid_sqdist(rows, cols), stats, cfg), stats


def _neuron_sets(areas) -> set[frozenset[int]]:
    return {frozenset(a.neurons) for a in areas}


def _fig15_ref() -> torch.Tensor:
    """Row 0: a plateau at 50 (neurons 0–2), a disturbed neuron 3 at 10, the same plateau again (4–6);
    every other neuron at 10."""
    ref = torch.full((ROWS * COLS,), 10.0)
    ref[[0, 1, 2, 4, 5, 6]] = 50.0
    return ref


# ------------------------------------------------------------------------------ object areas


def test_a_disturbed_neuron_separates_two_plateaus_of_equal_disparity():
    areas, _ = _areas(_fig15_ref(), AreaConfig(**PAPER))
    rest = frozenset(range(ROWS * COLS)) - {0, 1, 2, 4, 5, 6}
    assert _neuron_sets(areas) == {frozenset({0, 1, 2}), frozenset({4, 5, 6}), rest}
    left = next(a for a in areas if 0 in a.neurons)
    # the neurons beyond the disturbed one have the same disparity but are not in the area (Fig. 15)
    assert not {4, 5, 6} & set(left.neurons)
    assert left.pixels == 3 * B * B
    assert left.box == (0, 0, 3 * B - 1, B - 1)
    assert left.mean_disparity == pytest.approx(50.0)
    assert left.area_frac == pytest.approx(3 / 28)
    assert sum(a.pixels for a in areas) == ROWS * COLS * B * B
    assert sum(a.area_frac for a in areas) == pytest.approx(1.0)


def test_similarity_threshold_is_a_fraction_of_the_disparity_range():
    ref = torch.full((ROWS * COLS,), 10.0)
    ref[0], ref[1] = 50.0, 47.0  # |Δ| = 3 against a range of 40

    def near(similarity: float):
        return next(a for a in _areas(ref, AreaConfig(**{**PAPER, "similarity": similarity}))[0] if 0 in a.neurons)

    assert set(near(0.1).neurons) == {0, 1}  # 3 < 0.1 · 40
    assert set(near(0.05).neurons) == {0}  # 3 ≥ 0.05 · 40


def test_the_grid_link_joins_row_and_column_neighbours_not_diagonal_ones():
    ref = torch.full((ROWS * COLS,), 10.0)
    ref[0] = ref[COLS + 1] = 50.0  # (0, 0) and (1, 1): diagonal neighbours
    areas, _ = _areas(ref, AreaConfig(**PAPER))
    assert {frozenset({0}), frozenset({COLS + 1})} <= _neuron_sets(areas)
    ref[1] = 50.0  # (0, 1) is a row neighbour of (0, 0) and a column neighbour of (1, 1)
    areas, _ = _areas(ref, AreaConfig(**PAPER))
    assert frozenset({0, 1, COLS + 1}) in _neuron_sets(areas)
    assert len(areas) == 2  # and the 10-background is one area


def test_neurons_without_pixels_form_no_area():
    ref = _fig15_ref()
    labels, disp = _block_map(ref)
    labels[labels == 5] = 4  # neuron 5 wins no pixel
    labels[labels == 6] = 4
    stats = neuron_stats(labels, disp, ROWS * COLS)
    ref[[5, 6]] = 300.0  # dead neurons with a disparity of their own form their own component
    areas = find_object_areas(ref, grid_sqdist(ROWS, COLS), stats, AreaConfig(**PAPER))
    assert all(a.pixels > 0 for a in areas)
    assert not any({5, 6} & set(a.neurons) for a in areas)
    right = next(a for a in areas if 4 in a.neurons)
    assert right.box == (4 * B, 0, 7 * B - 1, B - 1)  # still the pixels relabelled to 4


# ---------------------------------------------------------------------------------- contrast


def _blob_scene(blob_d: float, back_d: float) -> tuple[list, object]:
    """A 1×2 SOM: neuron 0 the background, neuron 1 a square blob in the middle of a 40×60 image."""
    labels = torch.zeros(40, 60, dtype=torch.long)
    labels[10:20, 20:35] = 1
    disp = torch.where(labels == 1, blob_d, back_d).double()
    stats = neuron_stats(labels, disp, 2)
    ref = torch.tensor([back_d, blob_d])
    return find_object_areas(ref, grid_sqdist(1, 2), stats, AreaConfig(**PAPER)), stats


def test_a_near_blob_on_a_far_background_has_positive_contrast():
    areas, _ = _blob_scene(blob_d=40.0, back_d=10.0)
    blob = next(a for a in areas if a.neurons == [1])
    back = next(a for a in areas if a.neurons == [0])
    assert blob.contrast == pytest.approx(30.0)
    assert back.contrast == pytest.approx(-30.0)
    assert blob.box == (20, 10, 34, 19) and blob.pixels == 150


def test_a_far_blob_on_a_near_background_has_negative_contrast_and_is_not_salient():
    areas, stats = _blob_scene(blob_d=10.0, back_d=40.0)
    blob = next(a for a in areas if a.neurons == [1])
    assert blob.contrast == pytest.approx(-30.0)
    kept = select_areas(areas, stats, AreaConfig())
    assert [a.neurons for a in kept] == [[0]]  # the blob recedes: what stands out is the near surround


def test_isolated_area_without_neighbours_has_zero_contrast():
    labels = torch.zeros(5, 5, dtype=torch.long)
    stats = neuron_stats(labels, torch.full((5, 5), 3.0, dtype=torch.float64), 1)
    (area,) = find_object_areas(torch.tensor([3.0]), grid_sqdist(1, 1), stats, AreaConfig(**PAPER))
    assert area.contrast == 0.0 and area.area_frac == 1.0 and area.box == (0, 0, 4, 4)


def test_surround_pairs_match_a_pixel_by_pixel_reference():
    g = torch.Generator().manual_seed(3)
    h, w = 13, 17
    valid = torch.rand(h, w, generator=g) > 0.15
    segmented = valid & (torch.rand(h, w, generator=g) > 0.4)
    disp = torch.rand(h, w, generator=g, dtype=torch.float64) * 50
    labels = torch.where(segmented, torch.randint(0, 4, (h, w), generator=g), -1)
    idx, d_out = surround_pairs(segmented, valid, disp)
    want = {}
    for y in range(h):
        for x in range(w):
            for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
                yy, xx = y + dy, x + dx
                inside = 0 <= yy < h and 0 <= xx < w
                if inside and segmented[y, x] and valid[yy, xx] and not segmented[yy, xx]:
                    want.setdefault(y * w + x, []).append(float(disp[yy, xx]))
    got = {}
    for i, d in zip(idx.tolist(), d_out.tolist()):
        got.setdefault(i, []).append(d)
    assert {k: sorted(v) for k, v in got.items()} == {k: sorted(v) for k, v in want.items()}
    stats = neuron_stats(labels, disp, 4, surround=(idx, d_out))
    for n in range(4):  # per segment: its pairs with ground pixels behind its own mean disparity
        ref = [d for i, ds in want.items() for d in ds
               if int(labels.view(-1)[i]) == n and d < float(stats.mean_d[n])]
        assert int(stats.ground_count[n]) == len(ref)
        assert float(stats.ground_sum[n]) == pytest.approx(sum(ref))


def _on_ground(obj_d: float, ground_d: float):
    """A square segment (neuron 0) in a map whose every other valid pixel is the cut ground."""
    labels = torch.full((30, 40), -1, dtype=torch.long)
    labels[10:20, 15:25] = 0
    disp = torch.where(labels == 0, obj_d, ground_d).double()
    segmented = labels >= 0
    pairs = surround_pairs(segmented, torch.ones_like(segmented), disp)
    stats = neuron_stats(labels, disp, 1, surround=pairs)
    (area,) = find_object_areas(torch.tensor([obj_d]), grid_sqdist(1, 1), stats, AreaConfig())
    return area, stats


def test_the_ground_behind_an_area_is_its_background_and_the_ground_in_front_says_nothing():
    # an object the ground cut isolates from every segment: seen from above, the floor around it is
    # behind it, which is its contrast; without the ground it had none (nothing to compare with)
    area, stats = _on_ground(obj_d=30.0, ground_d=20.0)
    assert area.contrast == pytest.approx(10.0)
    assert int(stats.ground_count[0]) == 40  # its outline: 4 sides of 10 px
    # ground at or in front of its disparity (the floor before an object's foot) is left out
    area, stats = _on_ground(obj_d=20.0, ground_d=30.0)
    assert area.contrast == 0.0 and int(stats.ground_count[0]) == 0


# --------------------------------------------------------------------------------- selection


def _three_plateaus():
    """Areas at 50 (neurons 0–2, 3/28 of the map), 30 (neuron 27, 1/28) and the 10-background (24/28)."""
    ref = torch.full((ROWS * COLS,), 10.0)
    ref[[0, 1, 2]] = 50.0
    ref[27] = 30.0
    return ref


def test_select_nearest_keeps_the_area_with_the_largest_mean_disparity():
    ref = _three_plateaus()
    areas, stats = _areas(ref, AreaConfig(**PAPER))
    kept = select_areas(areas, stats, AreaConfig(**PAPER))
    assert len(kept) == 1 and set(kept[0].neurons) == {0, 1, 2} and kept[0].rank == 0
    ref[27] = 60.0  # now the corner neuron is nearer
    areas, stats = _areas(ref, AreaConfig(**PAPER))
    (best,) = select_areas(areas, stats, AreaConfig(**PAPER))
    assert best.neurons == [27]
    assert best.mean_disparity == max(a.mean_disparity for a in areas)


def test_select_salient_ranks_by_contrast_and_drops_areas_behind_their_surroundings():
    ref = _three_plateaus()
    cfg = AreaConfig(max_areas=3, size_power=0.0)
    areas, stats = _areas(ref, cfg)
    kept = select_areas(areas, stats, cfg)
    assert [sorted(a.neurons) for a in kept] == [[0, 1, 2], [27]]  # contrast 40 > 20; background < 0
    assert [a.rank for a in kept] == [0, 1]
    assert kept[0].contrast > kept[1].contrast > 0
    assert any(a.contrast < 0 for a in areas)
    capped = dataclasses.replace(cfg, max_areas=1)
    assert [sorted(a.neurons) for a in select_areas(areas, stats, capped)] == [[0, 1, 2]]


# ------------------------------------------------------------------------------ neuron_stats


def test_neuron_stats_match_brute_force():
    g = torch.Generator().manual_seed(11)
    h, w, k = 17, 23, 6
    labels = torch.randint(-1, 5, (h, w), generator=g)  # neuron 5 gets no pixel
    disp = torch.rand(h, w, generator=g, dtype=torch.float64) * 30 + 2
    s = neuron_stats(labels, disp, k)
    for n in range(k):
        m = labels == n
        assert int(s.count[n]) == int(m.sum())
        if m.any():
            ys, xs = m.nonzero(as_tuple=True)
            assert s.box[n].tolist() == [int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())]
            assert float(s.mean_d[n]) == pytest.approx(float(disp[m].mean()))
        else:
            assert s.box[n].tolist() == [w, h, -1, -1]
            assert torch.isnan(s.mean_d[n])
    boundary = torch.zeros(k, k, dtype=torch.float64)
    for y in range(h):
        for x in range(w):
            for yy, xx in ((y, x + 1), (y + 1, x)):
                if yy < h and xx < w:
                    a, b = int(labels[y, x]), int(labels[yy, xx])
                    if a >= 0 and b >= 0 and a != b:
                        boundary[a, b] += 1
                        boundary[b, a] += 1
    torch.testing.assert_close(s.boundary, boundary)
    valid = labels >= 0
    assert s.d_range == (pytest.approx(float(disp[valid].min())), pytest.approx(float(disp[valid].max())))
    # a spread computed once (as the pipeline does for all members) gives the same statistics
    shared = neuron_stats(labels, disp, k, spread=disparity_spread(disp, valid))
    assert (shared.d_range, shared.d_robust) == (s.d_range, s.d_robust)
    assert torch.equal(shared.boundary, s.boundary) and torch.equal(shared.box, s.box)


def test_neuron_stats_rejects_bad_inputs():
    with pytest.raises(TypeError, match="labels has dtype"):
        neuron_stats(torch.zeros(3, 3, dtype=torch.int32), torch.zeros(3, 3), 2)
    with pytest.raises(ValueError, match="differ in shape"):
        neuron_stats(torch.zeros(3, 3, dtype=torch.long), torch.zeros(3, 4), 2)


# -------------------------------------------------------------------------------- AreaConfig


@pytest.mark.parametrize("kwargs", [
    {"similarity": 0.0}, {"similarity": -0.1}, {"similarity": float("nan")},
    {"rule": "diagonal"}, {"rule": "nearest"}, {"max_areas": 0},
    {"size_power": -0.01},
    {"box_quantile": 0.5}, {"box_quantile": -0.01}, {"ground_clutter": -1.0}, {"merge": -0.5},
    {"merge": float("nan")}, {"min_purity": 1.5}, {"min_purity": -0.1},
    {"min_solidity": 1.5}, {"min_solidity": -0.1}, {"min_solidity": float("nan")}, {"solidity_size": 0.0},
    {"solidity_size": 0.6}, {"solidity_size": float("nan")},
])
def test_area_config_rejects_bad_values(kwargs):
    with pytest.raises(ValueError, match="|".join(kwargs)):
        AreaConfig(**kwargs)


def test_area_config_error_lists_the_valid_rules():
    with pytest.raises(ValueError, match="paper, salient"):
        AreaConfig(rule="largest")


def test_area_mask_is_the_union_of_its_segments():
    labels = torch.tensor([[0, 1, 2], [2, -1, 1]])
    area = ObjectArea(neurons=[1, 2], pixels=4, box=(1, 0, 2, 1), mean_disparity=1.0, contrast=0.0, area_frac=0.8)
    assert torch.equal(area.mask(labels), torch.tensor([[False, True, True], [True, False, True]]))
