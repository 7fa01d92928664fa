"""The optional merge tree of the object areas (``objects.hierarchy``): an object split into parts
at somewhat different depths is one candidate, joined across its small inner step before either
part joins the background across the large step of its outline."""

from __future__ import annotations

import torch

from somtorch.config import AreaConfig
from somtorch.tasks.objects import find_object_areas, merge_tree, neuron_stats, select_areas


def _scene() -> tuple[torch.Tensor, torch.Tensor]:
    """Background (segment 0, d = 10) holding a two-part object (a hand at d = 32, segment 1, and
    its forearm at d = 26, segment 2, side by side) and a small nearer speck (segment 3, d = 50)."""
    h, w = 60, 80
    labels = torch.zeros(h, w, dtype=torch.long)
    disp = torch.full((h, w), 10.0)
    labels[20:40, 20:35], disp[20:40, 20:35] = 1, 32.0
    labels[20:40, 35:50], disp[20:40, 35:50] = 2, 26.0
    labels[5:9, 64:68], disp[5:9, 64:68] = 3, 50.0
    return labels, disp


def _areas(hierarchy: bool):
    labels, disp = _scene()
    stats = neuron_stats(labels, disp, 4)
    cfg = AreaConfig(hierarchy=hierarchy, min_area_frac=0.001, size_power=0.25)
    ref = torch.tensor([10.0, 32.0, 26.0, 50.0])  # 5 % of the spread: no two segments are similar
    return stats, cfg, find_object_areas(ref, None, stats, cfg)


def test_merge_tree_joins_the_parts_before_the_background():
    stats, _, _ = _areas(False)
    rows = merge_tree(torch.eye(4, dtype=torch.float64), stats, min_boundary=0.1)
    first = rows[0].nonzero().flatten().tolist()
    assert first == [1, 2]  # the 6 px inner step, before any 16-40 px step to the background
    assert len(rows) == 3  # C - 1 joins: everything touches something
    assert rows[-1].tolist() == [1.0, 1.0, 1.0, 1.0]
    assert bool(((rows == 0) | (rows == 1)).all())  # each node holds a segment at most once


def test_the_whole_object_outranks_a_speck_only_with_the_tree():
    stats, cfg, flat = _areas(False)
    best_flat = select_areas(flat, stats, cfg)[0]
    assert best_flat.neurons == [3]  # each part alone stands out less than the speck
    stats, cfg, tree = _areas(True)
    assert len(tree) > len(flat)
    best = select_areas(tree, stats, cfg)[0]
    assert best.neurons == [1, 2]
    assert best.box == (20, 20, 49, 39)
    assert abs(best.mean_disparity - 29.0) < 1e-9
    assert abs(best.contrast - (29.0 - 10.0)) < 1e-9  # its whole outline borders the background


def test_the_tree_is_off_by_default_and_keeps_the_flat_areas_first():
    assert AreaConfig().hierarchy is False
    _, _, flat = _areas(False)
    _, _, tree = _areas(True)
    assert [a.neurons for a in tree[:len(flat)]] == [a.neurons for a in flat]
    assert [a.box for a in tree[:len(flat)]] == [a.box for a in flat]
