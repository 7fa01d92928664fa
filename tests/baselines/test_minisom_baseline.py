"""The MiniSom driver: same weights as MiniSom used directly, in somtorch's row-major neuron order.

The numerical agreement of MiniSom and somtorch's online rule is tested in
``tests/core/test_minisom_oracle.py``; here only the driver (arguments passed through, reshape).
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
from minisom import MiniSom

from somtorch import SOM
from somtorch.baselines import train_minisom

ROWS, COLS = 3, 5  # not square: a transposed reshape would be caught


@pytest.fixture(scope="module")
def data() -> np.ndarray:
    """120 points in 3-D, float64."""
    rng = np.random.RandomState(0)
    return np.vstack([rng.randn(40, 3) * 0.2 + m for m in ([0, 0, 0], [2, 1, 0], [0, 2, 2])])


def direct(data: np.ndarray, seed: int, init: str, steps: int, random_order: bool,
           sigma: float) -> np.ndarray:
    som = MiniSom(ROWS, COLS, data.shape[1], sigma=sigma, learning_rate=0.5, random_seed=seed)
    if init == "sample":
        som.random_weights_init(data)
    elif init == "pca":
        som.pca_weights_init(data)
    som.train(data, steps, random_order=random_order)
    return som.get_weights()  # (ROWS, COLS, D)


@pytest.mark.parametrize("init", ["sample", "pca", "minisom"])
@pytest.mark.parametrize("order", ["random", "sequential"])
def test_equals_minisom_used_directly(data, init, order):
    got = train_minisom(torch.from_numpy(data), ROWS, COLS, seeds=[4, 9], iterations=300, order=order,
                        init=init)
    assert got.shape == (2, ROWS * COLS, 3) and got.dtype == torch.float32
    for e, seed in enumerate((4, 9)):
        want = direct(data, seed, init, 300, order == "random", sigma=max(ROWS, COLS) / 2)
        for r in range(ROWS):
            for c in range(COLS):  # neuron k = r * cols + c holds MiniSom's weights[r, c]
                assert torch.equal(got[e, r * COLS + c], torch.from_numpy(want[r, c]).float())
    if order == "random":  # the seed drives the order (and the init): the maps differ. (In sequential order
        # 300 steps with a large σ forget the initial weights below float32 resolution: equal maps are fine)
        assert not torch.equal(got[0], got[1])


def test_epochs_default_to_epochs_times_n(data):
    x = torch.from_numpy(data)
    a = train_minisom(x, ROWS, COLS, seeds=[1], epochs=2, sigma=1.5)
    b = train_minisom(x, ROWS, COLS, seeds=[1], iterations=2 * len(data), sigma=1.5)
    assert torch.equal(a, b)


def test_reshape_matches_somtorch_grid(data):
    """Trained from MiniSom's own initial weights, somtorch's online SOM (row-major grid) lands on the
    driver's weights; on a 3x5 map a column-major or transposed reshape would not."""
    seed, steps, sigma = 2, 240, 1.5
    got = train_minisom(torch.from_numpy(data), ROWS, COLS, seeds=[seed], iterations=steps, sigma=sigma,
                        order="sequential", init="minisom")
    w0 = MiniSom(ROWS, COLS, 3, sigma=sigma, random_seed=seed).get_weights()  # the constructor's draw
    som = SOM(ROWS, COLS, 3, dtype=torch.float64, seed=seed)
    som.weight = torch.from_numpy(w0.reshape(ROWS * COLS, 3).copy())
    som.fit(torch.from_numpy(data), mode="online", iterations=steps, order="sequential", lr=0.5, sigma=sigma,
            lr_decay="asymptotic", sigma_decay="asymptotic", progress=False)
    ours = som.weight.detach()[0].float()
    assert (ours - torch.from_numpy(w0.reshape(ROWS * COLS, 3)).float()).abs().max() > 0.1  # it trained
    torch.testing.assert_close(got[0], ours, rtol=0, atol=1e-6)


def test_missing_minisom_says_how_to_install(monkeypatch, data):
    monkeypatch.setitem(sys.modules, "minisom", None)  # what Python does for a blocked/absent module
    with pytest.raises(ImportError, match="pip install minisom"):
        train_minisom(torch.from_numpy(data), ROWS, COLS, seeds=[0], iterations=5)


BAD = [
    (dict(x=np.zeros((5, 2))), TypeError, "x must be a torch.Tensor"),
    (dict(x=torch.zeros(5)), ValueError, "x must have 2 dimensions"),
    (dict(x=torch.tensor([[float("inf"), 0.0]])), ValueError, "x contains 1 non-finite"),
    (dict(rows=0), ValueError, "rows must be a positive integer"),
    (dict(cols=2.5), TypeError, "cols must be a positive integer"),
    (dict(seeds=[]), ValueError, "seeds is empty"),
    (dict(seeds=3), TypeError, "seeds must be a sequence of ints"),
    (dict(seeds=[0, -1]), ValueError, "seeds must lie in"),
    (dict(iterations=0), ValueError, "iterations must be a positive integer"),
    (dict(epochs=0), ValueError, "epochs must be a positive integer"),
    (dict(sigma=0.0), ValueError, "sigma must be finite and > 0"),
    (dict(lr=torch.tensor(0.5)), TypeError, "lr must be a Python number"),
    (dict(order="shuffled"), ValueError, "order='shuffled' is not known; valid names: random, sequential"),
    (dict(neighborhood="cosine"), ValueError, "neighborhood='cosine' is not known"),
    (dict(init="random"), ValueError, "init='random' is not known"),
    (dict(x=torch.rand(10, 1), init="pca"), ValueError, "init='pca' needs at least 2 features"),
]


@pytest.mark.parametrize("kwargs,err,msg", BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_input_names_the_argument(kwargs, err, msg):
    args = dict(x=torch.rand(10, 2), rows=2, cols=3, seeds=[0])
    args.update(kwargs)
    with pytest.raises(err, match=msg):
        train_minisom(args.pop("x"), args.pop("rows"), args.pop("cols"), **args)
