"""The optional colour term of the salient ranking: an area with no depth contrast but a colour of
its own can outrank a slightly nearer area of the background's colour."""

from __future__ import annotations

import torch

from somtorch.config import AreaConfig
from somtorch.tasks.objects import find_object_areas, neuron_stats, select_areas


def test_colour_salience_reorders_areas_only_when_switched_on():
    h, w = 60, 90
    labels = torch.zeros(h, w, dtype=torch.long)
    disp = torch.full((h, w), 10.0)
    labels[10:30, 10:30], disp[10:30, 10:30] = 1, 13.0  # a bit nearer, background colour
    labels[35:55, 50:70], disp[35:55, 50:70] = 2, 12.0  # a bit less near, a colour of its own
    stats = neuron_stats(labels, disp, 3)
    ref_d = torch.tensor([10.0, 13.0, 12.0])
    ref_c = torch.tensor([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [0.8, 0.2, 0.9]])
    cfg = AreaConfig(similarity=0.01)
    plain = select_areas(find_object_areas(ref_d, None, stats, cfg, ref_c), stats, AreaConfig(max_areas=2))
    assert [a.neurons for a in plain] == [[1], [2]]  # colour ignored: depth contrast decides
    cfg = AreaConfig(similarity=0.01, color_rank=1.0)
    areas = find_object_areas(ref_d, None, stats, cfg, ref_c)
    ranked = select_areas(areas, stats, AreaConfig(max_areas=2, color_rank=1.0))
    assert [a.neurons for a in ranked] == [[2], [1]]
    by = {tuple(a.neurons): a for a in areas}
    assert by[(1,)].salience == by[(1,)].contrast  # same colour as its surroundings: no colour term
    assert by[(2,)].salience > by[(2,)].contrast
