"""From the network's mask to obstacle boxes, the same :class:`~somtorch.tasks.baselines.Obstacle`
list the task-level baselines return (best first), so that :func:`~somtorch.tasks.reduction.reduce_map`
and the scorers treat the learned baseline exactly like the SOM's kept areas.

The probabilities are resized back to the map's size (bilinear); the pixels above
``cfg.threshold`` form 8-connected parts; a part smaller than ``cfg.min_area`` of the image, or
without a valid pixel, is dropped; each part's box spans its valid pixels. Parts are ranked by
their summed probability (the network's confidence times the area).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from somtorch.baselines.learned.data import prepare_input
from somtorch.baselines.learned.model import UNet
from somtorch.tasks.baselines import Obstacle

__all__ = ["learned_boxes", "mask_obstacles", "predict_proba"]


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


def mask_obstacles(prob: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor, *, threshold: float,
                   min_area: float) -> list[Obstacle]:
    """The parts of ``prob > threshold`` as obstacles, best (largest summed probability) first.

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
        scored.append((float(p[part].sum()), Obstacle(box, float(np.median(d[pv])), int(pv.sum()))))
    return [o for _, o in sorted(scored, key=lambda t: -t[0])]


def learned_boxes(disparity: torch.Tensor, valid: torch.Tensor, camera=None, *, model: UNet,
                  image: torch.Tensor | None = None) -> list[Obstacle]:
    """The learned baseline's obstacles on one map, best first (``camera`` is not used).

    Shape:
        ``disparity``, ``valid``: :math:`(H, W)`.
    """
    prob = predict_proba(model, disparity, valid, image)
    return mask_obstacles(prob, disparity, valid, threshold=model.cfg.threshold, min_area=model.cfg.min_area)
