"""Quality measures of a trained map, as pure functions of the weights.

* quantization error: mean Euclidean distance of each sample to its BMU (as MiniSom).
* topographic error: share of samples whose best and second-best units are not adjacent on the map
  (8-neighbourhood on rectangular maps, 6 on hexagonal; as MiniSom).
* U-matrix: mean distance of each neuron's reference vector to those of its adjacent neurons.
"""

from __future__ import annotations

import torch

from .distance import DEFAULT_CHUNK_ELEMENTS, bmu_search, gather_weights


@torch.no_grad()
def quantization_error(x: torch.Tensor, weight: torch.Tensor, *,
                       chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """Mean distance to the BMU.

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)`` → ``(E,)``.
    """
    e = weight.shape[0]
    n = x.shape[-2]
    total = torch.zeros(e, dtype=torch.float64, device=weight.device)
    step = max(1, chunk_elements // max(e * weight.shape[1], 1))
    for s in range(0, n, step):
        xs = x[s:s + step] if x.ndim == 2 else x[:, s:s + step]
        b = bmu_search(xs, weight, chunk_elements=chunk_elements)  # (E, n)
        w = gather_weights(weight, b)  # (E, n, D)
        # summed in float64, so that the chunking (which depends on E) does not change the float32 result
        total += torch.linalg.vector_norm(xs - w, dim=-1).double().sum(-1)
    return (total / n).to(weight.dtype)


@torch.no_grad()
def topographic_error(x: torch.Tensor, weight: torch.Tensor, adjacency: torch.Tensor, *,
                      chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """Share of samples whose two best units are not adjacent.

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)``, ``adjacency`` ``(K, K)`` bool →
        ``(E,)``. A 1-neuron map has no second unit: NaN.
    """
    e, k, _ = weight.shape
    if k < 2:
        return torch.full((e,), float("nan"), dtype=weight.dtype, device=weight.device)
    top2 = bmu_search(x, weight, k=2, chunk_elements=chunk_elements)  # (E, N, 2)
    ok = adjacency[top2[..., 0], top2[..., 1]]  # (E, N)
    return (~ok).double().mean(-1).to(weight.dtype)


def umatrix(weight: torch.Tensor, adjacency: torch.Tensor, rows: int, cols: int) -> torch.Tensor:
    """Mean distance of each neuron to its adjacent neurons (unnormalised U-matrix).

    Shape:
        ``weight`` ``(E, K, D)``, ``adjacency`` ``(K, K)`` → ``(E, rows, cols)``.
    """
    dist = torch.cdist(weight, weight)  # (E, K, K)
    adj = adjacency.to(weight.dtype)
    u = (dist * adj).sum(-1) / adj.sum(-1).clamp_min(1.0)
    return u.view(weight.shape[0], rows, cols)
