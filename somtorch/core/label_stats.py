"""The object step's one pass over a label map, in the native library of :mod:`somtorch.core.native`
(``somtorch_label_stats`` in ``csrc/bmu.cpp``): per-label pixel counts, sums of weight maps, boxes,
the label pairs of the 4-connected pixel pairs and a (label, group) table — the numbers of
``torch.bincount`` on the corresponding keys, without building the keys. It knows nothing of
disparity: the callers (:func:`somtorch.tasks.objects.neuron_stats` and the support link's checks)
pass the maps to sum, and keep their torch paths for when :func:`native_label_stats` returns None.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .native import _note, enabled, library

__all__ = ["LabelStats", "native_label_stats"]


@dataclass
class LabelStats:
    """What :func:`native_label_stats` counts on a label map with ``K`` labels.

    Attributes:
        count: pixels per label ``(K,)`` long.
        sums: per weight map, the sum of its values over each label's pixels ``(M, K)`` float64,
            added in row-major pixel order (the order of ``torch.bincount``: the same bits).
        box: per label ``(x0, y0, x1, y1)`` inclusive ``(K, 4)`` long; ``(W, H, −1, −1)`` for an
            absent label.
        pairs: ``pairs[a, b]`` = the 4-connected pixel pairs with label ``a`` first (left or above)
            and ``b`` second, ``a ≠ b``, both labelled ``(K, K)`` long (zero diagonal); None unless
            asked for.
        continuous: the same, counting only the pairs flagged by ``continuity``; None without it.
        groups: pixels per (label, group) ``(K, G)`` long; None without ``groups``.
    """

    count: torch.Tensor
    sums: torch.Tensor
    box: torch.Tensor
    pairs: torch.Tensor | None = None
    continuous: torch.Tensor | None = None
    groups: torch.Tensor | None = None


@torch.no_grad()
def native_label_stats(labels: torch.Tensor, k: int, weights: list[torch.Tensor] | None = None, *,
                       pairs: bool = False, continuity: torch.Tensor | None = None,
                       groups: torch.Tensor | None = None, n_groups: int = 0) -> LabelStats | None:
    """One pass over a label map: per-label pixel counts, sums of ``weights`` maps, boxes, and (with
    ``pairs``) the label pairs of the 4-connected pixel pairs, horizontal ones row by row, then the
    vertical ones (``continuity`` ``(H·(W−1) + (H−1)·W,)`` bool flags some of them in that order);
    ``groups`` ``(H, W)`` long in ``[0, n_groups)`` counts each label's pixels per group. The
    numbers of ``torch.bincount`` on the corresponding keys, without building the keys (the object
    step's per-map pass, :func:`somtorch.tasks.objects.neuron_stats`). Single-threaded: a map of
    ~10⁵ pixels takes a fraction of a millisecond.

    Returns None whenever the kernel cannot serve the call — ``SOMTORCH_NATIVE=0``, no library,
    tensors off the CPU, a label outside ``[−1, k)`` or a labelled pixel's group outside
    ``[0, n_groups)`` — and the caller uses its torch path.

    Shape:
        ``labels`` ``(H, W)`` long (−1 = no label); each weight map ``(H, W)``.
    """
    if not enabled():
        return None
    h, w = labels.shape
    n_pairs = max(h * (w - 1), 0) + max((h - 1) * w, 0)
    tensors = [labels, *(weights or []), *([] if continuity is None else [continuity]),
               *([] if groups is None else [groups])]
    if labels.dtype != torch.long or any(t.device.type != "cpu" for t in tensors) or k < 1 \
            or (groups is not None and (groups.shape != labels.shape or groups.dtype != torch.long
                                        or n_groups < 1)) \
            or any(t.shape != labels.shape for t in weights or []) \
            or (continuity is not None and (not pairs or continuity.numel() != n_pairs)):
        return None
    lib = library()
    if lib is None:
        return None
    lab = labels.contiguous()
    m = len(weights or [])
    wts = torch.stack([t.double() for t in weights]).contiguous() if m else torch.zeros(1, dtype=torch.double)
    cont = None if continuity is None else continuity.to(torch.uint8).contiguous()
    grp = None if groups is None else groups.contiguous()
    count = torch.zeros(k, dtype=torch.long)
    sums = torch.zeros(m, k, dtype=torch.float64)
    box = torch.empty(k, 4, dtype=torch.long)
    pair = torch.zeros(k, k, dtype=torch.long) if pairs else None
    cpair = torch.zeros(k, k, dtype=torch.long) if cont is not None else None
    gcount = torch.zeros(k, n_groups, dtype=torch.long) if grp is not None else None

    def ptr(t: torch.Tensor | None) -> int | None:
        return None if t is None else t.data_ptr()

    rc = lib.somtorch_label_stats(lab.data_ptr(), h, w, k, wts.data_ptr(), m, ptr(cont), ptr(grp),
                                  n_groups if grp is not None else 0, int(pairs), count.data_ptr(),
                                  sums.data_ptr(), box.data_ptr(), ptr(pair), ptr(cpair), ptr(gcount))
    if rc != 0:
        _note(f"label statistics refused (code {rc}: a label outside [-1, {k}) or a group outside "
              f"[0, {n_groups})); the torch path counts them")
        return None
    return LabelStats(count, sums, box, pair, cpair, gcount)
