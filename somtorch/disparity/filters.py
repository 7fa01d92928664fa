"""Clean-up of computed disparity maps before they become SOM input.

Block matchers (SGBM) leave speckles: small islands whose disparity differs from everything around
them (mismatches on textureless walls, at the search limit, at the rectification border). They
are rare in ground truth but carry the largest contrast of a computed map, so the object-area rule
would pick them. :func:`remove_speckles` marks them invalid with OpenCV's ``filterSpeckles``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from ..validation import check_positive, check_tensor


def remove_speckles(disparity: torch.Tensor, valid: torch.Tensor, *, max_size_frac: float = 0.001,
                    max_diff_frac: float = 0.02) -> torch.Tensor:
    """Valid mask without speckles.

    A speckle is a 4-connected region of pixels whose neighbours differ by at most
    ``max_diff_frac × spread`` (spread = 1st–99th percentile range of the valid disparities) and that
    holds fewer than ``max_size_frac × H·W`` pixels.

    Shape:
        ``disparity``, ``valid``: ``(H, W)`` → ``(H, W)`` bool.
    """
    check_tensor("disparity", disparity, ndim=2, floating=True)
    check_tensor("valid", valid, ndim=2, dtype=torch.bool)
    check_positive("max_size_frac", max_size_frac, allow_zero=True)
    check_positive("max_diff_frac", max_diff_frac)
    if max_size_frac == 0 or not bool(valid.any()):
        return valid.clone()
    h, w = disparity.shape
    d = disparity.detach().cpu().numpy().astype(np.float64)
    ok = valid.cpu().numpy()
    vals = d[ok]
    lo, hi = np.percentile(vals, [1, 99]) if vals.size > 1 else (vals.min(), vals.max())
    spread = max(float(hi - lo), 1e-6)
    # fixed point with 1/16 px resolution over the map's range, 0 reserved for invalid
    scale = min(16.0, 30000.0 / max(float(vals.max()), 1e-6))
    q = np.where(ok, np.clip(np.round(d * scale), 1, 32767), 0).astype(np.int16)
    cv2.filterSpeckles(q, 0, max(1, int(max_size_frac * h * w)), max(1, int(round(max_diff_frac * spread * scale))))
    return torch.from_numpy(q != 0).to(valid.device) & valid


def median_noise(sigma: float, size: int) -> float:
    """The per-pixel noise (px, a standard deviation) left by :func:`median_filter` with a ``size ×
    size`` window on a map with Gaussian noise ``sigma``: the median of n = size² samples errs by
    σ·√(π / (2n)) = σ·√(π/2) / size (its asymptotic standard error; measured 0.41 σ for size 3 on
    the corpus's noisy floors against 0.418 σ). The neighbour differences of the filtered map cannot
    measure it (:func:`~somtorch.tasks.ground.noise_sigma` reads 0.18 σ there): neighbouring windows
    share two thirds of their pixels, so their medians err alike. ``size`` ≤ 1: ``sigma``.

    >>> round(median_noise(0.8, 3), 3)
    0.334
    """
    return float(sigma) if size <= 1 else float(sigma) * math.sqrt(math.pi / 2.0) / size


def median_filter(disparity: torch.Tensor, valid: torch.Tensor, size: int, *,
                  rows: int = 256) -> torch.Tensor:
    """The median of the valid disparities in the ``size × size`` window around each valid pixel
    (invalid pixels keep their value and are never read; an even count takes the lower middle
    value, :func:`torch.nanmedian`). Edge-preserving: a surface's per-pixel noise goes, a depth edge
    stays where more than half the window lies on one side of it. ``size`` ≤ 1: a copy.

    Computed ``rows`` rows at a time (the window's values of a block are held at once).

    Shape:
        ``disparity``, ``valid``: ``(H, W)`` → ``(H, W)``, the dtype of ``disparity``.
    """
    check_tensor("disparity", disparity, ndim=2, floating=True)
    check_tensor("valid", valid, ndim=2, dtype=torch.bool)
    if size <= 1:
        return disparity.clone()
    if size % 2 == 0:
        raise ValueError(f"median_filter: size must be odd; got {size}")
    r = size // 2
    h, w = disparity.shape
    nan = torch.full((), float("nan"), dtype=disparity.dtype, device=disparity.device)
    padded = torch.nn.functional.pad(torch.where(valid, disparity, nan)[None, None], (r, r, r, r),
                                     value=float("nan"))[0, 0]
    out = disparity.clone()
    for y0 in range(0, h, rows):
        y1 = min(h, y0 + rows)
        block = padded[y0:y1 + 2 * r].unfold(0, size, 1).unfold(1, size, 1)  # (rows, W, size, size)
        med = block.reshape(y1 - y0, w, size * size).nanmedian(-1).values
        out[y0:y1] = torch.where(valid[y0:y1], med, disparity[y0:y1])
    return out
