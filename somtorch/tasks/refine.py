"""Paper step 1c, second half: from the selected object areas to the kept boxes.

After :func:`~somtorch.tasks.objects.select_areas` ranks the candidate areas, each candidate is

1. joined with the image-adjacent segments of similar disparity (:func:`merge_adjacent`: an object
   split over several areas at different depths is kept whole),
2. given a refined box (:func:`refine_box`: ground-plane clutter, stray fragments and thin
   protrusions left out),
3. kept only if its box is mostly its own pixels (:func:`box_purity`, ``min_purity``), else the next
   candidate is tried.

:func:`kept_areas` runs these steps in order; the parameters live in
:class:`~somtorch.tasks.objects.AreaConfig`.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from ..config import AreaConfig
from .objects import NeuronStats, ObjectArea, areas_of, label_mask
from .reduction import box_count

_D = AreaConfig  # the defaults of the helpers below are those of the config


def _grown(areas: list[ObjectArea], stats: NeuronStats, ratio: float, min_boundary: float,
           group: torch.Tensor, blocked: torch.Tensor | None = None) -> torch.Tensor:
    """``merge``'s growth of each area from its segments ``group`` ``(A, K)`` bool, ring by ring until
    nothing joins (see :func:`merge_adjacent`): a segment joins where its mean disparity is within
    ``ratio ×`` the area's contrast of the area's and its boundary with the group is at least
    ``min_boundary`` of its perimeter; none of ``blocked`` ``(K,)`` joins. The areas grow
    independently. Returns the grown ``(A, K)``."""
    mean_d = torch.nan_to_num(stats.mean_d, nan=float("inf"))  # empty segments never join
    own = torch.tensor([a.mean_disparity for a in areas], dtype=mean_d.dtype)
    tol = ratio * torch.tensor([max(a.contrast, 0.0) for a in areas], dtype=mean_d.dtype)
    may = (mean_d[None, :] - own[:, None]).abs() <= tol[:, None]
    if blocked is not None:
        may &= ~blocked[None, :]
    floor = min_boundary * stats.perimeter
    boundary = stats.boundary.double()
    group = group.clone()
    while True:
        # (A, K): each segment's boundary with each growing group; pixel-pair counts in float64 are
        # whole numbers, exact in any order of summation: the same bits from any BLAS kernel
        shared = group.double() @ boundary
        ring = ~group & may & (shared > 0) & (shared >= floor[None, :])
        if not bool(ring.any()):
            return group
        group |= ring


def merge_adjacent(kept: list[ObjectArea], stats: NeuronStats, *, ratio: float = _D.merge,
                   min_boundary: float = _D.min_boundary,
                   exclude: torch.Tensor | None = None) -> list[ObjectArea]:
    """Join to each kept area the segments that are other parts of the same object (``AreaConfig.merge``).

    A segment (one neuron's pixels) joins if it touches the growing group in the image (their common
    boundary is at least ``min_boundary`` of the segment's boundary with other segments) and its
    mean disparity differs from the kept area's by at most ``ratio ×`` the kept area's contrast:
    a motorcycle's front wheel, the far side of a toy, the top of a slanted box, which the
    similarity rule put into other areas (often together with background). Joining repeats, one
    ring of segments at a time, until nothing joins. A segment joins at most one group; a kept
    area that a better-ranked one absorbed is dropped.

    ``exclude`` ``(K,)`` bool marks segments that may not join (those of areas kept already).

    Returns:
        the kept areas in rank order; a grown area lists all its neurons, the union of the segment
        boxes, the pixel-weighted mean disparity, the selected area's contrast and
        ``extra["merged_segments"]``.
    """
    if ratio <= 0 or not kept:
        return kept
    k = int(stats.count.shape[0])
    total = float(stats.count.sum())
    taken = torch.zeros(k, dtype=torch.bool) if exclude is None else exclude.clone()
    out = []
    for a in kept:
        group = torch.zeros(k, dtype=torch.bool)
        group[torch.tensor(a.neurons)] = True
        if bool((group & taken).any()):
            continue
        group = _grown([a], stats, ratio, min_boundary, group[None], blocked=taken)[0]
        taken |= group
        added = int(group.sum()) - len(a.neurons)
        if added == 0:
            out.append(a)
            continue
        idx = group.nonzero().flatten()
        cnt = stats.count[idx]
        b = stats.box[idx][cnt > 0]
        box = (int(b[:, 0].min()), int(b[:, 1].min()), int(b[:, 2].max()), int(b[:, 3].max()))
        n = float(cnt.sum())
        mean = float((torch.nan_to_num(stats.mean_d[idx]) * cnt).sum() / n)
        out.append(replace(a, neurons=idx.tolist(), pixels=int(n), box=box, mean_disparity=mean,
                           area_frac=n / total, merged_segments=added))
    for i, a in enumerate(out):
        a.rank = i
    return out


def with_grown_contrast(areas: list[ObjectArea], stats: NeuronStats, cfg: AreaConfig) -> list[ObjectArea]:
    """``areas`` with their ``grown_contrast``: the contrast (:func:`~somtorch.tasks.objects.areas_of`)
    of each area as :func:`merge_adjacent` grows it alone (``cfg.merge``, ``cfg.min_boundary``), what
    the refinement would keep of it. The salient ranking reads it beside the area's own contrast
    (:func:`~somtorch.tasks.objects.rank_score`): an area beside an object, a table's front strip, whose
    growth swallows the object and the surface around it, stands out less once grown than the object's
    own area does (session 31, ``docs/validation_log.md``). ``areas`` as they are where ``cfg.merge`` is 0."""
    if cfg.merge <= 0 or not areas:
        return areas
    group = torch.zeros(len(areas), int(stats.count.shape[0]), dtype=torch.bool)
    for i, a in enumerate(areas):
        group[i, a.neurons] = True
    group = _grown(areas, stats, cfg.merge, cfg.min_boundary, group)  # each alone, all at once
    grown = areas_of([row.nonzero().flatten().tolist() for row in group], stats)
    return [replace(a, grown_contrast=g.contrast) for a, g in zip(areas, grown, strict=True)]


def refine_box(area: ObjectArea, labels: torch.Tensor, *, coverage: float = _D.box_coverage,
               quantile: float = _D.box_quantile, ground_residual: torch.Tensor | None = None,
               clutter_band: float = 0.0,
               drop_specks: bool = True, mask: torch.Tensor | None = None) -> ObjectArea:
    """The box of the object inside a kept area, without the parts of its segments that are not it.

    The area's pixels are split into image-connected pieces (8-connectivity; the pipeline passes the
    object step's map, already sampled every ``map_stride``-th pixel), then

    0. with ``drop_specks``, pieces without a solid 3 × 3 block of samples are dropped: specks and
       sparse bands of speckles at the object's disparity (SGBM leaves them along the image border)
       no longer stretch the box, whatever their share of the area's pixels, while a thin part
       attached to a solid one (a chair's slats, a wheel's spokes) stays with its piece;
    1. pieces lying on the ground plane are dropped: more than half of their pixels within
       ``clutter_band`` px of the plane (``ground_residual`` = |disparity − plane disparity|). A computed
       (SGBM) floor has streaks off the RANSAC inlier band that share the object's disparity; they
       are image-disconnected from the object and flat on the ground, the object is neither;
    2. the largest remaining pieces holding ``coverage`` of their pixels are kept (stray fragments of
       the segments far from the object do not stretch the box; 1.0 keeps all);
    3. the box spans the ``quantile`` … ``1 − quantile`` range of the kept pixels' x and y, so a
       1–2 px wide protrusion (an antenna, a cable, an SGBM streak) does not move an edge
       (0 = the full extent).

    Every step keeps the area unchanged if it would drop all pixels. ``mask``: the area's pixels,
    ``label_mask(labels, area.neurons)``, if the caller has it.

    Shape:
        ``labels`` ``(H, W)`` long; ``ground_residual``, ``mask`` ``(H, W)`` or None.
    """
    import cv2
    import numpy as np

    if coverage >= 1.0 and quantile <= 0.0 and not drop_specks and (ground_residual is None or clutter_band <= 0):
        return area
    mask = (label_mask(labels, area.neurons) if mask is None else mask).cpu().numpy()
    n, comp, st, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return area
    sizes = st[1:, cv2.CC_STAT_AREA].astype(np.float64)
    pieces = np.arange(1, n)
    dropped = 0
    if ground_residual is not None and clutter_band > 0:
        res = ground_residual.cpu().numpy()
        on_ground = np.bincount(comp[mask], weights=(res[mask] < clutter_band), minlength=n)[1:] / sizes
        flat = on_ground > 0.5
        if not flat.all():
            dropped = int(flat.sum())
            pieces, sizes = pieces[~flat], sizes[~flat]
    if drop_specks:  # pieces without a solid 3x3 block of samples are specks, unless nothing else is left
        opened = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8),
                                  borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)  # outside = empty
        solid = np.bincount(comp[opened], minlength=n)[pieces] > 0
        if solid.any():
            pieces, sizes = pieces[solid], sizes[solid]
    order = np.argsort(-sizes, kind="stable")
    need = min(coverage, 1.0) * sizes.sum()
    pieces = pieces[order[: int(np.searchsorted(np.cumsum(sizes[order]), need - 1e-9)) + 1]]
    take = np.zeros(n, dtype=bool)
    take[pieces] = True
    sel = take[comp]
    q = min(max(quantile, 0.0), 0.5)
    x0, x1 = _quantile_edges(sel.sum(0), q)
    y0, y1 = _quantile_edges(sel.sum(1), q)
    box = (x0, y0, x1, y1)
    return replace(area, box=box, segment_box=area.box, ground_clutter_pieces=dropped)


def _quantile_edges(counts, q: float) -> tuple[int, int]:
    """The ``q`` and ``1 − q`` quantiles of coordinates counted ``counts[i]`` times each (a mask's
    column or row sums): ``numpy.quantile(coords, [q, 1 - q], method="inverted_cdf")`` of the
    coordinates listed pixel by pixel, the same order statistics by numpy's index arithmetic, read
    off the cumulative counts instead of partitioning every pixel's coordinate (``q`` 0: the first
    and the last counted coordinate)."""
    import numpy as np

    cum = np.cumsum(counts)
    n = int(cum[-1])

    def rank(p: float) -> int:  # numpy's inverted_cdf: index n·p − 1, rounded up where fractional
        index = n * p - 1
        k = math.floor(index)
        return max(k if index - k == 0 else k + 1, 0)

    lo, hi = (rank(q), rank(1 - q)) if q > 0 else (0, n - 1)
    # the (k+1)-th smallest coordinate: the first whose cumulative count exceeds k
    return int(np.searchsorted(cum, lo, side="right")), int(np.searchsorted(cum, hi, side="right"))


def box_purity(area: ObjectArea, labels: torch.Tensor, valid_integral: torch.Tensor,
               mask: torch.Tensor | None = None, *, origin: tuple[int, int] = (0, 0)) -> float:
    """Share of the valid pixels inside ``area.box`` that belong to the area's segments (``mask``:
    ``label_mask(labels, area.neurons)``, if the caller has it, or that mask on a window of the map
    whose top-left pixel is ``origin`` (x, y) and which holds ``area.box``).

    Shape:
        ``labels`` ``(H, W)``; ``mask`` ``(H, W)`` or the window's shape; ``valid_integral``
        ``(H+1, W+1)``: the integral image of the valid mask.
    """
    x0, y0, x1, y1 = area.box
    n_valid = box_count(valid_integral, area.box)
    if mask is None:
        own = int(label_mask(labels[y0:y1 + 1, x0:x1 + 1], area.neurons).sum())
    else:
        ox, oy = origin
        own = int(mask[y0 - oy:y1 - oy + 1, x0 - ox:x1 - ox + 1].sum())
    return own / max(n_valid, 1)


def solidity(mask: torch.Tensor, *, size: float = _D.solidity_size, stride: int = 1) -> float:
    """Share of the pixels of ``mask`` that survive a morphological opening with a square of side
    ``size ×`` the shorter image side (on every ``stride``-th pixel; the nearest odd number of
    samples, at least 3): about 1 for a solid region, near 0 for scattered speckles and 1–2 px
    thin streaks (SGBM mismatches on textureless walls and ceilings), which no such square fits in.

    Shape:
        ``mask`` ``(H, W)`` bool.
    """
    s = max(1, int(stride))
    return _opened_share(mask[::s, ::s], solidity_square(mask.shape, size, s))


def solidity_square(shape: tuple[int, ...], size: float, stride: int = 1) -> int:
    """The side in px of the solidity square (``AreaConfig.solidity_size`` = ``size`` × the shorter
    side of a map of ``shape`` (H, W), on a grid of every ``stride``-th pixel): odd, so that it is
    centred and symmetric, and at least 3."""
    return max(3, 2 * round(size * min(shape) / stride / 2) + 1)


def _opened_share(sampled: torch.Tensor, k: int) -> float:
    import cv2
    import numpy as np

    m = sampled.cpu().numpy().astype(np.uint8)
    n = int(m.sum())
    if n == 0:
        return 0.0
    opened = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
    return float((opened & m).sum()) / n


def map_solidity(labels: torch.Tensor, cfg: AreaConfig) -> float:
    """:func:`solidity` of all the segmented pixels (``labels >= 0``), the reference of
    ``cfg.min_solidity``; the same for every member of an ensemble (they segment the same pixels)."""
    return max(solidity(labels >= 0, size=cfg.solidity_size), 1e-9)
