"""Initialisation from data: PCA (linear), random in the bounding box, and data samples."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch import SOM
from somtorch.core.init import INITS, init_pca, init_random, init_sample


@pytest.fixture
def cloud() -> torch.Tensor:
    """Anisotropic 3-D cloud with a clear first and second principal component, float64 ``(400, 3)``."""
    g = torch.Generator().manual_seed(2)
    stds = torch.tensor([3.0, 1.0, 0.2], dtype=torch.float64)
    z = torch.randn(400, 3, generator=g, dtype=torch.float64) * stds
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    return z @ q.T + torch.tensor([5.0, -2.0, 1.0], dtype=torch.float64)


def _pcs(x: torch.Tensor):
    xn = x.numpy()
    evals, evecs = np.linalg.eigh(np.cov(xn, rowvar=False))
    order = np.argsort(evals)[::-1]
    return xn.mean(0), evals[order], evecs[:, order]


def test_registry_names():
    assert set(INITS) == {"random", "sample", "pca"}


@pytest.mark.parametrize("rows,cols", [(6, 4), (3, 7)])
def test_pca_lies_in_the_plane_of_the_first_two_components(cloud, rows, cols):
    w = init_pca(cloud, rows, cols).numpy()
    mean, evals, evecs = _pcs(cloud)
    coef = (w - mean) @ evecs  # coordinates along the principal axes
    assert np.abs(coef[:, 2]).max() < 1e-9  # residual off the plane ~ 0
    std = np.sqrt(evals)
    # spans exactly +-1 std along each of the first two components
    np.testing.assert_allclose(np.abs(coef[:, 0]).max(), std[0], rtol=1e-9)
    np.testing.assert_allclose(np.abs(coef[:, 1]).max(), std[1], rtol=1e-9)
    np.testing.assert_allclose([coef[:, 0].min(), coef[:, 0].max()], [-std[0], std[0]], rtol=1e-9)
    np.testing.assert_allclose([coef[:, 1].min(), coef[:, 1].max()], [-std[1], std[1]], rtol=1e-9)
    # the first component runs along the longer grid axis
    c1 = coef[:, 0].reshape(rows, cols)
    if rows >= cols:
        assert np.allclose(c1, c1[:, :1]) and not np.allclose(c1, c1[:1, :])
    else:
        assert np.allclose(c1, c1[:1, :]) and not np.allclose(c1, c1[:, :1])


def test_pca_is_deterministic_and_the_same_for_every_member(cloud):
    a = init_pca(cloud, 4, 5)
    assert torch.equal(a, init_pca(cloud.clone(), 4, 5))
    som = SOM(4, 5, 3, ensemble=2, dtype=torch.float64, seed=1).initialize(cloud, "pca")
    other = SOM(4, 5, 3, ensemble=1, dtype=torch.float64, seed=99).initialize(cloud, "pca")
    assert torch.equal(som.weight[0], a) and torch.equal(som.weight[1], a) and torch.equal(other.weight[0], a)
    assert init_pca(cloud.float(), 4, 5).dtype == torch.float32


def test_random_init_is_inside_the_bounding_box_and_seeded(cloud):
    w = init_random(cloud, 50, torch.Generator().manual_seed(0))
    lo, hi = cloud.amin(0), cloud.amax(0)
    assert w.shape == (50, 3)
    assert bool(((w >= lo) & (w <= hi)).all())
    # it fills the box (not collapsed to a corner): each feature covers most of its range
    assert bool(((w.amax(0) - w.amin(0)) > 0.7 * (hi - lo)).all())
    assert torch.equal(w, init_random(cloud, 50, torch.Generator().manual_seed(0)))
    assert not torch.equal(w, init_random(cloud, 50, torch.Generator().manual_seed(1)))


def test_sample_init_picks_distinct_data_rows(cloud):
    w = init_sample(cloud, 30, torch.Generator().manual_seed(0))
    idx = [int((cloud == row).all(1).nonzero()[0]) for row in w]  # each row is a data row
    assert len(set(idx)) == 30
    assert torch.equal(w, init_sample(cloud, 30, torch.Generator().manual_seed(0)))


def test_sample_init_with_fewer_samples_than_neurons_repeats_rows(cloud):
    few = cloud[:5]
    w = init_sample(few, 12, torch.Generator().manual_seed(0))
    assert w.shape == (12, 3)
    assert all(bool((few == row).all(1).any()) for row in w)


@pytest.mark.parametrize("method", sorted(INITS))
def test_som_initialize_sets_flag_and_follows_seeds(cloud, method):
    som = SOM(3, 4, 3, ensemble=2, dtype=torch.float64, seed=10)
    assert not som.initialized
    assert som.initialize(cloud, method) is som and som.initialized
    solo = SOM(3, 4, 3, dtype=torch.float64, seed=11).initialize(cloud, method)
    assert torch.equal(som.weight[1], solo.weight[0])  # member 1 == solo with seed 10 + 1
    if method != "pca":
        assert not torch.equal(som.weight[0], som.weight[1])
