"""Chunked best-matching-unit (BMU) search.

Distances use the expansion ``‖x − w‖² = ‖x‖² − 2 x·w + ‖w‖²``; the ``‖x‖²`` term does not change
the ranking, so the search computes ``‖w‖² − 2 x·w`` with one ``addmm``/``baddbmm`` per chunk and
never holds more than ``chunk_elements`` scores at once, whatever N is. Rows are processed in chunks
so a 100-million-pixel input needs no N×K matrix.

On the CPU, the nearest one or two units come from the fused C++ kernel of
:mod:`somtorch.core.native` (exact squared distances, first index on ties, no score matrix at all)
whenever it builds; ``SOMTORCH_NATIVE=0`` forces the torch path above.
"""

from __future__ import annotations

import torch

from .. import interrupt
from .native import native_bmu

DEFAULT_CHUNK_ELEMENTS = 1 << 22  # scores per chunk (16 MiB in float32)


def _chunk_rows(n: int, per_row: int, chunk_elements: int) -> int:
    return max(1, min(n, chunk_elements // max(per_row, 1)))


def _scores(x: torch.Tensor, weight: torch.Tensor, wsq: torch.Tensor) -> torch.Tensor:
    """``‖w‖² − 2 x·w`` for one chunk: (n, D) shared → (n, E, K); (E, n, D) → (E, n, K)."""
    e, k, d = weight.shape
    if x.ndim == 2:
        s = torch.addmm(wsq.reshape(1, e * k), x, weight.reshape(e * k, d).T, alpha=-2.0)  # (n, E*K)
        return s.view(-1, e, k)
    return torch.baddbmm(wsq[:, None, :], x, weight.transpose(1, 2), alpha=-2.0)  # (E, n, K)


@torch.no_grad()
def bmu_search(x: torch.Tensor, weight: torch.Tensor, *, k: int = 1,
               chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """Indices of the ``k`` nearest neurons of every sample (Euclidean), nearest first.

    Args:
        x: samples, shared by all members ``(N, D)`` or per member ``(E, N, D)``.
        weight: reference vectors ``(E, K, D)``.
        k: how many nearest neurons (1 = the BMU).
        chunk_elements: bound on the number of scores held at once.

    Shape:
        returns ``(E, N)`` for k = 1, else ``(E, N, k)``; dtype long.

    On the CPU, k = 1 and k = 2 use the fused kernel of :mod:`somtorch.core.native` when it is
    available (exact squared distances ``Σ_d (x_d − w_d)²``, no score matrix); elsewhere, or with
    ``SOMTORCH_NATIVE=0``, the chunked ``‖w‖² − 2 x·w`` expansion below.
    """

    if k in (1, 2):
        fused = native_bmu(x, weight, k=k)
        if fused is not None:
            return fused
    e, kk, _ = weight.shape
    n = x.shape[-2]
    wsq = weight.square().sum(-1)  # (E, K)
    out = torch.empty((e, n) if k == 1 else (e, n, k), dtype=torch.long, device=weight.device)
    step = _chunk_rows(n, e * kk, chunk_elements)
    for s in range(0, n, step):
        interrupt.checkpoint()  # a pending SIGINT / SIGTERM stops the search here (somtorch.interrupt)
        xs = x[s:s + step] if x.ndim == 2 else x[:, s:s + step]
        sc = _scores(xs, weight, wsq)
        if k == 1:
            idx = sc.argmin(-1)
        else:
            idx = sc.topk(k, dim=-1, largest=False, sorted=True).indices
        if x.ndim == 2:
            idx = idx.transpose(0, 1)  # (n, E[, k]) → (E, n[, k])
        out[:, s:s + step] = idx
    return out


def gather_weights(weight: torch.Tensor, bmu: torch.Tensor) -> torch.Tensor:
    """The reference vector of each sample's BMU.

    Shape:
        ``weight`` ``(E, K, D)``, ``bmu`` ``(E, N)`` → ``(E, N, D)``.
    """
    return torch.gather(weight, 1, bmu[..., None].expand(-1, -1, weight.shape[-1]))


def pairwise_sqdist(x: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Squared distances of every sample to every neuron (differentiable, not chunked).

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)`` → ``(E, N, K)``.
    """
    xe = x.unsqueeze(0).expand(weight.shape[0], -1, -1) if x.ndim == 2 else x
    xsq = xe.square().sum(-1, keepdim=True)  # (E, N, 1)
    wsq = weight.square().sum(-1)[:, None, :]  # (E, 1, K)
    return torch.baddbmm(xsq + wsq, xe, weight.transpose(1, 2), alpha=-2.0).clamp_min(0.0)
