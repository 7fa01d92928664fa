"""From the network's mask to boxes: its connected parts, best first (the task-level adapter,
:mod:`somtorch.tasks.baselines.learned`, turns them into the :class:`~somtorch.tasks.baselines.Obstacle`
list every task baseline returns).

The probabilities are resized back to the map's size (bilinear); the pixels above
``cfg.threshold`` form 8-connected parts; a part smaller than ``cfg.min_area`` of the image, or
without a valid pixel, is dropped; each part's box spans its valid pixels. Parts are ranked by
their summed probability (the network's confidence times the area).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from somtorch.baselines.learned.data import prepare_input
from somtorch.baselines.learned.model import UNet

__all__ = ["Part", "mask_parts", "predict_parts", "predict_proba"]


@dataclass(frozen=True)
class Part:
    """One connected part of the predicted mask: its box ``(x0, y0, x1, y1)`` inclusive over its
    valid pixels, their median disparity (px) and count, and its summed probability (the rank)."""

    box: tuple[int, int, int, int]
    disparity: float
    pixels: int
    score: float


@torch.no_grad()
def predict_proba(model: UNet, disparity: torch.Tensor, valid: torch.Tensor,
                  image: torch.Tensor | None = None) -> torch.Tensor:
    """The main object's probability at every pixel of the map.

    Shape:
        - disparity, valid: :math:`(H, W)`; image: :math:`(3, H, W)` uint8 (with ``model.cfg.image``).
        - output: :math:`(H, W)` float32 in [0, 1].
    """
    x = prepare_input(disparity, valid, model.cfg, image)[None]  # (1, C, h, w)
    was = model.training
    model.eval()
    logits = model(x)  # (1, 1, h, w)
    model.train(was)
    up = F.interpolate(logits, size=tuple(disparity.shape), mode="bilinear", align_corners=False)
    return torch.sigmoid(up)[0, 0]


def mask_parts(prob: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor, *, threshold: float,
               min_area: float) -> list[Part]:
    """The parts of ``prob > threshold``, best (largest summed probability) first.

    Shape:
        ``prob``, ``disparity``, ``valid``: :math:`(H, W)`.
    """
    p = prob.detach().cpu().numpy()
    v = valid.detach().cpu().numpy()
    d = disparity.detach().cpu().numpy()
    n, lab, stats, _ = cv2.connectedComponentsWithStats((p > threshold).astype(np.uint8), connectivity=8)
    min_px = max(1, int(np.ceil(min_area * p.size)))
    scored = []
    for k in range(1, n):
        if stats[k, cv2.CC_STAT_AREA] < min_px:
            continue
        part = lab == k
        pv = part & v
        if not pv.any():
            continue
        ys, xs = np.nonzero(pv)
        box = (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))
        scored.append(Part(box, float(np.median(d[pv])), int(pv.sum()), float(p[part].sum())))
    return sorted(scored, key=lambda t: -t.score)


def predict_parts(model: UNet, disparity: torch.Tensor, valid: torch.Tensor,
                  image: torch.Tensor | None = None) -> list[Part]:
    """The parts of the network's mask on one map, at the map's size, best first.

    Shape:
        ``disparity``, ``valid``: :math:`(H, W)`.
    """
    prob = predict_proba(model, disparity, valid, image)
    return mask_parts(prob, disparity, valid, threshold=model.cfg.threshold, min_area=model.cfg.min_area)
