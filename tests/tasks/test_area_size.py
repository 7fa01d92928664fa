"""The size limits of step 1c are shares of the map's valid pixels, the ground plane's included."""

from __future__ import annotations

import pytest
import torch

from somtorch.tasks.detect import MapContext, find_objects
from somtorch.tasks.objects import AreaConfig, find_object_areas, neuron_stats


def _box_on_a_floor(h: int = 50, w: int = 100):
    """A floor (not segmented: the ground plane) fills 80 % of the map; 4 segments at one
    disparity (one box, four neurons) is everything else."""
    labels = torch.full((h, w), -1, dtype=torch.long)
    disp = torch.full((h, w), 5.0, dtype=torch.float64)
    for i in range(4):
        labels[10 + 5 * i:15 + 5 * i, 40:90] = i
        disp[10 + 5 * i:15 + 5 * i, 40:90] = 20.0
    return labels, disp


def test_an_object_that_is_all_the_ground_cut_leaves_is_kept():
    # the object is 20 % of the valid pixels but 100 % of the segmented ones: as a share of the
    # segmented pixels, max_area_frac (0.7) would refuse it and the whole map would be kept
    labels, disp = _box_on_a_floor()
    valid = torch.ones_like(labels, dtype=torch.bool)
    cfg = AreaConfig()
    ctx = MapContext.build(disp, valid, labels >= 0, None, cfg)
    res = find_objects(labels, torch.full((4,), 20.0), None, ctx, cfg)
    assert not res.no_object
    assert sorted(res.kept[0].neurons) == [0, 1, 2, 3] and res.kept[0].area_frac == pytest.approx(0.2)
    assert res.kept[0].box == (40, 10, 89, 29)


def test_area_frac_is_a_share_of_the_valid_pixels_when_given():
    labels, disp = _box_on_a_floor()
    stats = neuron_stats(labels, disp, 4)
    ref = torch.full((4,), 20.0)
    (seg,) = find_object_areas(ref, None, stats, AreaConfig())
    (val,) = find_object_areas(ref, None, stats, AreaConfig(), n_valid=labels.numel())
    assert seg.area_frac == pytest.approx(1.0) and val.area_frac == pytest.approx(0.2)
    assert seg.neurons == val.neurons and seg.box == val.box
