"""Optional refinements of the object areas and the input: box tightening, area growing, speckles."""

from __future__ import annotations

import torch

from somtorch.disparity.filters import remove_speckles
from somtorch.tasks.objects import ObjectArea, grow_area, tighten_box


def _area(neurons, box, mean_d=50.0, contrast=40.0):
    return ObjectArea(neurons=neurons, pixels=1, box=box, mean_disparity=mean_d, contrast=contrast, area_frac=0.1)


def test_tighten_box_drops_a_stray_fragment_but_keeps_the_body():
    labels = torch.full((100, 100), 1, dtype=torch.long)
    labels[20:60, 30:70] = 0  # the object's segment: a 40x40 block ...
    labels[95:97, 2:4] = 0  # ... plus a 2x2 stray fragment far away (0.25 % of its pixels)
    area = _area([0], (2, 20, 69, 96))
    tight = tighten_box(area, labels, coverage=0.99, stride=1)
    assert tight.box == (30, 20, 69, 59)
    assert tight.extra["segment_box"] == (2, 20, 69, 96)
    # coverage 1.0 keeps every piece: the paper's box of all segment pixels
    assert tighten_box(area, labels, coverage=1.0, stride=1).box == area.box


def test_grow_area_recovers_the_whole_near_object_and_stops_at_the_background():
    disp = torch.full((60, 80), 10.0)
    disp[10:40, 20:50] = 50.0  # near object
    labels = torch.full((60, 80), 1, dtype=torch.long)
    labels[10:25, 20:35] = 0  # the SOM area holds only the object's top-left quarter
    usable = torch.ones(60, 80, dtype=torch.bool)
    grown = grow_area(_area([0], (20, 10, 34, 24)), labels, disp, usable, stride=1)
    assert grown.box == (20, 10, 49, 39)
    assert grown.pixels == 30 * 30
    assert grown.extra["grow_threshold"] == 30.0  # mean − contrast / 2
    # pixels that may not join (e.g. the ground plane) stop the growth
    usable[:, 35:] = False
    assert grow_area(_area([0], (20, 10, 34, 24)), labels, disp, usable, stride=1).box == (20, 10, 34, 39)


def test_grow_area_leaves_a_non_salient_area_alone():
    disp = torch.full((20, 20), 10.0)
    labels = torch.zeros(20, 20, dtype=torch.long)
    area = _area([0], (0, 0, 4, 4), mean_d=10.0, contrast=-3.0)
    assert grow_area(area, labels, disp, torch.ones(20, 20, dtype=torch.bool)) is area


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
