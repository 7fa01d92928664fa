"""Chunked BMU search and pairwise distances against brute force (``torch.cdist`` without the mm trick)."""

from __future__ import annotations

import pytest
import torch

from somtorch import SOM
from somtorch.core.distance import bmu_search, gather_weights, pairwise_sqdist

E, K, D = 3, 12, 4


def _brute(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Exact distances ``(E, N, K)``: x ``(N, D)`` or ``(E, N, D)``, w ``(E, K, D)``."""
    xe = x.expand(w.shape[0], -1, -1) if x.ndim == 2 else x
    return torch.cdist(xe, w, compute_mode="donot_use_mm_for_euclid_dist")


@pytest.fixture
def data():
    g = torch.Generator().manual_seed(7)
    w = torch.randn(E, K, D, generator=g, dtype=torch.float64)
    x_shared = torch.randn(101, D, generator=g, dtype=torch.float64)
    x_member = torch.randn(E, 53, D, generator=g, dtype=torch.float64)
    return w, x_shared, x_member


@pytest.mark.parametrize("which", ["shared", "member"])
def test_bmu_equals_brute_force_argmin(data, which):
    w, xs, xm = data
    x = xs if which == "shared" else xm
    got = bmu_search(x, w)
    assert got.shape == (E, x.shape[-2]) and got.dtype == torch.long
    assert torch.equal(got, _brute(x, w).argmin(-1))


@pytest.mark.parametrize("which", ["shared", "member"])
def test_two_best_units_sorted(data, which):
    w, xs, xm = data
    x = xs if which == "shared" else xm
    got = bmu_search(x, w, k=2)
    dist = _brute(x, w)
    assert got.shape == (E, x.shape[-2], 2)
    assert torch.equal(got, dist.topk(2, dim=-1, largest=False, sorted=True).indices)
    assert torch.equal(got[..., 0], bmu_search(x, w))
    d_sel = torch.gather(dist, -1, got)
    assert bool((d_sel[..., 0] <= d_sel[..., 1]).all())


@pytest.mark.parametrize("which", ["shared", "member"])
@pytest.mark.parametrize("k", [1, 2])
def test_tiny_chunks_give_the_same_answer(data, which, k):
    w, xs, xm = data
    x = xs if which == "shared" else xm
    # 7 scores per chunk is fewer than one row (E*K = 36): one sample per chunk
    assert torch.equal(bmu_search(x, w, k=k, chunk_elements=7), bmu_search(x, w, k=k))
    assert torch.equal(bmu_search(x, w, k=k, chunk_elements=E * K * 10), bmu_search(x, w, k=k))


@pytest.mark.parametrize("k", [1, 2])
def test_single_sample(data, k):
    w, xs, _ = data
    x = xs[:1]
    got = bmu_search(x, w, k=k)
    assert got.shape == ((E, 1) if k == 1 else (E, 1, 2))
    want = _brute(x, w).topk(k, dim=-1, largest=False).indices
    assert torch.equal(got.view(E, 1, k), want)


def test_float32_matches_brute_force_up_to_near_ties():
    g = torch.Generator().manual_seed(3)
    w = torch.rand(2, 20, 3, generator=g)
    x = torch.rand(500, 3, generator=g)
    got = bmu_search(x, w)
    dist = _brute(x.double(), w.double())
    best = dist.min(-1).values
    chosen = torch.gather(dist, -1, got[..., None])[..., 0]
    # where the float32 expansion picks another unit it is a near tie (within float32 rounding)
    assert float((chosen - best).max()) < 1e-5
    assert float((got == dist.argmin(-1)).double().mean()) > 0.99


def test_pairwise_sqdist_equals_squared_cdist_and_is_differentiable(data):
    w, xs, xm = data
    for x in (xs, xm):
        assert torch.allclose(pairwise_sqdist(x, w), _brute(x, w).square(), atol=1e-10)
    x = xs[:5].clone().requires_grad_(True)
    ww = w[:, :4].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(pairwise_sqdist, (x, ww))


def test_gather_weights_picks_the_bmu_rows(data):
    w, xs, _ = data
    b = bmu_search(xs, w)
    g = gather_weights(w, b)
    assert g.shape == (E, xs.shape[0], D)
    for e in range(E):
        assert torch.equal(g[e], w[e, b[e]])


def test_som_bmu_uses_the_same_search(data):
    w, xs, xm = data
    som = SOM(3, 4, D, ensemble=E, dtype=torch.float64, seed=0)
    som.weight = w
    assert torch.equal(som.bmu(xs), bmu_search(xs, w))
    assert torch.equal(som.bmu(xm, chunk_elements=7), bmu_search(xm, w))
    assert torch.equal(som(xs), pairwise_sqdist(xs, w))
