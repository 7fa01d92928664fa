"""Quantization error, topographic error and U-matrix against brute-force definitions."""

from __future__ import annotations

import math

import pytest
import torch

from somtorch import SOM
from somtorch.core.grid import adjacency, grid_sqdist
from somtorch.core.metrics import quantization_error, topographic_error, umatrix

ROWS, COLS, D = 3, 4, 3


def _cdist(x, w):
    xe = x.expand(w.shape[0], -1, -1) if x.ndim == 2 else x
    return torch.cdist(xe, w, compute_mode="donot_use_mm_for_euclid_dist")


@pytest.fixture
def setup():
    g = torch.Generator().manual_seed(11)
    w = torch.rand(2, ROWS * COLS, D, generator=g, dtype=torch.float64)
    x = torch.rand(97, D, generator=g, dtype=torch.float64)
    xm = torch.rand(2, 61, D, generator=g, dtype=torch.float64)
    return w, x, xm


def test_quantization_error_is_mean_distance_to_bmu(setup):
    w, x, xm = setup
    for xx in (x, xm):
        want = _cdist(xx, w).min(-1).values.mean(-1)
        got = quantization_error(xx, w)
        assert got.shape == (2,)
        assert torch.allclose(got, want, rtol=1e-12)
        assert torch.allclose(quantization_error(xx, w, chunk_elements=5), want, rtol=1e-12)


def test_quantization_error_zero_when_units_sit_on_samples():
    x = torch.rand(12, 2, dtype=torch.float64)
    assert float(quantization_error(x, x[None])) == 0.0


@pytest.mark.parametrize("topology,toroidal", [("rectangular", False), ("rectangular", True),
                                               ("hexagonal", False), ("hexagonal", True)])
def test_topographic_error_brute_force(setup, topology, toroidal):
    rows = 4 if topology == "hexagonal" else ROWS
    _, x, xm = setup
    w = torch.rand(2, rows * COLS, D, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    d2 = grid_sqdist(rows, COLS, topology, toroidal, dtype=torch.float64)
    thr = 2.0 if topology == "rectangular" else 1.0
    for xx in (x, xm):
        top2 = _cdist(xx, w).topk(2, dim=-1, largest=False).indices  # (E, N, 2)
        gd = d2[top2[..., 0], top2[..., 1]]
        want = (gd > thr + 1e-9).double().mean(-1)
        got = topographic_error(xx, w, adjacency(d2, topology))
        assert torch.equal(got, want)
    assert 0.0 < float(want.max()) < 1.0  # random weights: a mixed case, so the test can fail both ways


def test_topographic_error_of_one_neuron_map_is_nan():
    x = torch.rand(5, 2)
    te = topographic_error(x, torch.rand(1, 1, 2), torch.zeros(1, 1, dtype=torch.bool))
    assert math.isnan(float(te))


@pytest.mark.parametrize("topology", ["rectangular", "hexagonal"])
def test_umatrix_brute_force(setup, topology):
    w, _, _ = setup
    d2 = grid_sqdist(ROWS, COLS, topology, dtype=torch.float64)
    adj = adjacency(d2, topology)
    u = umatrix(w, adj, ROWS, COLS)
    assert u.shape == (2, ROWS, COLS)
    for e in range(2):
        for k in range(ROWS * COLS):
            nb = adj[k].nonzero().flatten().tolist()
            want = sum(float((w[e, k] - w[e, j]).norm()) for j in nb) / len(nb)
            assert float(u[e, k // COLS, k % COLS]) == pytest.approx(want, rel=1e-12)


def test_umatrix_of_flat_map_is_zero():
    w = torch.ones(1, ROWS * COLS, D)
    adj = adjacency(grid_sqdist(ROWS, COLS), "rectangular")
    assert torch.equal(umatrix(w, adj, ROWS, COLS), torch.zeros(1, ROWS, COLS))


def test_som_methods_equal_functions(setup):
    w, x, xm = setup
    som = SOM(ROWS, COLS, D, ensemble=2, dtype=torch.float64, seed=0, toroidal=True)
    som.weight = w
    assert torch.equal(som.quantization_error(x), quantization_error(x, w))
    assert torch.equal(som.topographic_error(xm), topographic_error(xm, w, som.adjacency))
    assert torch.equal(som.umatrix(), umatrix(w, som.adjacency, ROWS, COLS))


def test_quantization_error_of_a_member_does_not_depend_on_the_ensemble_size():
    # the chunk length depends on E; float64 sums keep each member's float32 result unchanged
    g = torch.Generator().manual_seed(3)
    x = torch.rand(60_000, 3, generator=g)
    w = torch.rand(40, 28, 3, generator=g)
    qe = quantization_error(x, w, chunk_elements=1 << 18)
    solo = torch.cat([quantization_error(x, w[e:e + 1], chunk_elements=1 << 18) for e in range(40)])
    assert torch.equal(qe, solo)
