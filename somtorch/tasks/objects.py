"""Paper step 1c: object-area recognition on a trained SOM.

Neurons that lie close on the SOM grid and have similar reference disparities form one object
area; a "disturbed" (dissimilar) neuron between two similar ones separates them, because areas
grow only through grid-adjacent, similar pairs (connected components of that graph).

Everything works on neuron-level statistics (``neuron_stats``: pixel count, mean disparity, box and
the image-space boundary between segments), computed in one pass over the label map, so recognition
costs O(K²) whatever the image size.

Selection of the kept areas:

* ``"nearest"`` — the paper's rule: the area with the largest mean disparity;
* ``"salient"`` — areas that stand out from their surroundings: contrast = mean disparity of the
  area − boundary-weighted mean disparity of the segments touching it in the image; areas larger
  than ``max_area_frac`` of the valid pixels or smaller than ``min_area_frac`` are rejected, the rest
  ranked by contrast, those above ``min_contrast`` (a fraction of the disparity range) kept, at most
  ``max_areas``;
* ``"all"`` — every area passing the size limits.

With ``hierarchy`` the candidates are also the nodes of the areas' merge tree (:func:`merge_tree`):
an object in parts at somewhat different depths is then one candidate beside its parts.

What happens to the selected areas afterwards (joining adjacent segments, box refinement, growing,
the purity test) is in :mod:`somtorch.tasks.refine`; :func:`~somtorch.tasks.refine.kept_areas` runs
selection and those steps in order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..config import AreaConfig
from ..config.options import LINKS, SELECTIONS, SPREADS
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
        perimeter: boundary length of each segment with other segments ``(K,)``.
        edge_boundary: the part of ``boundary`` that lies on image edges ``(K, K)`` (pixel pairs
            with an edge pixel at either end), or None without an edge map.
        moments: per-segment sums of u, v, u², uv, v², u·d, v·d ``(K, 7)`` with u, v the pixel
            coordinates from the image centre in image widths (the plane fit of ``facing``), or None.
    """

    count: torch.Tensor
    mean_d: torch.Tensor
    box: torch.Tensor
    boundary: torch.Tensor
    d_range: tuple[float, float]
    d_robust: tuple[float, float]
    edge_boundary: torch.Tensor | None = None
    moments: torch.Tensor | None = None

    @property
    def perimeter(self) -> torch.Tensor:
        return self.boundary.sum(1)

    def spread(self, kind: str) -> float:
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
    salience: float | None = None  # contrast plus the colour term (px); None = the contrast alone
    segment_box: tuple[int, int, int, int] | None = None  # box of all its segments' pixels, before refinement
    merged_segments: int = 0  # segments joined by merge_adjacent
    ground_clutter_pieces: int = 0  # pieces left out of the box as ground clutter
    grow_threshold: float | None = None  # disparity threshold of grow_area
    purity: float | None = None  # share of the box's valid pixels that are the area's own
    solidity: float | None = None  # share of its pixels an opening keeps (refine.solidity), in [0, 1]
    solidity_rel: float | None = None  # that share over the map's own (what objects.min_solidity tests)
    confidence: float | None = None  # rank score relative to the best candidate's (1 = best)
    facing: float | None = None  # cos of its disparity plane's tilt from the line of sight

    @property
    def ranking(self) -> float:
        """What the salient selection ranks by (before the size term): the salience, or the contrast."""
        return self.contrast if self.salience is None else self.salience

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
                 edges: torch.Tensor | None = None, moments: bool = False) -> NeuronStats:
    """Statistics of the segments of one label map.

    Args:
        spread: :func:`disparity_spread` of ``disparity`` over ``labels >= 0`` if already known
            (computed here otherwise).
        edges: ``(H, W)`` bool, pixels on (or near) an image edge; gives ``edge_boundary``.
        moments: also compute ``moments`` (the segments' coordinate and disparity moments).

    Shape:
        ``labels`` ``(H, W)`` long (−1 invalid), ``disparity`` ``(H, W)``.
    """
    check_tensor("labels", labels, ndim=2, dtype=torch.long)
    if disparity.shape != labels.shape:
        raise ValueError(f"disparity {tuple(disparity.shape)} and labels {tuple(labels.shape)} differ in shape")
    k = num_neurons
    h, w = labels.shape
    valid = labels >= 0
    # label k+1 (index K) collects the invalid pixels so that no boolean gather is needed
    lab = torch.where(valid, labels, k)
    count = torch.bincount(lab.view(-1), minlength=k + 1)[:k].double()
    dsum = torch.bincount(lab.view(-1), weights=disparity.reshape(-1).double(), minlength=k + 1)[:k]
    mean_d = dsum / count
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
    pairs = []
    for a, b in ((lab[:, :-1], lab[:, 1:]), (lab[:-1, :], lab[1:, :])):
        pairs.append((a * (k + 1) + b).reshape(-1))
    flat = torch.cat(pairs)

    def symmetric(counts: torch.Tensor) -> torch.Tensor:
        m = counts.view(k + 1, k + 1)[:k, :k].double()
        m.fill_diagonal_(0.0)
        return m + m.T

    boundary = symmetric(torch.bincount(flat, minlength=(k + 1) ** 2))
    edge_boundary = None
    if edges is not None:
        on = torch.cat([(edges[:, :-1] | edges[:, 1:]).reshape(-1), (edges[:-1, :] | edges[1:, :]).reshape(-1)])
        edge_boundary = symmetric(torch.bincount(flat, weights=on.double(), minlength=(k + 1) ** 2))
    mom = None
    if moments:
        u = ((torch.arange(w, dtype=torch.float64) - 0.5 * (w - 1)) / w).expand(h, w)
        v = ((torch.arange(h, dtype=torch.float64)[:, None] - 0.5 * (h - 1)) / w).expand(h, w)
        d = disparity.double()
        flat_lab = lab.view(-1)
        mom = torch.stack([torch.bincount(flat_lab, weights=q.reshape(-1), minlength=k + 1)[:k]
                           for q in (u, v, u * u, u * v, v * v, u * d, v * d)], 1)
    d_range, d_robust = spread if spread is not None else disparity_spread(disparity, valid)
    return NeuronStats(count, mean_d, box, boundary, d_range, d_robust, edge_boundary, mom)


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
                      cfg: AreaConfig | None = None, ref_color: torch.Tensor | None = None) -> list[ObjectArea]:
    """All object areas of one SOM (connected components of similar, grid-adjacent neurons).

    Args:
        ref_disparity: reference disparity of each neuron in px ``(K,)``.
        grid_d2: squared grid distances ``(K, K)`` of the SOM (adjacent = 1, diagonal = 2), or None
            for segmenters without a grid (k-means, superpixels): their segments link through the
            image only, whatever ``cfg.link`` says.
        stats: :func:`neuron_stats` of the member's label map.
        cfg: recognition parameters.
        ref_color: reference colour (Y, Cb, Cr in [0, 1]) of each neuron ``(K, 3)``, or None; with
            ``cfg.color_rank > 0`` an area's salience adds ``color_rank × spread ×`` the distance
            between its colour and its surroundings' (boundary-weighted), so an object with little
            depth contrast but a colour of its own can rank.

    Returns:
        areas with at least one pixel, in no particular order (see :func:`select_areas`).
    """
    cfg = cfg or AreaConfig()
    tau = cfg.similarity * stats.spread(cfg.spread)
    reach = 1.0 + 1e-6 if cfg.connectivity == 4 else 2.0 + 1e-6
    ref = ref_disparity.double().cpu()
    link = cfg.link if grid_d2 is not None else "image"
    if grid_d2 is not None:
        near = grid_d2.cpu() <= reach
    if link != "grid":
        per = stats.perimeter.clamp_min(1.0)
        touch = stats.boundary >= cfg.min_boundary * torch.minimum(per[:, None], per[None, :])
        near = touch if link == "image" else near | touch
    adj = near & ((ref[:, None] - ref[None, :]).abs() < tau)
    adj.fill_diagonal_(False)
    comps = _components(adj)
    # per-component sums as (C, K) one-hot products: one pass instead of a loop of small tensor ops
    onehot = torch.zeros(len(comps), len(ref), dtype=torch.float64)
    for i, comp in enumerate(comps):
        onehot[i, comp] = 1.0
    cnt = stats.count.double()
    md = torch.nan_to_num(stats.mean_d.double())
    if cfg.hierarchy and len(comps) > 1:
        onehot = torch.cat([onehot, merge_tree(onehot, stats, cfg.min_boundary)])
        comps = comps + [row.nonzero().flatten().tolist() for row in onehot[len(comps):]]
    n_px = onehot @ cnt
    mean = (onehot @ (md * cnt)) / n_px.clamp_min(1.0)
    border = (onehot @ stats.boundary) * (1.0 - onehot)  # (C, K) boundary with the segments outside
    b_len = border.sum(1)
    contrast = torch.where(b_len > 0, mean - (border @ md) / b_len.clamp_min(1e-300), torch.zeros_like(mean))
    salience = contrast.clone()
    if ref_color is not None and cfg.color_rank > 0:
        rc = ref_color.double().cpu()  # (K, 3)
        own_c = (onehot @ (rc * cnt[:, None])) / n_px.clamp_min(1.0)[:, None]  # (C, 3)
        around_c = (border @ rc) / b_len.clamp_min(1e-300)[:, None]
        c_con = torch.where(b_len > 0, (own_c - around_c).norm(dim=1), torch.zeros_like(mean))
        salience = salience + cfg.color_rank * stats.spread(cfg.spread) * c_con
    if stats.edge_boundary is not None and cfg.edge_rank > 0:
        # a depth boundary that no image edge follows is a matching artefact, not an object's
        # outline: the share of the area's border on image edges, against the map's share
        e_border = ((onehot @ stats.edge_boundary) * (1.0 - onehot)).sum(1)
        share = torch.where(b_len > 0, e_border / b_len.clamp_min(1e-300), torch.ones_like(mean))
        map_share = float(stats.edge_boundary.sum() / stats.boundary.sum().clamp_min(1e-300))
        if map_share > 0:
            salience = salience * (share / map_share).clamp(max=1.0) ** cfg.edge_rank
    facing = None
    if stats.moments is not None and cfg.facing_rank > 0:
        facing = _facing(onehot @ stats.moments, n_px, mean)
        salience = salience * facing ** cfg.facing_rank
    member = (onehot > 0) & (stats.count > 0)[None, :]  # (C, K): its non-empty segments
    big = torch.iinfo(torch.long).max
    x0 = torch.where(member, stats.box[None, :, 0], big).amin(1)
    y0 = torch.where(member, stats.box[None, :, 1], big).amin(1)
    x1 = torch.where(member, stats.box[None, :, 2], -1).amax(1)
    y1 = torch.where(member, stats.box[None, :, 3], -1).amax(1)
    total = float(stats.count.sum())
    areas = []
    for i, comp in enumerate(comps):
        n = float(n_px[i])
        if n == 0:
            continue
        areas.append(ObjectArea(comp, int(n), (int(x0[i]), int(y0[i]), int(x1[i]), int(y1[i])), float(mean[i]),
                                float(contrast[i]), n / total, salience=float(salience[i]),
                                facing=None if facing is None else float(facing[i])))
    return areas


