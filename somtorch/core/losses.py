"""Differentiable SOM objectives, so a map can sit inside a network and train with ``torch.optim``.

* soft assignment: ``softmax(−‖x − w_k‖² / τ)`` over the neurons — a differentiable BMU.
* SOM energy (Heskes 1999): ``E = mean_n Σ_k h(r_{c(n)}, r_k; σ) ‖x_n − w_k‖²`` with the winner
  ``c(n) = argmin_k ‖x_n − w_k‖²`` taken as a constant (no gradient flows through the argmin).
  Its gradient step at fixed winners is exactly a (mini-)batch Kohonen update.
"""

from __future__ import annotations

import torch

from .distance import pairwise_sqdist
from .neighborhood import NeighborhoodFn


def soft_assign(x: torch.Tensor, weight: torch.Tensor, temperature: float | torch.Tensor) -> torch.Tensor:
    """Soft BMU weights, differentiable w.r.t. ``x`` and ``weight``; ``temperature`` scalar or ``(E,)``.

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)`` → ``(E, N, K)``, rows sum to 1.
    """
    tau = torch.as_tensor(temperature, dtype=weight.dtype, device=weight.device).reshape(-1, 1, 1)
    return torch.softmax(-pairwise_sqdist(x, weight) / tau, dim=-1)


def som_energy(x: torch.Tensor, weight: torch.Tensor, grid_d2: torch.Tensor, sigma: torch.Tensor,
               neighborhood: NeighborhoodFn, *, normalize: bool = True) -> torch.Tensor:
    """Neighbourhood-weighted squared distances to all units, centred on each sample's BMU.

    Args:
        normalize: divide each sample's weights by their sum so that the loss is on the scale of a
            squared distance whatever σ is.

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)``, ``grid_d2`` ``(K, K)``, ``sigma``
        scalar or ``(E,)`` → ``(E,)`` (one loss per member; ``.sum()`` it to train an ensemble).
    """
    d2 = pairwise_sqdist(x, weight)  # (E, N, K)
    with torch.no_grad():
        c = d2.argmin(-1)  # (E, N)
    sig = torch.as_tensor(sigma, dtype=weight.dtype, device=weight.device).reshape(-1, 1, 1)
    h = neighborhood(grid_d2[c], sig)  # (E, N, K)
    if normalize:
        h = h / h.sum(-1, keepdim=True).clamp_min(1e-12)
    return (h * d2).sum(-1).mean(-1)
