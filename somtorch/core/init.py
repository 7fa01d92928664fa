"""Initialisation of the reference vectors from data.

* ``random``: uniform within the bounding box of the data (per feature).
* ``sample``: K distinct random samples of the data (fewer samples than neurons: with repetition).
* ``pca``: Kohonen's linear initialisation — the neurons span the plane of the first two principal
  components around the mean, ±1 standard deviation along each, the larger component along the
  longer grid axis. Deterministic (identical for every ensemble member) and usually the fastest to
  converge.

Every random method draws only from the per-member generators it is given, so member e of an
ensemble gets exactly what a solo SOM with that member's seed gets.
"""

from __future__ import annotations

import torch

from ..config.options import INITS  # noqa: F401  (re-exported: core.som and the tests read it here)


def init_random(x: torch.Tensor, k: int, generator: torch.Generator,
                bounds: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
    """Uniform in the data's bounding box (``bounds`` = precomputed (min, max) per feature).

    Shape: ``x`` ``(N, D)`` → ``(K, D)``.
    """
    lo, hi = bounds if bounds is not None else (x.amin(0), x.amax(0))
    u = torch.rand(k, x.shape[1], generator=generator, dtype=torch.float64, device=x.device)
    return (lo.double() + u * (hi - lo).double()).to(x.dtype)


def init_sample(x: torch.Tensor, k: int, generator: torch.Generator) -> torch.Tensor:
    """Random data samples. Shape: ``x`` ``(N, D)`` → ``(K, D)``."""
    n = x.shape[0]
    if n >= k:
        idx = torch.randperm(n, generator=generator, device=x.device)[:k]
    else:
        idx = torch.randint(n, (k,), generator=generator, device=x.device)
    return x[idx].clone()


def init_pca(x: torch.Tensor, rows: int, cols: int) -> torch.Tensor:
    """Linear initialisation along the first two principal components. ``(N, D)`` → ``(K, D)``."""
    xd = x.double()
    mean = xd.mean(0)
    n, d = xd.shape
    cov = (xd - mean).T @ (xd - mean) / max(n - 1, 1)
    evals, evecs = torch.linalg.eigh(cov)  # ascending
    order = torch.argsort(evals, descending=True)
    evals = evals[order].clamp_min(0.0)
    evecs = evecs[:, order]
    # fix the sign of each component so that the result does not depend on the LAPACK build
    flip = torch.sign(evecs[evecs.abs().argmax(0), torch.arange(d)])
    evecs = evecs * torch.where(flip == 0, torch.ones_like(flip), flip)
    axes = evecs * evals.sqrt()  # (D, D): column j = j-th component scaled by its std
    a1 = axes[:, 0]
    a2 = axes[:, 1] if d > 1 else torch.zeros_like(a1)
    along_r = torch.linspace(-1.0, 1.0, rows, dtype=torch.float64) if rows > 1 else torch.zeros(1, dtype=torch.float64)
    along_c = torch.linspace(-1.0, 1.0, cols, dtype=torch.float64) if cols > 1 else torch.zeros(1, dtype=torch.float64)
    r = along_r.repeat_interleave(cols).to(x.device)[:, None]
    c = along_c.repeat(rows).to(x.device)[:, None]
    if rows >= cols:
        w = mean + r * a1 + c * a2
    else:
        w = mean + c * a1 + r * a2
    return w.to(x.dtype)