def merge_tree(onehot: torch.Tensor, stats: NeuronStats, min_boundary: float) -> torch.Tensor:
    """The inner nodes of the merge tree of the areas ``onehot`` ``(C, K)`` (``AreaConfig.hierarchy``).

    Starting from the areas, the two that touch in the image (common boundary at least
    ``min_boundary`` of the shorter of their outer perimeters) with the smallest disparity step
    across that boundary (boundary-weighted mean of |Δ mean d| over the segment pairs on it) are
    joined into one node, until no two touch: C − 1 joins at most. An object split into parts at
    somewhat different depths (a hand and its forearm, a canopy and its trunk)
    joins across its small inner steps before any part joins the background across the large step
    of its outline, so the whole object is one node; the ranking chooses between a node and its
    parts (a kept node's parts and ancestors share its segments and are not kept again).

    Returns:
        ``(N, K)`` float64 membership rows of the inner nodes, in the order they were joined.
    """
    md = torch.nan_to_num(stats.mean_d.double())
    step = stats.boundary * (md[:, None] - md[None, :]).abs()
    rows = [r for r in onehot.double()]
    b = (onehot @ stats.boundary @ onehot.T).numpy().copy()  # common boundary of two nodes
    s = (onehot @ step @ onehot.T).numpy().copy()  # the same, weighted by the step on it
    np.fill_diagonal(b, 0.0)
    np.fill_diagonal(s, 0.0)
    per = b.sum(1)  # outer perimeter of each node (with other segments)
    alive = np.ones(len(rows), dtype=bool)
    joined = []
    while alive.sum() > 1:
        live = np.flatnonzero(alive)
        bb, pp = b[np.ix_(live, live)], per[live]
        touch = (bb > 0) & (bb >= min_boundary * np.minimum(pp[:, None], pp[None, :]))
        if not touch.any():
            break
        cost = np.where(touch, s[np.ix_(live, live)] / np.where(touch, bb, 1.0), np.inf)
        flat = int(np.argmin(cost))
        i, j = int(live[flat // len(live)]), int(live[flat % len(live)])
        rows.append(rows[i] + rows[j])
        joined.append(rows[-1])
        nb, ns = b[i] + b[j], s[i] + s[j]
        nb[[i, j]] = 0.0
        ns[[i, j]] = 0.0
        b = np.pad(b, ((0, 1), (0, 1)))
        s = np.pad(s, ((0, 1), (0, 1)))
        b[-1, :-1] = b[:-1, -1] = nb
        s[-1, :-1] = s[:-1, -1] = ns
        per = np.append(per, per[i] + per[j] - 2.0 * b[i, j])
        alive[[i, j]] = False
        alive = np.append(alive, True)
    return torch.stack(joined) if joined else onehot.new_zeros(0, onehot.shape[1])


def _facing(mom: torch.Tensor, n: torch.Tensor, mean_d: torch.Tensor) -> torch.Tensor:
    """How squarely each area faces the camera: cos of the angle between the normal of its
    least-squares disparity plane and the line of sight, in [0, 1].

    A 3-D plane is affine in disparity, d = a·u + b·v + c (u, v from the principal point — taken as
    the image centre — in units of the focal length, taken as the image width); its normal makes
    an angle θ with the optical axis with tan θ = |(a, b)| / c, c the plane's disparity at the
    principal point. A fronto-parallel object has cos θ = 1; a side wall or a floor, receding to
    its vanishing line through the principal point (c ≈ 0), cos θ ≈ 0; c ≤ 0 (a surface seen
    nearly edge-on) gives 0.

    Shape:
        ``mom`` ``(C, 7)`` summed :attr:`NeuronStats.moments`; ``n``, ``mean_d`` ``(C,)``.
    """
    nn = n.clamp_min(1.0)
    su, sv, suu, suv, svv, sud, svd = mom.unbind(1)
    mu, mv = su / nn, sv / nn
    cuu, cuv, cvv = suu / nn - mu * mu, suv / nn - mu * mv, svv / nn - mv * mv
    cud, cvd = sud / nn - mu * mean_d, svd / nn - mv * mean_d
    ridge = 1e-6  # (a thousandth of the image width)²: a 1-px-thin area has no gradient across
    cuu, cvv = cuu + ridge, cvv + ridge
    det = cuu * cvv - cuv * cuv
    a = (cud * cvv - cvd * cuv) / det
    b = (cvd * cuu - cud * cuv) / det
    c = mean_d - a * mu - b * mv
    cos = c / (a * a + b * b + c * c).sqrt().clamp_min(1e-12)
    return cos.clamp(0.0, 1.0)


def select_areas(areas: list[ObjectArea], stats: NeuronStats, cfg: AreaConfig | None = None) -> list[ObjectArea]:
    """The kept areas, best first, with ``rank`` set (see the module docstring)."""
    cfg = cfg or AreaConfig()
    if cfg.select == "nearest":
        ranked = sorted(areas, key=lambda a: -a.mean_disparity)[:1]
    else:
        ok = [a for a in areas if cfg.min_area_frac <= a.area_frac <= cfg.max_area_frac]
        if cfg.select == "salient":
            ok = [a for a in ok if a.contrast >= cfg.min_contrast * stats.spread(cfg.spread)]
            ranked = sorted(ok, key=lambda a: -a.ranking * a.area_frac ** cfg.size_power)
        else:
            ranked = sorted(ok, key=lambda a: -a.mean_disparity)
        ranked = ranked[:cfg.max_areas]
    for i, a in enumerate(ranked):
        a.rank = i
    return ranked
