"""Tests of somtorch.tasks.reduction (paper step 1d): boxes, tolerance, union vs crops."""

from __future__ import annotations

import pytest
import torch

from somtorch.tasks.reduction import expand_box, reduce_map


def _all_valid(h: int = 20, w: int = 30) -> torch.Tensor:
    return torch.ones(h, w, dtype=torch.bool)


def test_a_box_without_tolerance_keeps_exactly_its_pixels():
    r = reduce_map([(3, 2, 12, 6)], _all_valid(), tolerance_frac=0.0, tolerance_image=0.0)
    assert r.boxes == [(3, 2, 12, 6)]
    assert r.kept_union == r.kept_crops == 10 * 5
    assert r.valid_total == 600
    assert r.reduction_union == pytest.approx(100 * (1 - 50 / 600))
    expected = torch.zeros(20, 30, dtype=torch.bool)
    expected[2:7, 3:13] = True
    assert torch.equal(r.mask, expected)


def test_tolerance_in_px_and_as_a_fraction_of_the_box_side():
    box = (10, 5, 19, 14)  # 10 × 10 px
    assert reduce_map([box], _all_valid(), tolerance_px=2, tolerance_frac=0.0, tolerance_image=0.0).boxes == [(8, 3, 21, 16)]
    assert reduce_map([box], _all_valid(), tolerance_frac=0.1, tolerance_image=0.0).boxes == [(9, 4, 20, 15)]
    assert reduce_map([box], _all_valid(), tolerance_px=1, tolerance_frac=0.2, tolerance_image=0.0).boxes == [(7, 2, 22, 17)]
    wide = (0, 10, 19, 11)  # 20 × 2 px: the margin follows each side's own length
    assert expand_box(wide, (40, 40), tolerance_frac=0.25) == (0, 9, 24, 12)


def test_boxes_are_clipped_to_the_image():
    r = reduce_map([(1, 0, 28, 18)], _all_valid(), tolerance_px=5, tolerance_frac=0.0, tolerance_image=0.0)
    assert r.boxes == [(0, 0, 29, 19)]
    assert r.kept_union == 600 and r.reduction_union == 0.0
    assert expand_box((25, 15, 29, 19), (20, 30), tolerance_px=100) == (0, 0, 29, 19)


def test_only_valid_pixels_count():
    valid = _all_valid()
    valid[:, :15] = False
    r = reduce_map([(10, 0, 19, 9)], valid, tolerance_frac=0.0, tolerance_image=0.0)
    assert r.valid_total == 300
    assert r.kept_union == r.kept_crops == 5 * 10
    assert bool(r.mask[0, 10]) and not bool(valid[0, 10])  # the mask is geometric, counts are of valid pixels


def test_overlapping_boxes_count_once_in_the_union_and_twice_as_crops():
    r = reduce_map([(0, 0, 9, 9), (5, 5, 14, 14)], _all_valid(), tolerance_frac=0.0, tolerance_image=0.0)
    assert r.kept_union == 100 + 100 - 25
    assert r.kept_crops == 200 > r.kept_union
    assert r.crops_valid == [100, 100]
    assert r.reduction_crops < r.reduction_union


def test_crops_reduction_can_be_negative():
    valid = torch.zeros(20, 30, dtype=torch.bool)
    valid[:11, :11] = True  # 121 valid pixels, almost all inside both boxes
    r = reduce_map([(0, 0, 9, 9), (1, 1, 10, 10)], valid, tolerance_frac=0.0, tolerance_image=0.0)
    assert r.kept_union == 119 and r.kept_crops == 200
    assert r.reduction_union == pytest.approx(100 * (1 - 119 / 121))
    assert r.reduction_crops == pytest.approx(100 * (1 - 200 / 121))
    assert r.reduction_crops < 0


def test_no_box_keeps_nothing():
    r = reduce_map([], _all_valid(), tolerance_image=0.0)
    assert r.kept_union == r.kept_crops == 0 and r.boxes == [] and not bool(r.mask.any())
    assert r.reduction_union == 100.0


