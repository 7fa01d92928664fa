"""Toy label maps for the object step's tests: segments of constant disparity."""

from __future__ import annotations

import torch

from somtorch.tasks.objects import AreaConfig, find_object_areas, neuron_stats


def flat_segments(labels: torch.Tensor, depth: dict[int, float], cfg: AreaConfig | None = None):
    """``(disparity, stats, areas)`` of a label map whose segment k lies at ``depth[k]`` px
    (segments linked as the step links them, without a grid)."""
    disp = torch.zeros(labels.shape)
    for k, v in depth.items():
        disp[labels == k] = v
    stats = neuron_stats(labels, disp, len(depth))
    areas = find_object_areas(torch.tensor([depth[k] for k in range(len(depth))]), None, stats,
                              cfg or AreaConfig())
    return disp, stats, areas
