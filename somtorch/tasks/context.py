"""The object step's per-map context: what does not depend on the member (the valid-mask integral
image, the disparity spread, the map's own solidity, the ground residual and height, the regions an
area may be split into, the continuity flags of a support-verified map), built once per map
(:meth:`MapContext.build`) and shared by every member of an ensemble and every map of a run; and
:func:`object_mode`, how step 1c links and ranks on a map and why.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config import AreaConfig, ReductionConfig
from .ground import GroundPlane
from .objects import disparity_spread, pair_continuity, surround_pairs
from .reduction import valid_integral
from .refine import map_solidity, solidity_square

__all__ = ["MapContext", "object_mode"]


@dataclass
class MapContext:
    """What the object step needs of one map, the same for every member.

    Attributes:
        disparity: the map in px ``(H, W)``.
        valid: pixels with a disparity ``(H, W)``.
        usable: pixels that were segmented (valid, not ground) ``(H, W)``.
        integral: integral image of ``valid`` ``(H+1, W+1)``.
        spread: :func:`~somtorch.tasks.objects.disparity_spread` of the segmented pixels.
        solidity: :func:`~somtorch.tasks.refine.map_solidity` of the segmented pixels.
        ground_residual: |disparity − ground plane| ``(H, W)`` or None (no plane, or clutter off).
        clutter_band: ``ground_clutter ×`` the plane's inlier band, px (0 without a plane).
        surround: :func:`~somtorch.tasks.objects.surround_pairs` of the map, or None (contrast
            against the segments alone).
        islands: where the ground plane was verified by what it supports (``salient`` rule), the
            8-connected components of the segmented pixels ``(H, W)`` long (0 outside them);
            else None (no continuity link on this map).
        continuity: where ``islands`` is set, :func:`~somtorch.tasks.objects.pair_continuity` of
            the map (whether each 4-connected pixel pair is continuous in depth); else None.
        uncut: the ``salient`` rule's regions of the segmented pixels (:func:`_regions`: the cut
            ground and invalid gaps wider than the solidity square separate them) ``(H, W)`` long;
            None under ``paper``. An area spread over several is split (:func:`kept_areas`).
        n_islands: the number of labels of ``islands`` (0 where it is None).
        margins: the reduction's margins ``(px, share of the box side, share of the image diagonal)``
            on this map (:func:`~somtorch.tasks.reduction.reduce_map`): the keep budget counts each
            box as the reduced map will keep it. :meth:`build` takes them from a
            :class:`~somtorch.config.ReductionConfig`; a context made directly has none.
        ground_height: where ``islands`` is set (a verified support), disparity − the support plane
            ``(H, W)``: above it > 0, beneath it < 0 (:func:`standing_areas`); else None.
    """

    disparity: torch.Tensor
    valid: torch.Tensor
    usable: torch.Tensor
    integral: torch.Tensor
    spread: tuple[tuple[float, float], tuple[float, float]]
    solidity: float
    ground_residual: torch.Tensor | None
    clutter_band: float
    surround: tuple[torch.Tensor, torch.Tensor] | None = None
    islands: torch.Tensor | None = None
    continuity: torch.Tensor | None = None
    uncut: torch.Tensor | None = None
    n_islands: int = 0
    margins: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ground_height: torch.Tensor | None = None

    @classmethod
    def build(cls, disparity: torch.Tensor, valid: torch.Tensor, segmented: torch.Tensor,
              ground: GroundPlane | None, cfg: AreaConfig, reduction: ReductionConfig | None = None,
              stride: int = 1) -> MapContext:
        """The context of a map whose ``segmented`` ``(H, W)`` pixels carry a label (``labels >= 0``);
        ``reduction``: the margins of the boxes kept (None = the defaults), on a map read every
        ``stride``-th pixel (a margin in px shrinks with it; the shares do not)."""
        h, w = disparity.shape
        residual, band = None, 0.0
        height = None if ground is None else disparity - ground.disparity(h, w)
        if height is not None and cfg.ground_clutter > 0:
            residual = height.abs()
            band = cfg.ground_clutter * ground.tol
        lab = torch.where(segmented, 0, -1)
        islands = continuity = None
        if object_mode(ground, cfg)[0] == "support":
            islands, continuity = _islands(segmented), pair_continuity(disparity)
        else:
            height = None
        uncut = None if cfg.rule == "paper" else _regions(segmented, valid,
                                                          solidity_square(disparity.shape, cfg.solidity_size))
        r = reduction or ReductionConfig()
        return cls(disparity, valid, segmented, valid_integral(valid), disparity_spread(disparity, segmented),
                   map_solidity(lab, cfg), residual, band, surround_pairs(segmented, valid, disparity),
                   islands, continuity, uncut, 0 if islands is None else int(islands.max()) + 1,
                   (r.tolerance_px / stride, r.tolerance_frac, r.tolerance_image), height)


def object_mode(ground: GroundPlane | None, cfg: AreaConfig) -> tuple[str, str]:
    """How step 1c links and ranks on a map, and why: ``("support", why)`` where the support test
    verified the cut plane (segments link by similarity and by depth continuity; areas ranked by
    size × nearness), ``("contrast", why)`` elsewhere under the ``salient`` rule — the fallback:
    similarity links, ranked by contrast × size — and ``("paper", why)`` under the paper's rule.
    ``why`` is one sentence for ``metrics.json`` (:func:`somtorch.outputs.summarize`)."""
    if cfg.rule == "paper":
        return "paper", "objects.rule=paper: grid-adjacent similar neurons, the nearest area"
    if ground is None:
        return "contrast", ("no ground plane was cut (none passed the tests, ground.rule=none, or the plane "
                            "held every pixel)")
    rim = "" if ground.rim_frac is None else f", {ground.rim_frac:.0%} of the view's rim"
    held = f"it holds {ground.inlier_frac:.0%} of the valid pixels{rim}"
    if ground.support:
        return "support", f"the cut ground plane was verified as a support ({held})"
    return "contrast", f"the cut ground plane was verified by its position only, not as a support ({held})"


def _islands(segmented: torch.Tensor) -> torch.Tensor:
    """8-connected components of ``segmented`` ``(H, W)`` bool → labels ``(H, W)`` long (0 = not segmented)."""
    import cv2
    import numpy as np

    _, lab = cv2.connectedComponents(segmented.cpu().numpy().astype(np.uint8), connectivity=8)
    return torch.from_numpy(lab.astype(np.int64))


def _regions(segmented: torch.Tensor, valid: torch.Tensor, k: int) -> torch.Tensor:
    """The regions an area may be split into (:attr:`MapContext.uncut`): the 8-connected components
    of the segmented pixels, where an invalid gap joins what lies on both sides of it if a closing
    with a ``k × k`` square fills it (a sparse map's holes, an SGBM map's missing pixels inside a
    surface), and separates them where it is wider (as the cut ground does). ``(H, W)`` long, 0
    outside the regions."""
    import cv2
    import numpy as np

    closed = cv2.morphologyEx(segmented.cpu().numpy().astype(np.uint8), cv2.MORPH_CLOSE,
                              np.ones((k, k), np.uint8))
    return _islands(segmented | (~valid & torch.from_numpy(closed.astype(bool))))
