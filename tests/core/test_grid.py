"""Grid geometry: coordinates, squared grid distances (flat and toroidal) and adjacency."""

from __future__ import annotations

import math

import pytest
import torch

from somtorch import SOM
from somtorch.core.grid import adjacency, grid_coordinates, grid_sqdist, neighbor_threshold


def _degree(rows: int, cols: int, topology: str, toroidal: bool = False) -> torch.Tensor:
    d2 = grid_sqdist(rows, cols, topology, toroidal, dtype=torch.float64)
    return adjacency(d2, topology).sum(1).view(rows, cols)


def test_coordinates_are_row_major():
    g = grid_coordinates(3, 4)
    assert g.shape == (12, 2)
    k = 2 * 4 + 1  # row 2, col 1
    assert g[k].tolist() == [2.0, 1.0]
    assert torch.equal(g[:, 0], torch.arange(3.0).repeat_interleave(4))
    assert torch.equal(g[:, 1], torch.arange(4.0).repeat(3))


def test_coordinates_follow_dtype():
    assert grid_coordinates(2, 3, dtype=torch.float64).dtype == torch.float64


def test_rectangular_adjacency_counts_corner_edge_inner():
    deg = _degree(4, 5, "rectangular")
    expected = torch.full((4, 5), 8)
    expected[0, :] = expected[-1, :] = 5
    expected[:, 0] = expected[:, -1] = 5
    expected[0, 0] = expected[0, -1] = expected[-1, 0] = expected[-1, -1] = 3
    assert torch.equal(deg, expected)


def test_rectangular_adjacency_is_the_8_neighbourhood():
    rows, cols = 4, 5
    adj = adjacency(grid_sqdist(rows, cols), "rectangular")
    for a in range(rows * cols):
        for b in range(rows * cols):
            ra, ca = divmod(a, cols)
            rb, cb = divmod(b, cols)
            want = a != b and abs(ra - rb) <= 1 and abs(ca - cb) <= 1
            assert bool(adj[a, b]) == want, (a, b)


def test_flat_sqdist_matches_cdist_of_coordinates():
    for topology in ("rectangular", "hexagonal"):
        coords = grid_coordinates(4, 6, topology, dtype=torch.float64)
        d2 = grid_sqdist(4, 6, topology, dtype=torch.float64)
        assert torch.allclose(d2, torch.cdist(coords, coords).square(), atol=1e-12)
        assert torch.equal(d2, d2.T) and bool((d2.diagonal() == 0).all())


def test_hexagonal_inner_neuron_has_six_neighbours_at_distance_one():
    rows, cols = 5, 6
    d2 = grid_sqdist(rows, cols, "hexagonal", dtype=torch.float64)
    deg = _degree(rows, cols, "hexagonal")
    assert bool((deg[1:-1, 1:-1] == 6).all())
    assert int(deg.max()) == 6
    for r in range(1, rows - 1):
        for c in range(1, cols - 1):
            row = d2[r * cols + c]
            near = torch.isclose(row, torch.tensor(1.0, dtype=torch.float64), atol=1e-9)
            assert int(near.sum()) == 6
            # the next ring is at distance sqrt(3) or farther: nothing between 1 and sqrt(3)
            others = row[(row > 1.0 + 1e-9)]
            assert float(others.min()) == pytest.approx(3.0, abs=1e-9)


def test_rectangular_torus_every_neuron_has_8_neighbours():
    deg = _degree(4, 5, "rectangular", toroidal=True)
    assert bool((deg == 8).all())
    d2 = grid_sqdist(4, 5, "rectangular", True, dtype=torch.float64)
    # corner (0, 0) touches the opposite corner (3, 4) across both seams
    assert float(d2[0, 3 * 5 + 4]) == pytest.approx(2.0)
    # the largest wrapped offset on a 4x5 torus is (2, 2)
    assert float(d2.max()) == pytest.approx(8.0)
    assert bool((d2 <= grid_sqdist(4, 5, "rectangular", False, dtype=torch.float64) + 1e-12).all())


def test_hexagonal_torus_every_neuron_has_6_neighbours():
    deg = _degree(4, 6, "hexagonal", toroidal=True)
    assert bool((deg == 6).all())


def test_hexagonal_torus_needs_even_rows():
    with pytest.raises(ValueError, match="rows"):
        grid_sqdist(3, 4, "hexagonal", True)
    with pytest.raises(ValueError, match="rows"):
        SOM(5, 4, 2, topology="hexagonal", toroidal=True)


def test_neighbor_threshold_values():
    assert neighbor_threshold("rectangular") == pytest.approx(math.sqrt(2.0))
    assert neighbor_threshold("hexagonal") == 1.0
    with pytest.raises(ValueError, match="hexagonal, rectangular"):
        neighbor_threshold("triangular")


def test_som_buffers_match_grid_functions():
    som = SOM(4, 4, 2, topology="hexagonal", toroidal=True, seed=0)
    assert torch.equal(som.grid, grid_coordinates(4, 4, "hexagonal"))
    assert torch.equal(som.grid_d2, grid_sqdist(4, 4, "hexagonal", True))
    assert torch.equal(som.adjacency, adjacency(som.grid_d2, "hexagonal"))
    assert som.num_neurons == 16 and som.weight.shape == (1, 16, 2)
