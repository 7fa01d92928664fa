"""The salient ranking reads what ``merge`` keeps of an area (session 31): ``with_grown_contrast``
and the geometric mean in ``rank_score``."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from somtorch.tasks.context import MapContext
from somtorch.tasks.detect import kept_areas
from somtorch.tasks.objects import AreaConfig, areas_of, find_object_areas, neuron_stats, rank_score, select_areas
from somtorch.tasks.refine import merge_adjacent, with_grown_contrast

from .toys import flat_segments

H, W = 60, 120
DEPTH = {0: 10.0, 1: 30.0, 2: 40.0, 3: 28.0, 4: 20.0}


def _strip_beside_a_surface():
    """Two equal blocks in front of a far background (d 10): the object (1, d 30) stands alone;
    the other (2, d 40) touches a large surface (3, d 28, set in a wall 4 at d 20) within ``merge``'s
    tolerance, so what ``merge`` keeps of it is the block and the surface, hardly in front of the wall."""
    labels = torch.zeros(H, W, dtype=torch.long)
    labels[10:50, 10:20] = 1
    labels[:, 60:] = 4
    labels[10:50, 60:110] = 3
    labels[10:50, 50:60] = 2
    disp, stats, areas = flat_segments(labels, DEPTH)
    return labels, disp, stats, areas


def test_rank_score_is_the_geometric_mean_of_the_two_contrasts():
    cfg = AreaConfig()
    a = areas_of([[0]], neuron_stats(torch.zeros(4, 4, dtype=torch.long), torch.ones(4, 4), 1))[0]
    a = replace(a, contrast=16.0, area_frac=0.0625)
    size = 0.0625 ** cfg.size_power
    assert rank_score(a, cfg) == pytest.approx(16.0 * size)  # not measured: the contrast alone
    assert rank_score(replace(a, grown_contrast=4.0), cfg) == pytest.approx(8.0 * size)
    assert rank_score(replace(a, grown_contrast=-3.0), cfg) == 0.0  # grown, it lies behind its surroundings
    # a verified support ranks by size x nearness whatever the growth
    grown = replace(a, grown_contrast=4.0)
    assert rank_score(grown, cfg, on_support=True) == rank_score(a, cfg, on_support=True)


def test_grown_contrast_is_the_contrast_of_what_merge_adjacent_keeps():
    # a random map of 12 segments: growing every area at once equals merge_adjacent growing each alone
    g = torch.Generator().manual_seed(3)
    seeds = torch.randint(0, 40, (12, 2), generator=g)
    yy, xx = torch.meshgrid(torch.arange(40), torch.arange(50), indexing="ij")
    dist = (yy[..., None] - seeds[:, 0]) ** 2 + (xx[..., None] - seeds[:, 1]) ** 2
    labels = dist.argmin(-1)
    ref = torch.rand(12, generator=g) * 40 + 5
    disp = ref[labels] + torch.rand(40, 50, generator=g)
    stats = neuron_stats(labels, disp, 12)
    cfg = AreaConfig()
    areas = find_object_areas(ref, None, stats, cfg)
    grown = with_grown_contrast(areas, stats, cfg)
    assert [a.neurons for a in grown] == [a.neurons for a in areas]
    n_grew = 0
    for a, b in zip(areas, grown):
        group = merge_adjacent([a], stats, ratio=cfg.merge, min_boundary=cfg.min_boundary)[0].neurons
        n_grew += len(group) > len(a.neurons)
        assert b.grown_contrast == pytest.approx(areas_of([group], stats)[0].contrast)
        assert b.contrast == a.contrast
    assert n_grew > 0  # the map exercises the growth
    # merge off: nothing is grown, the areas come back as they were
    assert with_grown_contrast(areas, stats, AreaConfig(merge=0.0)) is areas


def test_an_area_whose_growth_swallows_a_surface_ranks_below_a_standalone_object():
    labels, disp, stats, areas = _strip_beside_a_surface()
    cfg = AreaConfig()
    by = {tuple(a.neurons): a for a in with_grown_contrast(areas, stats, cfg)}
    # the block beside the surface stands out more than the object on its own (22.8 against 20 px) ...
    assert by[(2,)].contrast > by[(1,)].contrast
    assert [a.neurons for a in select_areas(areas, stats, cfg)][:2] == [[2], [1]]
    # ... but merge grows it into the surface, which is hardly in front of the wall (13 px)
    assert by[(2,)].grown_contrast == pytest.approx(13.0)
    assert by[(1,)].grown_contrast == by[(1,)].contrast == pytest.approx(20.0)
    assert rank_score(by[(2,)], cfg) == pytest.approx(math.sqrt(22.8 * 13.0) * by[(2,)].area_frac ** cfg.size_power)
    ctx = MapContext.build(disp, torch.ones(H, W, dtype=torch.bool), labels >= 0, None, cfg)
    trace = []
    kept = kept_areas(areas, stats, labels, cfg, ctx, trace=trace)
    assert [c.area.neurons for c in trace][:2] == [[1], [2]] and trace[0].score > trace[1].score
    assert [a.neurons for a in kept] == [[1]] and kept[0].box == (10, 10, 19, 49)
    assert trace[1].verdict.startswith("skipped: the kept boxes would hold")  # the grown block: too much
    # the paper's rule ranks by nearness alone: the block, the nearest area, is its choice
    assert [a.neurons for a in kept_areas(areas, stats, labels, AreaConfig(rule="paper"), ctx)][0][0] == 2