@pytest.mark.parametrize("n_boxes", [1, 2, 3, 12])
def test_integral_image_counts_equal_brute_force_mask_sums(n_boxes):
    # the union's count is read off the integral image for one box and inside the boxes' common
    # extent for several: both must equal the whole map's mask sum
    for seed in range(6):
        g = torch.Generator().manual_seed(7 + seed)
        h, w = 53, 71
        valid = torch.rand(h, w, generator=g) > 0.35
        boxes = []
        for _ in range(n_boxes):
            x0, x1 = sorted(torch.randint(0, w, (2,), generator=g).tolist())
            y0, y1 = sorted(torch.randint(0, h, (2,), generator=g).tolist())
            boxes.append((x0, y0, x1, y1))
        r = reduce_map(boxes, valid, tolerance_px=1.5, tolerance_frac=0.1, tolerance_image=0.0)
        union = torch.zeros(h, w, dtype=torch.bool)
        for (x0, y0, x1, y1), n in zip(r.boxes, r.crops_valid, strict=True):
            assert 0 <= x0 <= x1 < w and 0 <= y0 <= y1 < h
            assert n == int(valid[y0:y1 + 1, x0:x1 + 1].sum())
            union[y0:y1 + 1, x0:x1 + 1] = True
        assert torch.equal(r.mask, union)
        assert r.kept_union == int((union & valid).sum())
        assert r.kept_crops == sum(r.crops_valid)
        assert r.valid_total == int(valid.sum())


def test_reduce_map_rejects_bad_arguments():
    with pytest.raises(TypeError, match="valid has dtype"):
        reduce_map([(0, 0, 1, 1)], torch.ones(4, 4))
    with pytest.raises(ValueError, match="valid must have 2 dimensions"):
        reduce_map([(0, 0, 1, 1)], torch.ones(1, 4, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match="tolerance_px"):
        reduce_map([(0, 0, 1, 1)], _all_valid(), tolerance_px=-1, tolerance_image=0.0)
    with pytest.raises(ValueError, match="tolerance_frac"):
        reduce_map([(0, 0, 1, 1)], _all_valid(), tolerance_frac=float("inf"), tolerance_image=0.0)


@pytest.mark.parametrize("box", [(10, 0, 5, 5), (40, 0, 45, 5)], ids=["inverted", "outside"])
def test_reduce_map_rejects_boxes_that_are_inverted_or_outside_the_image(box):
    with pytest.raises(ValueError, match="box"):
        reduce_map([box], _all_valid(), tolerance_frac=0.0, tolerance_image=0.0)


def test_image_tolerance_is_a_fraction_of_the_image_diagonal_for_every_box():
    valid = torch.ones(30, 40, dtype=torch.bool)  # diagonal 50 px: 2 % = 1 px
    small, large = (10, 10, 11, 11), (5, 5, 34, 24)
    r = reduce_map([small, large], valid, tolerance_frac=0.0, tolerance_image=0.02)
    assert r.boxes == [(9, 9, 12, 12), (4, 4, 35, 25)]  # the same 1 px margin whatever the box size
    # it adds to the other two margins
    assert reduce_map([small], valid, tolerance_px=1, tolerance_frac=0.5, tolerance_image=0.02).boxes == [(7, 7, 14, 14)]
    with pytest.raises(ValueError, match="tolerance_image"):
        reduce_map([small], valid, tolerance_image=-0.1)


def test_a_precomputed_integral_gives_the_same_reduction_and_must_fit_the_mask():
    from somtorch.tasks.reduction import valid_integral

    valid = torch.rand(30, 40, generator=torch.Generator().manual_seed(3)) > 0.3
    boxes = [(2, 3, 20, 12), (15, 10, 39, 29)]
    plain = reduce_map(boxes, valid, tolerance_image=0.02)
    shared = reduce_map(boxes, valid, tolerance_image=0.02, integral=valid_integral(valid))
    assert (shared.boxes, shared.kept_union, shared.kept_crops, shared.crops_valid) == \
        (plain.boxes, plain.kept_union, plain.kept_crops, plain.crops_valid)
    with pytest.raises(ValueError, match="integral has shape"):
        reduce_map(boxes, valid, integral=valid_integral(valid[:, :-1]), tolerance_image=0.0)


def test_the_integral_image_is_the_cumulative_sums_of_the_mask():
    """valid_integral (OpenCV's integral on the CPU) holds the same int32 sums as the two cumulative
    sums that define it: on random masks, views of them, empty, full and one-pixel masks."""
    from somtorch.tasks.reduction import valid_integral

    g = torch.Generator().manual_seed(4)
    masks = [torch.rand(h, w, generator=g) < p for h, w, p in ((1, 1, 0.5), (3, 200, 0.3), (97, 131, 0.9),
                                                                 (240, 320, 0.5))]
    masks += [masks[-1][::3, 1::2], masks[-1].T, torch.zeros(5, 7, dtype=torch.bool),
              torch.ones(6, 4, dtype=torch.bool), torch.zeros(0, 3, dtype=torch.bool)]
    for m in masks:
        want = torch.zeros(m.shape[0] + 1, m.shape[1] + 1, dtype=torch.int32)
        want[1:, 1:] = m.to(torch.int32).cumsum(0, dtype=torch.int32).cumsum(1, dtype=torch.int32)
        got = valid_integral(m)
        assert got.dtype == torch.int32 and torch.equal(got, want), tuple(m.shape)
