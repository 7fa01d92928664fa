"""Salient-object-detection metrics of a kept mask against the objects' union.

So that the reduction compares with the RGB-D saliency literature, the three measures reported
there, written from their definitions (the ``pysodmetrics`` package is the test oracle):

* **F-measure** ``F_β = (1 + β²) P R / (β² P + R)`` with ``β² = 0.3`` (Achanta et al., CVPR 2009),
  of a binary prediction (the kept mask is binary, so the adaptive and maximum F-measures of the
  literature coincide with it).
* **MAE**, the mean absolute error between prediction and ground truth over the image.
* **S-measure** (Fan et al., ICCV 2017): ``α · S_object + (1 − α) · S_region``, ``α = 0.5``; the
  object term compares the foreground and background distributions, the region term is an
  SSIM-like score of the four quadrants around the ground truth's centroid.

Inputs are ``(H, W)`` arrays or tensors: the prediction in ``[0, 1]`` (bool accepted), the ground
truth bool.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["f_measure", "mae", "s_measure", "saliency_scores"]

_EPS = np.spacing(1)  # as the reference implementations


def _inputs(pred: Any, gt: Any) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(pred.detach().cpu().numpy() if hasattr(pred, "detach") else pred, dtype=np.float64)
    g = np.asarray(gt.detach().cpu().numpy() if hasattr(gt, "detach") else gt).astype(bool)
    if p.ndim != 2 or p.shape != g.shape:
        raise ValueError(f"prediction {p.shape} and ground truth {g.shape} must be the same 2-D shape")
    if p.size and (not np.isfinite(p).all() or p.min() < 0 or p.max() > 1):
        raise ValueError("the prediction must lie in [0, 1]")
    return p, g


def f_measure(pred: Any, gt: Any, beta2: float = 0.3) -> float:
    """``F_β`` of the prediction thresholded at 0.5 (a binary mask is its own threshold)."""
    p, g = _inputs(pred, gt)
    b = p >= 0.5
    tp = float((b & g).sum())
    precision = tp / (b.sum() + _EPS)
    recall = tp / (g.sum() + _EPS)
    return float((1 + beta2) * precision * recall / (beta2 * precision + recall + _EPS))


def mae(pred: Any, gt: Any) -> float:
    """Mean absolute error over the image."""
    p, g = _inputs(pred, gt)
    return float(np.abs(p - g).mean())


def _s_object(x: np.ndarray) -> float:
    mean = x.mean()
    std = x.std(ddof=1) if x.size > 1 else 0.0
    return float(2 * mean / (mean ** 2 + 1 + std + _EPS))


def _ssim(p: np.ndarray, g: np.ndarray) -> float:
    n = p.size
    x, y = p.mean() if n else 0.0, g.mean() if n else 0.0
    sx = ((p - x) ** 2).sum() / (n - 1 + _EPS)
    sy = ((g - y) ** 2).sum() / (n - 1 + _EPS)
    sxy = ((p - x) * (g - y)).sum() / (n - 1 + _EPS)
    a = 4 * x * y * sxy
    b = (x ** 2 + y ** 2) * (sx + sy)
    if a != 0:
        return float(a / (b + _EPS))
    return 1.0 if b == 0 else 0.0


def s_measure(pred: Any, gt: Any, alpha: float = 0.5) -> float:
    """Structure measure of Fan et al. (2017) in ``[0, 1]``."""
    p, g = _inputs(pred, gt)
    y = g.mean()
    if y == 0:
        return float(1 - p.mean())
    if y == 1:
        return float(p.mean())
    obj = _s_object(p[g]) * y + _s_object((1 - p)[~g]) * (1 - y)
    h, w = g.shape
    cy, cx = (int(c) + 1 for c in np.argwhere(g).mean(axis=0).round())  # as the MATLAB original
    area = h * w
    w_lt, w_rt, w_lb = cx * cy / area, cy * (w - cx) / area, (h - cy) * cx / area
    w_rb = 1 - w_lt - w_rt - w_lb
    region = (_ssim(p[:cy, :cx], g[:cy, :cx]) * w_lt + _ssim(p[:cy, cx:], g[:cy, cx:]) * w_rt
              + _ssim(p[cy:, :cx], g[cy:, :cx]) * w_lb + _ssim(p[cy:, cx:], g[cy:, cx:]) * w_rb)
    return float(max(0.0, alpha * obj + (1 - alpha) * region))


def saliency_scores(pred: Any, gt: Any) -> dict[str, float]:
    """``{"f_measure", "mae", "s_measure"}`` of one prediction."""
    return {"f_measure": f_measure(pred, gt), "mae": mae(pred, gt), "s_measure": s_measure(pred, gt)}
