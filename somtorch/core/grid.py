"""Grid geometry of a SOM: neuron coordinates and distances on the map.

Neurons are numbered in row-major order, ``k = r * cols + c``. Coordinates are ``(row, col)`` in grid
units:

* rectangular: ``(r, c)``; the 8 surrounding neurons are neighbours (distance ≤ √2);
* hexagonal (offset rows): ``(r · √3/2, c + 0.5 · (r mod 2))``; the 6 surrounding neurons are at
  distance 1. (MiniSom offsets columns instead of rows; the geometry is the same transposed.)

A toroidal map wraps both axes; a hexagonal torus needs an even number of rows so that the row
offsets line up across the seam.
"""

from __future__ import annotations

import math

import torch

from ..config.options import TOPOLOGIES
from ..validation import check_choice, check_positive_int
_HEX_ROW = math.sqrt(3.0) / 2.0


def grid_coordinates(rows: int, cols: int, topology: str = "rectangular", *, dtype=torch.float32,
                     device=None) -> torch.Tensor:
    """Coordinates of the neurons on the map.

    Shape:
        returns ``(K, 2)`` with ``K = rows * cols``, columns ``(row, col)`` in grid units.

    >>> grid_coordinates(2, 2)
    tensor([[0., 0.],
            [0., 1.],
            [1., 0.],
            [1., 1.]])
    """
    rows = check_positive_int("rows", rows)
    cols = check_positive_int("cols", cols)
    check_choice("topology", topology, TOPOLOGIES)
    r = torch.arange(rows, dtype=torch.float64, device=device).repeat_interleave(cols)
    c = torch.arange(cols, dtype=torch.float64, device=device).repeat(rows)
    if topology == "hexagonal":
        c = c + 0.5 * (r % 2)
        r = r * _HEX_ROW
    return torch.stack([r, c], dim=1).to(dtype)


def grid_sqdist(rows: int, cols: int, topology: str = "rectangular", toroidal: bool = False, *,
                dtype=torch.float32, device=None) -> torch.Tensor:
    """Squared distances between all pairs of neurons on the map (wrapped on a torus).

    Shape:
        returns ``(K, K)``.
    """
    coords = grid_coordinates(rows, cols, topology, dtype=torch.float64, device=device)
    delta = coords[:, None, :] - coords[None, :, :]  # (K, K, 2)
    if toroidal:
        if topology == "hexagonal" and rows % 2:
            raise ValueError(f"a hexagonal toroidal map needs an even number of rows; got rows={rows}")
        period = torch.tensor([rows * (_HEX_ROW if topology == "hexagonal" else 1.0), float(cols)],
                              dtype=torch.float64, device=device)
        # smallest distance over the 9 periodic images (exact for both topologies)
        best = None
        for sr in (-1.0, 0.0, 1.0):
            for sc in (-1.0, 0.0, 1.0):
                shift = torch.tensor([sr, sc], dtype=torch.float64, device=device) * period
                d2 = (delta + shift).square().sum(-1)
                best = d2 if best is None else torch.minimum(best, d2)
        return best.to(dtype)
    return delta.square().sum(-1).to(dtype)


def neighbor_threshold(topology: str) -> float:
    """Largest grid distance at which two neurons count as adjacent (√2 rectangular, 1 hexagonal)."""
    check_choice("topology", topology, TOPOLOGIES)
    return math.sqrt(2.0) if topology == "rectangular" else 1.0


def adjacency(grid_d2: torch.Tensor, topology: str) -> torch.Tensor:
    """Boolean adjacency matrix of the map (8-neighbourhood rectangular, 6 hexagonal), no self loops.

    Shape:
        ``grid_d2``: ``(K, K)`` → ``(K, K)`` bool.
    """
    thr = neighbor_threshold(topology) + 1e-6
    adj = grid_d2 <= thr * thr
    adj.fill_diagonal_(False)
    return adj


def default_sigma(rows: int, cols: int) -> float:
    """The initial neighbourhood radius when none is given: half the longer grid side (grid units)."""
    return max(rows, cols) / 2.0
