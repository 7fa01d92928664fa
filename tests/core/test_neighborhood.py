"""Neighbourhood functions: value 1 at the winner, shapes, agreement with MiniSom's formulas."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from minisom import MiniSom

from somtorch.core.grid import grid_sqdist
from somtorch.core.neighborhood import NEIGHBORHOODS, bubble, gaussian, mexican_hat, triangle

ROWS, COLS = 4, 6


@pytest.fixture(scope="module")
def d2() -> torch.Tensor:
    return grid_sqdist(ROWS, COLS, dtype=torch.float64)


def test_registry_names():
    assert set(NEIGHBORHOODS) == {"gaussian", "bubble", "mexican_hat", "triangle"}


@pytest.mark.parametrize("name", sorted(NEIGHBORHOODS))
@pytest.mark.parametrize("sigma", [0.3, 1.0, 2.5])
def test_value_at_winner_is_one(name, sigma, d2):
    h = NEIGHBORHOODS[name](d2, torch.tensor(sigma, dtype=torch.float64))
    assert h.shape == d2.shape
    assert torch.equal(h.diagonal(), torch.ones(ROWS * COLS, dtype=torch.float64))


@pytest.mark.parametrize("name", ["gaussian", "bubble", "triangle"])
def test_non_increasing_with_distance_and_in_unit_interval(name):
    dd = torch.linspace(0, 30, 301, dtype=torch.float64)
    h = NEIGHBORHOODS[name](dd, torch.tensor(1.7, dtype=torch.float64))
    assert bool((h[1:] <= h[:-1]).all())
    assert bool(((h >= 0) & (h <= 1)).all())


@pytest.mark.parametrize("sigma", [0.7, 1.3, 2.0])
def test_gaussian_equals_minisom(sigma, d2):
    ms = MiniSom(ROWS, COLS, 2, sigma=sigma, neighborhood_function="gaussian", random_seed=0)
    for k in range(ROWS * COLS):
        c = divmod(k, COLS)
        want = ms._gaussian(c, sigma)  # (ROWS, COLS)
        ours = gaussian(d2[k], torch.tensor(sigma, dtype=torch.float64)).view(ROWS, COLS).numpy()
        np.testing.assert_allclose(ours, want, rtol=1e-13, atol=1e-300)


def test_mexican_hat_equals_minisom(d2):
    sigma = 1.3
    ms = MiniSom(ROWS, COLS, 2, sigma=sigma, neighborhood_function="mexican_hat", random_seed=0)
    for k in (0, 7, 23):
        want = ms._mexican_hat(divmod(k, COLS), sigma)
        ours = mexican_hat(d2[k], torch.tensor(sigma, dtype=torch.float64)).view(ROWS, COLS).numpy()
        np.testing.assert_allclose(ours, want, rtol=1e-12, atol=1e-15)
    assert float(mexican_hat(torch.tensor(4.0), torch.tensor(1.0))) < 0  # the negative ring


def test_bubble_is_radial_step_inclusive():
    d = torch.tensor([0.0, 0.5, 1.0, 1.5, 2.0, 2.01], dtype=torch.float64)
    h = bubble(d * d, torch.tensor(2.0, dtype=torch.float64))
    assert h.tolist() == [1.0, 1.0, 1.0, 1.0, 1.0, 0.0]


def test_triangle_is_linear_cone():
    d = torch.tensor([0.0, 0.5, 1.0, 2.0, 3.0], dtype=torch.float64)
    h = triangle(d * d, torch.tensor(2.0, dtype=torch.float64))
    assert torch.allclose(h, torch.tensor([1.0, 0.75, 0.5, 0.0, 0.0], dtype=torch.float64))


@pytest.mark.parametrize("name", sorted(NEIGHBORHOODS))
def test_per_member_sigma_broadcasts(name, d2):
    fn = NEIGHBORHOODS[name]
    sig = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
    h = fn(d2[None], sig.view(-1, 1, 1))  # (E, K, K)
    assert h.shape == (3, ROWS * COLS, ROWS * COLS)
    for e in range(3):
        assert torch.equal(h[e], fn(d2, sig[e]))
