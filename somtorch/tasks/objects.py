"""Paper step 1c: object-area recognition on a trained SOM.

Neurons that lie close on the SOM grid and have similar reference disparities form one object
area; a "disturbed" (dissimilar) neuron between two similar ones separates them, because areas
grow only through grid-adjacent, similar pairs (connected components of that graph).

Everything works on neuron-level statistics (``neuron_stats``: pixel count, mean disparity, box, the
image-space boundary between segments and with the ground), computed in one pass over the label
map, so recognition costs O(K²) whatever the image size.

Linking and selection follow ``AreaConfig.rule``:

* ``"paper"`` — the paper's rule: neurons adjacent on the SOM grid with similar reference
  disparities (similarity relative to the full disparity range) link; the area with the largest
  mean disparity is kept;
* ``"salient"`` — segments that share a boundary in the image link (similarity relative to the 5th–95th
  percentile spread); areas that stand out from their surroundings: contrast = mean disparity of the
  area − boundary-weighted mean disparity of what touches it in the image: the segments around it
  and, where the ground plane was cut out of the map, the ground pixels along its outline that lie
  *behind* the segment they touch (:func:`surround_pairs`). A support surface is background where
  it runs behind an object (a floor seen from above, the floor beyond a table's edge); where it
  lies at or in front of the object's disparity — the floor in front of an object's foot, beside
  it in a forward view — it says nothing about the object's salience and is left out. Without
  that, an object the ground cut isolates from every segment had no contrast at all. The areas in
  front of their surroundings (contrast ≥ 0) are ranked by contrast × ``area_frac ** size_power``,
  at most ``max_areas``; the contrast there is the geometric mean of the area's own and that of
  what ``merge`` keeps of it (its ``grown_contrast``, which
  :func:`~somtorch.tasks.detect.kept_areas` measures: :func:`rank_score`); on a map whose support
  plane was verified and cut (``on_support``: what
  is left stands on it) by size × nearness, ``area_frac ×`` mean disparity — the biggest nearest
  thing on the support, the ``plane_components`` baseline's choice (session 17, docs/validation_log.md).

What happens to the selected areas afterwards (joining adjacent segments, box refinement, growing,
the purity test) is in :mod:`somtorch.tasks.refine`; :func:`~somtorch.tasks.detect.kept_areas` runs
selection and those steps in order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import AreaConfig
from ..config.objects import CONTINUITY_STEP_FRAC, CONTINUITY_STEP_PX
from ..core.label_stats import native_label_stats
from ..validation import check_tensor



@dataclass
class NeuronStats:
    """Per-neuron statistics of one label map (K neurons).

    Attributes:
        count: pixels per segment ``(K,)``.
        mean_d: mean disparity of each segment (NaN if empty) ``(K,)``.
        box: per-segment (x0, y0, x1, y1) ``(K, 4)``; empty segments hold (W, H, −1, −1).
        boundary: image-space boundary length between segments ``(K, K)`` (4-connected pixel pairs).
        d_range: (min, max) disparity of the map.
        d_robust: (5th, 95th) percentile of the disparity of the map.
        ground_count: per segment, its 4-connected pixel pairs with the unsegmented valid pixels
            (the removed ground plane) whose disparity lies below the segment's mean (the ground
            behind it) ``(K,)``, or None.
        ground_sum: the disparity of those neighbours, summed per segment ``(K,)``, or None.
        continuous: of the pixel pairs in ``boundary``, those across which the disparity is
            continuous (:func:`continuous_pairs`) ``(K, K)``, or None (not asked for).
        perimeter: boundary length of each segment with other segments ``(K,)``.
    """

    count: torch.Tensor
    mean_d: torch.Tensor
    box: torch.Tensor
    boundary: torch.Tensor
    d_range: tuple[float, float]
    d_robust: tuple[float, float]
    ground_count: torch.Tensor | None = None
    ground_sum: torch.Tensor | None = None
    continuous: torch.Tensor | None = None

    @property
    def perimeter(self) -> torch.Tensor:
        """Boundary length of each segment with the other segments ``(K,)``."""
        return self.boundary.sum(1)

    def spread(self, kind: str) -> float:
        """The disparity spread of the map in px: full range (``kind="range"``) or 5th-95th percentile
        (``"robust"``), at least 1e-9."""
        lo, hi = self.d_range if kind == "range" else self.d_robust
        return max(hi - lo, 1e-9)


@dataclass
class ObjectArea:
    """One object area: a connected set of similar neurons and the pixels of their segments."""

    neurons: list[int]
    pixels: int
    box: tuple[int, int, int, int]
    mean_disparity: float
    contrast: float
    area_frac: float
    rank: int = -1
    segment_box: tuple[int, int, int, int] | None = None  # box of all its segments' pixels, before refinement
    merged_segments: int = 0  # segments joined by merge_adjacent
    ground_clutter_pieces: int = 0  # pieces left out of the box as ground clutter
    purity: float | None = None  # share of the box's valid pixels that are the area's own
    solidity: float | None = None  # share of its pixels an opening keeps (refine.solidity), in [0, 1]
    solidity_rel: float | None = None  # that share over the map's own (what objects.min_solidity tests)
    confidence: float | None = None  # rank score relative to the best candidate's (1 = best)
    grown_contrast: float | None = None  # contrast of the area as merge grows it (refine.with_grown_contrast)

    def mask(self, labels: torch.Tensor) -> torch.Tensor:
        """The area's pixels: the union of its neurons' segments. ``labels`` ``(H, W)`` → ``(H, W)`` bool."""
        return label_mask(labels, self.neurons)


def label_mask(labels: torch.Tensor, neurons: list[int] | torch.Tensor) -> torch.Tensor:
    """``labels ∈ neurons`` as a bool mask of ``labels``' shape (−1 = no segment is never in):
    a lookup table indexed by the labels, the same mask as ``torch.isin`` in about half the time."""
    idx = torch.as_tensor(neurons, dtype=torch.long, device=labels.device)
    top = int(idx.max()) if idx.numel() else 0
    lut = torch.zeros(top + 3, dtype=torch.bool, device=labels.device)  # [-1, 0 … top, above top]
    lut[idx + 1] = True
    return lut[(labels + 1).clamp_(max=top + 2)] if idx.numel() else torch.zeros_like(labels, dtype=torch.bool)


def disparity_spread(disparity: torch.Tensor, valid: torch.Tensor) -> tuple[tuple[float, float], tuple[float, float]]:
    """(min, max) and (5th, 95th percentile) of the disparity of the ``valid`` pixels (the latter on a
    ~20,000-pixel regular subsample): the ``d_range`` / ``d_robust`` of :class:`NeuronStats`.

    They depend on the segmented pixels only, not on the segments, so the members of an ensemble
    (which all segment the same pixels) can share one computation (``neuron_stats(spread=…)``).
    """
    d = torch.masked_select(disparity, valid)  # = disparity[valid] (same order), 2-3x faster
    step = max(1, d.numel() // 20_000)
    sample = d[::step].double()
    n = sample.numel()
    lo_q = float(sample.kthvalue(max(1, int(0.05 * n))).values)
    hi_q = float(sample.kthvalue(max(1, int(0.95 * n))).values)
    return (float(d.min()), float(d.max())), (lo_q, hi_q)


def neuron_stats(labels: torch.Tensor, disparity: torch.Tensor, num_neurons: int, *,
                 spread: tuple[tuple[float, float], tuple[float, float]] | None = None,
                 surround: tuple[torch.Tensor, torch.Tensor] | None = None,
                 continuity: torch.Tensor | None = None) -> NeuronStats:
    """Statistics of the segments of one label map.

    Every statistic comes from one pass over the map: the native kernel's
    (:func:`~somtorch.core.label_stats.native_label_stats`) or, where it is unavailable, bincounts on
    labels, on (row, label) and (column, label) keys, and on the (label, label) keys of the
    4-connected pixel pairs — the same numbers, bit for bit.

    Args:
        spread: :func:`disparity_spread` of ``disparity`` over ``labels >= 0`` if already known
            (computed here otherwise).
        surround: :func:`surround_pairs` of the map (the same for every member): the segments'
            boundary with the unsegmented valid pixels (the ground) is counted too.
        continuity: :func:`pair_continuity` of ``disparity`` (the same for every member): also
            count, per pair of segments, the boundary pixel pairs across which the disparity is
            continuous (:attr:`NeuronStats.continuous`; counted in the boundary's bincount).

    Shape:
        ``labels`` ``(H, W)`` long (−1 invalid), ``disparity`` ``(H, W)``.
    """
    check_tensor("labels", labels, ndim=2, dtype=torch.long)
    if disparity.shape != labels.shape:
        raise ValueError(f"disparity {tuple(disparity.shape)} and labels {tuple(labels.shape)} differ in shape")
    k = num_neurons
    h, w = labels.shape
    valid = labels >= 0
    if continuity is not None and tuple(continuity.shape) != (max(h * (w - 1), 0) + max((h - 1) * w, 0),):
        raise ValueError(f"continuity {tuple(continuity.shape)} is not pair_continuity() of an {h}×{w} map")

    def symmetric(counts: torch.Tensor) -> torch.Tensor:  # (K, K) pair counts → boundary lengths
        m = counts.double()
        m.fill_diagonal_(0.0)
        return m + m.T

    cont = None
    one = native_label_stats(labels, k, [disparity], pairs=True, continuity=continuity)
    if one is not None:  # the fused pass: the same numbers (tests/tasks/test_neuron_stats_native.py)
        count, dsum, box = one.count.double(), one.sums[0], one.box
        boundary = symmetric(one.pairs)
        if continuity is not None:
            cont = symmetric(one.continuous)
    else:
        count, dsum, box, boundary, cont = _segment_counts(labels, disparity, k, continuity)
    mean_d = dsum / count
    d_range, d_robust = spread if spread is not None else disparity_spread(disparity, valid)
    g_count = g_sum = None
    if surround is not None:
        idx, d_out = surround
        keys = labels.reshape(-1)[idx]
        behind = d_out < mean_d[keys]  # the support is background only where it lies behind the segment
        keys, d_out = keys[behind], d_out[behind]
        g_count = torch.bincount(keys, minlength=k).double()
        g_sum = torch.bincount(keys, weights=d_out, minlength=k).double()  # long when empty
    return NeuronStats(count, mean_d, box, boundary, d_range, d_robust, g_count, g_sum, cont)


def _segment_counts(labels: torch.Tensor, disparity: torch.Tensor, k: int, continuity: torch.Tensor | None
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """:func:`neuron_stats`' pass over the map in torch (where the native kernel is unavailable):
    bincounts on labels, on (row, label) and (column, label) keys, and on the (label, label) keys
    of the 4-connected pixel pairs. Returns counts, disparity sums, boxes, boundary lengths and
    continuous boundary lengths (None without ``continuity``)."""
    h, w = labels.shape
    # label k+1 (index K) collects the invalid pixels so that no boolean gather is needed
    lab = torch.where(labels >= 0, labels, k)
    count = torch.bincount(lab.view(-1), minlength=k + 1)[:k].double()
    dsum = torch.bincount(lab.view(-1), weights=disparity.reshape(-1).double(), minlength=k + 1)[:k]
    # per-row / per-column presence of each label gives the boxes without listing pixel coordinates
    rows = torch.bincount((lab + (k + 1) * torch.arange(h)[:, None]).view(-1), minlength=h * (k + 1))
    cols = torch.bincount((lab + (k + 1) * torch.arange(w)[None, :]).view(-1), minlength=w * (k + 1))
    rows = rows.view(h, k + 1)[:, :k] > 0  # (H, K)
    cols = cols.view(w, k + 1)[:, :k] > 0  # (W, K)
    box = torch.empty(k, 4, dtype=torch.long)
    ar_h, ar_w = torch.arange(h)[:, None], torch.arange(w)[:, None]
    box[:, 0] = torch.where(cols, ar_w, w).amin(0)
    box[:, 1] = torch.where(rows, ar_h, h).amin(0)
    box[:, 2] = torch.where(cols, ar_w, -1).amax(0)
    box[:, 3] = torch.where(rows, ar_h, -1).amax(0)
    pairs = [(a * (k + 1) + b).reshape(-1) for a, b in ((lab[:, :-1], lab[:, 1:]), (lab[:-1, :], lab[1:, :]))]
    flat = torch.cat(pairs)  # (P,) pair keys: every 4-connected pixel pair, horizontal then vertical

    def symmetric(counts: torch.Tensor) -> torch.Tensor:
        m = counts.view(k + 1, k + 1)[:k, :k].double()
        m.fill_diagonal_(0.0)
        return m + m.T

    if continuity is None:
        return count, dsum, box, symmetric(torch.bincount(flat, minlength=(k + 1) ** 2)), None
    # one bincount for both: key × 2 + (continuous across the pair)
    both = torch.bincount(flat * 2 + continuity, minlength=2 * (k + 1) ** 2).view(-1, 2)
    return count, dsum, box, symmetric(both.sum(1)), symmetric(both[:, 1].contiguous())


def pair_continuity(disparity: torch.Tensor) -> torch.Tensor:
    """Whether the disparity is continuous (:func:`continuous_pairs`) across each 4-connected pixel
    pair of a map, in :func:`neuron_stats`' pair order (horizontal pairs row by row, then vertical).
    It depends on the map alone, so every member of an ensemble shares it.

    Shape:
        ``disparity`` ``(H, W)`` → ``(H·(W−1) + (H−1)·W,)`` bool.
    """
    return torch.cat([continuous_pairs(disparity[:, :-1], disparity[:, 1:]).reshape(-1),
                      continuous_pairs(disparity[:-1, :], disparity[1:, :]).reshape(-1)])


def continuous_pairs(d_a: torch.Tensor, d_b: torch.Tensor) -> torch.Tensor:
    """Whether the disparity is continuous across each pixel pair: ``|d_a − d_b| ≤
    max(CONTINUITY_STEP_PX, CONTINUITY_STEP_FRAC · (d_a + d_b) / 2)`` (a surface running on, not an
    occluding edge; the step rule of the ``plane_components`` baseline).

    Shape:
        ``d_a``, ``d_b`` any (equal) shape → bool of that shape.
    """
    da, db = d_a.double(), d_b.double()
    return (da - db).abs() <= torch.clamp_min(0.5 * CONTINUITY_STEP_FRAC * (da + db), CONTINUITY_STEP_PX)


def surround_pairs(segmented: torch.Tensor, valid: torch.Tensor, disparity: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """The 4-connected pixel pairs of a segmented pixel and a valid pixel left out of the
    segmentation (the removed ground plane): the flat index of the segmented pixel and the
    disparity of the other, one row per pair. They depend on which pixels are segmented, not on
    the labels, so every member of an ensemble shares them (``neuron_stats(surround=…)``).

    Shape:
        ``segmented``, ``valid``, ``disparity`` ``(H, W)`` → ``(P,)`` long, ``(P,)`` float64.
    """
    h, w = segmented.shape
    out = valid & ~segmented
    flat = torch.arange(h * w).view(h, w)
    d = disparity.double()
    idx, dd = [], []
    for a, b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                 ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
        for s, o in ((a, b), (b, a)):  # the segmented side, the other side
            m = segmented[s] & out[o]
            idx.append(flat[s][m])
            dd.append(d[o][m])
    return torch.cat(idx), torch.cat(dd)


def _components(adj: torch.Tensor) -> list[list[int]]:
    k = adj.shape[0]
    nbrs = [adj[i].nonzero().flatten().tolist() for i in range(k)]
    seen, comps = [False] * k, []
    for s in range(k):
        if seen[s]:
            continue
        stack, comp = [s], []
        seen[s] = True
        while stack:
            i = stack.pop()
            comp.append(i)
            for j in nbrs[i]:
                if not seen[j]:
                    seen[j] = True
                    stack.append(j)
        comps.append(sorted(comp))
    return comps


def find_object_areas(ref_disparity: torch.Tensor, grid_d2: torch.Tensor | None, stats: NeuronStats,
                      cfg: AreaConfig | None = None, *, continuous: float = 0.0,
                      linkable: torch.Tensor | None = None) -> list[ObjectArea]:
    """All object areas of one SOM (connected components of similar, grid-adjacent neurons).

    Args:
        ref_disparity: reference disparity of each neuron in px ``(K,)``.
        grid_d2: squared grid distances ``(K, K)`` of the SOM (adjacent = 1, diagonal = 2), or None
            for segmenters without a grid (k-means, superpixels): their segments link through the
            image, whatever ``cfg.rule`` says.
        stats: :func:`neuron_stats` of the member's label map.
        cfg: recognition parameters.
        continuous: touching segments (``salient`` rule) also link where at least this share of
            their boundary's pixel pairs is continuous (:attr:`NeuronStats.continuous`; 0 = no
            continuity link; the caller decides where it applies: on support-verified maps,
            ``CONTINUOUS_SHARE``).
        linkable: ``(K,)`` bool, the segments that may link by continuity (None = all).

    Returns:
        areas with at least one pixel, in no particular order (see :func:`select_areas`).
    """
    cfg = cfg or AreaConfig()
    ref = ref_disparity.double().cpu()
    paper = cfg.rule == "paper"
    tau = cfg.similarity * stats.spread("range" if paper else "robust")
    if paper and grid_d2 is not None:
        near = grid_d2.cpu() <= 1.0 + 1e-6  # adjacent on the grid: one step along a row or a column
    else:
        near = _touching(stats, cfg.min_boundary)
    adj = near & ((ref[:, None] - ref[None, :]).abs() < tau)
    if continuous > 0 and not paper:
        if stats.continuous is None:
            raise ValueError("find_object_areas(continuous > 0) needs "
                             "neuron_stats(..., continuity=pair_continuity(d))")
        cont = near & (stats.boundary > 0) & (stats.continuous >= continuous * stats.boundary)
        if linkable is not None:
            cont &= linkable[:, None] & linkable[None, :]
        adj |= cont
    adj.fill_diagonal_(False)
    return areas_of(_components(adj), stats)


def _touching(stats: NeuronStats, min_boundary: float) -> torch.Tensor:
    """``(K, K)`` bool: the common boundary is at least ``min_boundary`` of the shorter perimeter."""
    per = stats.perimeter.clamp_min(1.0)
    return stats.boundary >= min_boundary * torch.minimum(per[:, None], per[None, :])


def areas_of(comps: list[list[int]], stats: NeuronStats) -> list[ObjectArea]:
    """The object areas of the neuron groups ``comps`` (lists of neuron indices), with their pixel
    count, box, mean disparity, contrast and share of the segmented pixels; empty groups are left out."""
    # per-component sums as (C, K) one-hot products: one pass instead of a loop of small tensor ops
    onehot = torch.zeros(len(comps), int(stats.count.shape[0]), dtype=torch.float64)
    rows = [i for i, comp in enumerate(comps) for _ in comp]
    onehot[rows, [j for comp in comps for j in comp]] = 1.0
    cnt = stats.count.double()
    md = torch.nan_to_num(stats.mean_d.double())
    n_px = onehot @ cnt
    mean = (onehot @ (md * cnt)) / n_px.clamp_min(1.0)
    border = (onehot @ stats.boundary) * (1.0 - onehot)  # (C, K) boundary with the segments outside
    b_len = border.sum(1)
    b_sum = border @ md
    if stats.ground_count is not None:  # the removed ground around it is a neighbour too
        b_len = b_len + onehot @ stats.ground_count
        b_sum = b_sum + onehot @ stats.ground_sum
    contrast = torch.where(b_len > 0, mean - b_sum / b_len.clamp_min(1e-300), torch.zeros_like(mean))
    member = (onehot > 0) & (stats.count > 0)[None, :]  # (C, K): its non-empty segments
    big = torch.iinfo(torch.long).max
    x0 = torch.where(member, stats.box[None, :, 0], big).amin(1)
    y0 = torch.where(member, stats.box[None, :, 1], big).amin(1)
    x1 = torch.where(member, stats.box[None, :, 2], -1).amax(1)
    y1 = torch.where(member, stats.box[None, :, 3], -1).amax(1)
    total = float(stats.count.sum())
    # as Python numbers once, not one tensor element at a time
    n_l, mean_l, con_l = n_px.tolist(), mean.tolist(), contrast.tolist()
    boxes = torch.stack([x0, y0, x1, y1], 1).tolist()
    areas = []
    for i, comp in enumerate(comps):
        n = n_l[i]
        if n == 0:
            continue
        areas.append(ObjectArea(comp, int(n), tuple(boxes[i]), mean_l[i], con_l[i], n / total))
    return areas


def select_areas(areas: list[ObjectArea], stats: NeuronStats, cfg: AreaConfig | None = None, *,
                 on_support: bool = False) -> list[ObjectArea]:
    """The kept areas, best first, with ``rank`` set (see the module docstring; ``on_support``: the
    map's support plane was verified and cut, :func:`rank_score`)."""
    cfg = cfg or AreaConfig()
    if cfg.rule == "paper":
        ranked = sorted(areas, key=lambda a: -a.mean_disparity)[:1]
    else:
        ranked = salient_order(areas, cfg, on_support=on_support)[:cfg.max_areas]
    for i, a in enumerate(ranked):
        a.rank = i
    return ranked


def salient_order(areas: list[ObjectArea], cfg: AreaConfig, *, on_support: bool = False) -> list[ObjectArea]:
    """The ``salient`` rule's candidates, best first: the areas in front of their surroundings
    (contrast ≥ 0; one behind them is not salient) by :func:`rank_score`, all of them (``rank``
    untouched)."""
    return sorted((a for a in areas if a.contrast >= 0),
                  key=lambda a: -rank_score(a, cfg, on_support=on_support))


def rank_score(area: ObjectArea, cfg: AreaConfig, *, on_support: bool = False) -> float:
    """The salient ranking's score: ``contrast × area_frac ** size_power``; where the area carries its
    ``grown_contrast`` (:func:`~somtorch.tasks.refine.with_grown_contrast`), the geometric mean
    ``√(contrast × max(grown_contrast, 0))`` takes the contrast's place: the area stands out, and so
    does what ``merge`` keeps of it. On a map whose support plane was verified and cut
    (``on_support``), ``area_frac ×`` mean disparity (size × nearness)."""
    if on_support:
        return area.area_frac * area.mean_disparity
    salience = area.contrast
    if area.grown_contrast is not None:
        salience = math.sqrt(max(area.contrast, 0.0) * max(area.grown_contrast, 0.0))
    return salience * area.area_frac ** cfg.size_power
