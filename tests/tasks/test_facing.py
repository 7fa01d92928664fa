"""The optional facing term of the salient ranking: an area's salience is multiplied by the cosine
of the tilt of its disparity plane from the line of sight, so a side wall or a floor receding to
the vanishing point loses it and a fronto-parallel object keeps it."""

from __future__ import annotations

import math

import torch

from somtorch.config import AreaConfig
from somtorch.tasks.objects import _facing, find_object_areas, neuron_stats, select_areas


def _plane_moments(a: float, b: float, c: float, box: tuple[int, int, int, int], h: int, w: int):
    """Labels (1 inside ``box``), disparity d = a·u + b·v + c (u, v from the centre in widths)."""
    u = ((torch.arange(w, dtype=torch.float64) - 0.5 * (w - 1)) / w).expand(h, w)
    v = ((torch.arange(h, dtype=torch.float64)[:, None] - 0.5 * (h - 1)) / w).expand(h, w)
    disp = (a * u + b * v + c).float()
    labels = torch.zeros(h, w, dtype=torch.long)
    x0, y0, x1, y1 = box
    labels[y0:y1, x0:x1] = 1
    return labels, disp


def test_facing_is_the_cosine_of_the_planes_tilt():
    h, w = 60, 80
    for a, b, c in [(0.0, 0.0, 20.0), (20.0, 0.0, 20.0), (0.0, 10.0, 17.3), (30.0, 30.0, 5.0)]:
        labels, disp = _plane_moments(a, b, c, (45, 10, 75, 50), h, w)
        stats = neuron_stats(labels, disp, 2, moments=True)
        n = stats.count[1:2]
        got = float(_facing(stats.moments[1:2], n, stats.mean_d[1:2].double())[0])
        assert math.isclose(got, c / math.sqrt(a * a + b * b + c * c), abs_tol=2e-3), (a, b, c, got)
    # a surface whose plane has no positive disparity at the principal point is seen edge-on: 0
    labels, disp = _plane_moments(60.0, 0.0, -5.0, (60, 10, 78, 50), h, w)
    stats = neuron_stats(labels, disp, 2, moments=True)
    assert float(_facing(stats.moments[1:2], stats.count[1:2], stats.mean_d[1:2].double())[0]) == 0.0


def test_facing_term_demotes_a_receding_wall_only_when_switched_on():
    h, w = 60, 80
    u = ((torch.arange(w, dtype=torch.float32) - 0.5 * (w - 1)) / w).expand(h, w)
    disp = torch.full((h, w), 8.0)
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[:, 64:] = 1  # a side wall: disparity grows towards the right edge, 0 at the centre
    disp[:, 64:] = 60.0 * u[:, 64:]
    labels[25:45, 20:40], disp[25:45, 20:40] = 2, 20.0  # a fronto-parallel object, less near
    ref = torch.tensor([8.0, float(disp[:, 64:].mean()), 20.0])
    pick = AreaConfig(max_areas=2, size_power=0.0)
    stats = neuron_stats(labels, disp, 3, moments=True)
    plain = select_areas(find_object_areas(ref, None, stats, AreaConfig(similarity=0.01)), stats, pick)
    assert [a.neurons for a in plain] == [[1], [2]]  # depth contrast alone: the wall first
    areas = find_object_areas(ref, None, stats, AreaConfig(similarity=0.01, facing_rank=1.0))
    assert [a.neurons for a in select_areas(areas, stats, pick)] == [[2], [1]]
    by = {tuple(a.neurons): a for a in areas}
    assert by[(2,)].facing > 0.99 and by[(1,)].facing < 0.1
    assert math.isclose(by[(2,)].salience, by[(2,)].contrast * by[(2,)].facing, rel_tol=1e-9)
