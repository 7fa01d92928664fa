"""Step 1c: an area whose pixels lie in several regions that the cut ground (session 14) or an
invalid gap wider than the solidity square (session 18) separates is split into them, each part
refined, checked and kept on its own (``somtorch.tasks.detect.kept_areas``, ``docs/validation.md``)."""

from __future__ import annotations

import dataclasses

import torch

from somtorch.config import AreaConfig
from somtorch.tasks.context import MapContext
from somtorch.tasks.detect import find_objects
from somtorch.tasks.ground import GroundPlane
from somtorch.tasks.refine import solidity_square

H, W, FLOOR_D = 80, 120, 5.0


def _floor_with(labels: torch.Tensor, disp: torch.Tensor, cfg: AreaConfig, ground: bool = True):
    valid = torch.ones(H, W, dtype=torch.bool)
    segmented = labels >= 0
    plane = GroundPlane(0.0, 0.0, FLOOR_D, 0.5, valid & ~segmented, float((~segmented).float().mean()), True)
    ctx = MapContext.build(disp, valid, segmented, plane if ground else None, cfg)
    k = int(labels.max()) + 1
    ref = torch.stack([disp[labels == n].mean() for n in range(k)])
    return find_objects(labels, ref.float(), None, ctx, cfg)


def _two_boxes_one_segment():
    """Two boxes standing apart on a floor seen from above, both covered by neuron 0 (one SOM
    segment can hold two objects at the same height), and a lower slab (neuron 1) beside them."""
    labels = torch.full((H, W), -1, dtype=torch.long)
    disp = torch.full((H, W), FLOOR_D, dtype=torch.float64)
    labels[10:30, 10:30] = 0
    labels[40:70, 70:110] = 0
    labels[50:60, 20:40] = 1
    disp[labels == 0], disp[labels == 1] = 20.0, 12.0
    return labels, disp


def test_an_area_split_by_the_cut_ground_keeps_one_box_per_object():
    labels, disp = _two_boxes_one_segment()
    cfg = AreaConfig()
    result = _floor_with(labels, disp, cfg)
    boxes = sorted(a.box for a in result.kept if a.neurons == [0])
    assert boxes == [(10, 10, 29, 29), (70, 40, 109, 69)]  # not one box spanning both
    big, small = sorted((a for a in result.kept if a.neurons == [0]), key=lambda a: -a.pixels)
    assert (big.pixels, small.pixels) == (1200, 400) and big.rank < small.rank
    # without a cut plane the floor is segmented too (neuron 2) and joins the two: one box over both
    whole = _floor_with(torch.where(labels < 0, 2, labels), disp, cfg, ground=False)
    assert [a.box for a in whole.kept if a.neurons == [0]] == [(10, 10, 109, 69)]


def test_the_parts_of_one_area_count_once_against_max_areas():
    labels, disp = _two_boxes_one_segment()
    one = _floor_with(labels, disp, dataclasses.replace(AreaConfig(), max_areas=1))
    assert sorted(a.box for a in one.kept) == [(10, 10, 29, 29), (70, 40, 109, 69)]  # both parts, no slab


def test_a_part_lying_flat_on_the_ground_is_left_out():
    labels, disp = _two_boxes_one_segment()
    disp[10:30, 10:30] = FLOOR_D + 0.5  # the small box becomes floor clutter within the plane's band
    result = _floor_with(labels, disp, AreaConfig())
    assert [a.box for a in result.kept if a.neurons == [0]] == [(70, 40, 109, 69)]


def _gap_map(gap: int):
    """The two boxes of :func:`_two_boxes_one_segment` on a segmented backdrop (neuron 2, no ground
    plane), with an invalid band ``gap`` px wide over the map's full height between them (an
    SGBM map's missing pixels)."""
    labels, disp = _two_boxes_one_segment()
    labels = torch.where(labels < 0, 2, labels)
    valid = torch.ones(H, W, dtype=torch.bool)
    valid[:, 50:50 + gap] = False
    labels[~valid] = -1
    return labels, disp, valid


def _unplaned(labels: torch.Tensor, disp: torch.Tensor, valid: torch.Tensor, cfg: AreaConfig):
    ctx = MapContext.build(disp, valid, labels >= 0, None, cfg)
    ref = torch.stack([disp[labels == n].mean() for n in range(3)])
    return find_objects(labels, ref.float(), None, ctx, cfg)


def test_a_wide_invalid_gap_splits_an_area_a_narrow_one_does_not():
    cfg = AreaConfig()
    k = solidity_square((H, W), cfg.solidity_size, 1)
    wide = _unplaned(*_gap_map(k + 5), cfg)
    assert sorted(a.box for a in wide.kept if a.neurons == [0]) == [(10, 10, 29, 29), (70, 40, 109, 69)]
    # a gap the closing with the solidity square fills (a sparse map's holes) joins what lies
    # on both sides of it: one box over both
    narrow = _unplaned(*_gap_map(k - 1), cfg)
    assert [a.box for a in narrow.kept if a.neurons == [0]] == [(10, 10, 109, 69)]
    # the paper rule splits nothing
    paper = _unplaned(*_gap_map(k + 5), dataclasses.replace(cfg, rule="paper"))
    assert [a.box for a in paper.kept if 0 in a.neurons][0][::2] == (10, 109)
