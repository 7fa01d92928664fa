"""Neighbourhood functions h(d², σ) of the SOM, all radial on the grid.

Each takes squared grid distances ``d2`` and a radius ``sigma`` broadcastable to it and returns the
neighbourhood weight (1 at the winner for every function). The learning rate is applied by the
caller: ``h_ci(t) = α(t) · h(‖r_c − r_i‖², σ(t))``.

* gaussian: ``exp(−d²/2σ²)`` (Kohonen 2001; the paper's choice)
* bubble: ``1[d ≤ σ]`` (radial; MiniSom's bubble is a square box instead)
* mexican_hat: ``exp(−d²/2σ²) · (1 − d²/σ²)`` (same formula as MiniSom)
* triangle: ``max(0, 1 − d/σ)`` (radial and normalised; MiniSom's is a separable, unnormalised box)
"""

from __future__ import annotations

from collections.abc import Callable

import torch

NeighborhoodFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def gaussian(d2: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Gaussian neighbourhood ``exp(−d²/(2σ²))``."""
    return torch.exp(d2 / (-2.0 * sigma * sigma))


def bubble(d2: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Bubble (step) neighbourhood: 1 inside radius σ, 0 outside."""
    return (d2 <= sigma * sigma).to(d2.dtype)


def mexican_hat(d2: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Mexican hat (Ricker) neighbourhood ``exp(−d²/2σ²)(1 − d²/σ²)``; negative in a ring."""
    s2 = sigma * sigma
    return torch.exp(d2 / (-2.0 * s2)) * (1.0 - d2 / s2)


def triangle(d2: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Triangular (cone) neighbourhood ``max(0, 1 − d/σ)``."""
    return torch.clamp(1.0 - torch.sqrt(d2) / sigma, min=0.0)


NEIGHBORHOODS: dict[str, NeighborhoodFn] = {
    "gaussian": gaussian,
    "bubble": bubble,
    "mexican_hat": mexican_hat,
    "triangle": triangle,
}
