"""Scoring a reduction against a ground-truth object mask (the paper's Tables 1 and 2).

* identified fraction: share of the object's pixels *with a valid disparity* that lie inside the
  kept area (pixels without disparity are not in the data set, so no method can be scored on them);
* identified_100 / identified_95: fraction ≥ 1.0 / ≥ 0.95;
* x_opt: the reduction obtained by keeping exactly the object's bounding box;
* useful hit: ≥ 95 % identified AND reduction ≥ 0.75 · x_opt (a hit that also reduces the data).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

from ..validation import check_tensor
from .reduction import Reduction, extent, reduce_map

#: The paper's useful hit: at least this share of the object identified …
IDENTIFIED = 0.95
#: … at a reduction of at least this factor × x_opt.
USEFUL_FACTOR = 0.75


@dataclass
class Score:
    """One reduction scored against an object mask (see the module docstring for the terms).

    Attributes:
        identified_fraction: share of the object's valid pixels inside the kept area.
        identified_100: all of them inside.
        identified_95: at least 95 % inside.
        reduction_union: reduction (%) keeping the union of the kept boxes.
        reduction_crops: reduction (%) keeping every kept box as a separate crop (can be negative).
        x_opt: reduction (%) of keeping exactly the object's bounding box.
        useful_hit: identified_95 and reduction_union ≥ 0.75 · x_opt.
    """

    identified_fraction: float
    identified_100: bool
    identified_95: bool
    reduction_union: float
    reduction_crops: float
    x_opt: float
    useful_hit: bool

    def as_dict(self) -> dict:
        """The score as a plain dict."""
        return asdict(self)


def object_box(mask: torch.Tensor) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, x1, y1), inclusive, of a non-empty bool mask ``(H, W)``."""
    ys, xs = mask.nonzero(as_tuple=True)
    if ys.numel() == 0:
        raise ValueError("the object mask is empty: no bounding box")
    return int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())


def optimal_reduction(object_mask: torch.Tensor, valid: torch.Tensor, integral: torch.Tensor | None = None) -> float:
    """x_opt: the reduction in % when exactly the object's bounding box is kept (``integral``: the
    valid mask's integral image if the caller has it)."""
    return reduce_map([object_box(object_mask)], valid, tolerance_px=0.0, tolerance_frac=0.0,
                      tolerance_image=0.0, integral=integral).reduction_union


def score_reduction(reduction: Reduction, object_mask: torch.Tensor, valid: torch.Tensor,
                    *, useful_factor: float = USEFUL_FACTOR, x_opt: float | None = None) -> Score:
    """Score one reduced map against an object mask ``(H, W)`` bool.

    ``x_opt``: :func:`optimal_reduction` of the same mask and valid pixels if already known (it does
    not depend on the reduction, so the members of an ensemble share one).
    """
    check_tensor("object_mask", object_mask, ndim=2, dtype=torch.bool)
    if object_mask.shape != valid.shape or reduction.mask.shape != valid.shape:
        raise ValueError(f"object_mask {tuple(object_mask.shape)}, valid {tuple(valid.shape)} and the "
                         f"reduction mask {tuple(reduction.mask.shape)} must have the same shape")
    obj = object_mask & valid
    n_obj = int(obj.sum())
    if n_obj == 0:
        raise ValueError("the object has no pixel with a valid disparity: it cannot be scored")
    if reduction.boxes:  # the kept pixels lie inside the boxes: count there only
        x0, y0, x1, y1 = extent(reduction.boxes)
        inside = int((obj[y0:y1 + 1, x0:x1 + 1] & reduction.mask[y0:y1 + 1, x0:x1 + 1]).sum())
    else:
        inside = int((obj & reduction.mask).sum())
    frac = inside / n_obj
    if x_opt is None:
        x_opt = optimal_reduction(object_mask, valid)
    red = reduction.reduction_union
    return Score(frac, frac >= 1.0, frac >= IDENTIFIED, red, reduction.reduction_crops, x_opt,
                 frac >= IDENTIFIED and red >= useful_factor * x_opt)
