"""The reference SOM: MiniSom (the library the paper cites), driven seed by seed.

MiniSom is an optional dependency, imported on the first call (``pip install minisom``). Each seed
trains its own ``MiniSom`` on the CPU in float64, one sample per step (Kohonen's online rule with
MiniSom's asymptotic decay of α and σ); the weights are returned in somtorch's layout so that they
can be scored with the same code as :class:`somtorch.SOM`.

Grid convention: MiniSom's ``weights[i, j]`` has ``i`` in ``range(x)`` and ``j`` in ``range(y)``;
we build ``MiniSom(x=rows, y=cols, ...)``, so ``i`` is the row and ``j`` the column, the
neighbourhood ``exp(−((i − i')² + (j − j')²) / 2σ²)`` uses the grid distance of
:func:`somtorch.core.grid.grid_sqdist` for a rectangular map, and the row-major reshape gives neuron
``k = r * cols + c``, as :func:`somtorch.core.grid.grid_coordinates` numbers them (tested: somtorch's
online SOM started from MiniSom's initial weights on a 3x5 map lands on the driver's weights).

MiniSom specifics worth knowing when comparing: ``random_weights_init`` draws samples *with*
replacement; ``pca_weights_init`` spans mean ± the *unit* principal directions (not scaled by the
standard deviations as :func:`somtorch.core.init.init_pca`); with ``order="random"`` MiniSom shuffles
the T = iterations indices ``arange(T) % N`` as one block, so a sample is not seen exactly once per
epoch; α and σ decay per step over T (``asymptotic_decay``).
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import numpy as np
import torch

from .._optional import optional_import
from ..core.grid import default_sigma
from ..validation import check_choice, check_positive, check_positive_int, check_tensor

__all__ = ["MINISOM_INITS", "MINISOM_NEIGHBORHOODS", "MINISOM_ORDERS", "import_minisom", "train_minisom"]

MINISOM_INITS = ("sample", "pca", "minisom")
"""``sample``: ``random_weights_init`` (random samples, drawn with replacement by MiniSom);
``pca``: ``pca_weights_init`` (mean ± unit principal directions, deterministic); ``minisom``: the
constructor's own draw (random unit-norm vectors)."""
MINISOM_NEIGHBORHOODS = ("gaussian", "mexican_hat", "bubble", "triangle")
MINISOM_ORDERS = ("random", "sequential")


def import_minisom():
    """Return the ``minisom`` module, or raise ``ImportError`` saying how to install it."""
    return optional_import("minisom", "minisom",
                           hint="MiniSom is needed only for the baseline somtorch.baselines.train_minisom "
                                "(or the baselines extra: pip install -e \".[baselines]\").")


def _check_seeds(seeds: Sequence[int]) -> list[int]:
    if isinstance(seeds, (str, bytes, torch.Tensor)) or not isinstance(seeds, Sequence):
        raise TypeError(f"seeds must be a sequence of ints, e.g. range(10); got {type(seeds).__name__}")
    out = []
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, numbers.Integral):
            raise TypeError(f"seeds must hold ints; got {type(s).__name__} {s!r}")
        if not 0 <= s < 2**32:
            raise ValueError(f"seeds must lie in [0, 2**32) (numpy RandomState); got {s}")
        out.append(int(s))
    if not out:
        raise ValueError("seeds is empty; give at least one seed, e.g. seeds=[0]")
    return out


def train_minisom(x: torch.Tensor, rows: int, cols: int, *, seeds: Sequence[int],
                  iterations: int | None = None, epochs: int = 10, sigma: float | None = None,
                  lr: float = 0.5, order: str = "random", neighborhood: str = "gaussian",
                  init: str = "sample") -> torch.Tensor:
    """Train one MiniSom per seed on ``x`` and return the weights in somtorch's layout.

    For each seed: ``MiniSom(rows, cols, D, sigma=sigma, learning_rate=lr,
    neighborhood_function=neighborhood, random_seed=seed)``, the chosen initialisation, then
    ``som.train(data, T, random_order=(order == "random"))`` with ``T = iterations`` or
    ``epochs * N`` single-sample updates (MiniSom's defaults for everything else: asymptotic
    decay of α and σ, rectangular topology, Euclidean distance).

    Args:
        x: samples ``(N, D)``, floating point, finite; passed to MiniSom as float64 numpy.
        rows, cols: grid size; ``K = rows * cols``.
        seeds: one MiniSom per seed (``random_seed``; it drives the initialisation and the order).
        iterations: number of single-sample updates T (``>= 1``, MiniSom rejects 0); default
            ``epochs * N``.
        epochs: passes over the data when ``iterations`` is None.
        sigma: initial neighbourhood radius in grid units; default ``max(rows, cols) / 2``.
        lr: initial learning rate.
        order: ``"random"`` (MiniSom shuffles its T indices with the seed's generator) or
            ``"sequential"`` (0, 1, …, N−1, 0, …).
        neighborhood: ``"gaussian"``, ``"mexican_hat"``, ``"bubble"`` or ``"triangle"`` (MiniSom warns
            when σ is not an integer for the last two).
        init: ``"sample"`` (``random_weights_init``), ``"pca"`` (``pca_weights_init``; needs D >= 2)
            or ``"minisom"`` (the constructor's random unit vectors).

    Returns:
        weights ``(E, K, D)`` float32 on the CPU, E = ``len(seeds)``, neuron ``k = r * cols + c``.

    Raises:
        ImportError: MiniSom is not installed (``pip install minisom``).
        TypeError / ValueError: bad arguments, before any training.

    Shape:
        - x: ``(N, D)``
        - returns: ``(E, rows * cols, D)``
    """
    check_tensor("x", x, ndim=2, floating=True, finite=True)
    rows = check_positive_int("rows", rows)
    cols = check_positive_int("cols", cols)
    seeds = _check_seeds(seeds)
    n, d = x.shape
    if d == 0:
        raise ValueError(f"x has no features (shape {tuple(x.shape)})")
    if iterations is not None:
        iterations = check_positive_int("iterations", iterations)
    epochs = check_positive_int("epochs", epochs)
    for name, value in (("sigma", sigma), ("lr", lr)):
        if isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a Python number for MiniSom; got a tensor (use float(...))")
    if sigma is not None:
        check_positive("sigma", sigma)
    check_positive("lr", lr)
    check_choice("order", order, MINISOM_ORDERS)
    check_choice("neighborhood", neighborhood, MINISOM_NEIGHBORHOODS)
    check_choice("init", init, MINISOM_INITS)
    if init == "pca" and d < 2:
        raise ValueError(f"init='pca' needs at least 2 features; x has D={d} (use init='sample')")
    minisom = import_minisom()

    data = np.ascontiguousarray(x.detach().cpu().double().numpy())  # (N, D) float64
    steps = iterations if iterations is not None else epochs * n
    radius = float(sigma) if sigma is not None else default_sigma(rows, cols)
    out = []
    for seed in seeds:
        som = minisom.MiniSom(rows, cols, d, sigma=radius, learning_rate=float(lr),
                              neighborhood_function=neighborhood, random_seed=seed)
        if init == "sample":
            som.random_weights_init(data)
        elif init == "pca":
            som.pca_weights_init(data)
        som.train(data, steps, random_order=(order == "random"))
        w = np.asarray(som.get_weights())  # (rows, cols, D): w[r, c]
        # row-major: neuron k = r * cols + c holds w[r, c]
        out.append(torch.from_numpy(w.reshape(rows * cols, d).astype(np.float32)))
    return torch.stack(out)  # (E, K, D)
