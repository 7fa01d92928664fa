"""Paper step 1b: segmentation — every valid pixel goes to its best-matching unit.

One neuron = one segment, so a label map has values 0 … K−1 and −1 at pixels without a disparity.
"""

from __future__ import annotations

import torch

from .. import interrupt
from ..core.distance import DEFAULT_CHUNK_ELEMENTS, bmu_search
from ..validation import check_tensor


def segment(weight: torch.Tensor, x: torch.Tensor, pixels: torch.Tensor, shape: tuple[int, int], *,
            chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """Label map of every member: BMU index per pixel, −1 where there is no feature vector.

    Args:
        weight: SOM reference vectors ``(E, K, D)`` in feature units.
        x: feature vectors of the pixels ``(N, D)``.
        pixels: their (y, x) coordinates ``(N, 2)`` long.
        shape: ``(H, W)`` of the map.

    Shape:
        returns ``(E, H, W)`` long.
    """
    check_tensor("weight", weight, ndim=3, floating=True)
    check_tensor("x", x, ndim=2, last_dim=weight.shape[-1])
    check_tensor("pixels", pixels, ndim=2, last_dim=2)
    if pixels.shape[0] != x.shape[0]:
        raise ValueError(f"pixels has {pixels.shape[0]} rows but x has {x.shape[0]}")
    h, w = shape
    labels = torch.full((weight.shape[0], h * w), -1, dtype=torch.long, device=weight.device)
    flat = pixels[:, 0] * w + pixels[:, 1]
    per = members_per_call(x.shape[0], weight.shape[1])
    for e0 in range(0, weight.shape[0], per):  # members in groups: a signal stops between them
        interrupt.checkpoint()
        labels[e0:e0 + per, flat] = bmu_search(x, weight[e0:e0 + per], chunk_elements=chunk_elements)
    return labels.view(-1, h, w)


def members_per_call(n: int, k: int, work: int = 1 << 27) -> int:
    """Members whose BMU search :func:`segment` does in one call: about ``work`` distances (a
    fraction of a second), so that an interrupt is honoured quickly and the ``(E', N)`` indices stay small."""
    return max(1, work // max(1, n * k))


def grey_map(labels: torch.Tensor, ref_disparity: torch.Tensor) -> torch.Tensor:
    """Paint each segment with its neuron's reference disparity (NaN where invalid).

    Shape:
        ``labels`` ``(E, H, W)``, ``ref_disparity`` ``(E, K)`` → ``(E, H, W)`` float.
    """
    e, h, w = labels.shape
    lut = torch.cat([ref_disparity, torch.full_like(ref_disparity[:, :1], float("nan"))], dim=1)  # (E, K+1)
    idx = torch.where(labels < 0, ref_disparity.shape[1], labels).view(e, -1)
    return torch.gather(lut, 1, idx).view(e, h, w)


def color_map(labels: torch.Tensor, num_neurons: int, *, seed: int = 0) -> torch.Tensor:
    """Paint each segment with a random colour (the paper's Fig. 12); black where invalid.

    Shape:
        ``labels`` ``(E, H, W)`` → ``(E, H, W, 3)`` uint8.
    """
    g = torch.Generator().manual_seed(seed)
    palette = torch.randint(40, 256, (num_neurons + 1, 3), generator=g, dtype=torch.uint8)
    palette[num_neurons] = 0
    idx = torch.where(labels < 0, num_neurons, labels).cpu()
    return palette[idx]
