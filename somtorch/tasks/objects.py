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

What happens to the selected areas afterwards (joining adjacent segments, box refinement, growing,
the purity test) is in :mod:`somtorch.tasks.refine`; :func:`~somtorch.tasks.refine.kept_areas` runs
selection and those steps in order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ..validation import check_choice, check_positive, check_positive_int, check_tensor

SELECTIONS = ("nearest", "salient", "all")
LINKS = ("grid", "image", "both")
SPREADS = ("range", "robust")


@dataclass
class AreaConfig:
    """Parameters of object-area recognition (see the module docstring).

    The defaults are the ``robust`` preset (segments merge across image-space boundaries, robust
    spread, salient selection); ``conf/objects/paper.yaml`` holds the paper's literal rule
    (``link="grid"``, ``spread="range"``, ``similarity=0.1``, ``select="nearest"``).

    Attributes:
        similarity: two linked neurons are similar if their reference disparities differ by
            less than ``similarity × spread`` of the map.
        connectivity: 4 (grid rows/columns only) or 8 (diagonals too) for rectangular maps.
        link: which neurons may join: ``"grid"`` (adjacent on the SOM grid, the paper's rule),
            ``"image"`` (their segments share a boundary in the image) or ``"both"``.
        spread: ``"range"`` (d_max − d_min of the segmented pixels, the paper's reading) or
            ``"robust"`` (5th–95th percentile, insensitive to the outliers of computed maps).
        min_boundary: with ``link="image"``/``"both"``, two segments touch if their common boundary
            is at least this fraction of the shorter of their two perimeters.
        select: ``"nearest"``, ``"salient"`` or ``"all"``.
        merge: join to each kept area the image-adjacent segments whose mean disparity is within
            ``merge ×`` its contrast of its own (other parts of the same object at another depth, see
            :func:`~somtorch.tasks.refine.merge_adjacent`); 0 = off. Measured (100 runs, OR, useful hits Motorcycle / KITTI /
            FlyingThings3D / ETH3D / OAK-D toy): off 87/91/85/93/85, 0.5 99/91/87/93/91, 0.75
            99/91/100/93/99, 1.0 93/91/100/91/100.
        min_purity: a kept area's (joined, refined) box must be at least this share its own pixels,
            of the valid pixels inside it; otherwise the next candidate in rank order is tried (at most
            ``purity_candidates`` in all; if none passes, the best-ranked one is kept). Rejects areas
            made of scattered SGBM speckles and border junk, whose box is mostly other segments.
            0 = off. Measured (100 runs, OR, useful hits): the 8 shared scenes 483 / 488 / 479 / 449
            at 0.15 / 0.25 / 0.35 / 0.5 (0 = 483); four scenes re-computed with our SGBM (KITTI's
            estimate, Motorcycle, ETH3D, FlyingThings3D pairs) 168 at 0, 228 / **249** / 196 at
            0.15 / 0.25 / 0.35 (ETH3D 8 → 87).
        min_solidity: a kept area's segments must also be solid: the share of their pixels that
            survives a morphological opening with a square of ``solidity_size ×`` the shorter image
            side must be at least ``min_solidity ×`` the same share for all the segmented pixels (see
            :func:`~somtorch.tasks.refine.solidity`); otherwise the next candidate is tried, as for
            the purity. Rejects the thin horizontal streaks and scattered mismatches SGBM leaves
            on textureless ceilings and walls, which can be the nearest, most contrasted "area" of a
            computed map. 0 = off. Measured (100 runs, OR, check off): the relative solidity of
            every kept area that is a useful hit on the 8 shared scenes is 0.43–1.74 (ETH3D's
            slatted chair lowest; KITTI's sparse ground truth above 1 thanks to the
            normalisation); the picks below 0.25 on the OAK-D desk and corridor are ceiling
            streaks and scattered speckles (checked by eye, 0.00–0.23);
            with 0.25 the OAK-D scenes without masks keep junk in 3 / 0 / 0 of 100 runs (desk /
            corridor / kid_bedroom) instead of 52 / 31 / 3, and the scores of the masked scenes
            (shared and computed-disparity) are unchanged (488 / 249 useful hits at 0, 0.15,
            0.25 and 0.35).
        solidity_size: side of the opening's square as a fraction of the shorter image side.
        purity_candidates: how many ranked candidates the purity and solidity tests may try.
        grow: replace each kept area by the image-connected region around it that is nearer than
            half-way between the area and its surroundings (``mean_disparity − contrast/2``): an
            object split over several areas is recovered whole, background pixels inside the
            area's segments are dropped.
        grow_stride: the growing and the box refinement work on every ``grow_stride``-th pixel.
        box_coverage: a kept area's box covers its largest image-connected pieces up to this share
            of its pixels, so stray fragments of its segments far from the object do not stretch the
            box (1.0 = the box of all the segments' pixels, the paper's reading).
        box_quantile: the box spans the ``box_quantile`` … ``1 − box_quantile`` quantiles of the kept
            pixels' coordinates, so a thin protrusion (an antenna, an SGBM streak: ~0.1 % of the
            pixels) does not move an edge; 0 = the full extent. See :func:`~somtorch.tasks.refine.refine_box`.
        ground_clutter: pieces of a kept area lying on the ground plane (more than half of their
            pixels within ``ground_clutter ×`` the plane's inlier band) are left out of its box:
            streaks of a computed floor that share the object's disparity. 0 = off; no effect
            without a ground plane. The default 3 measured (100 runs, OR) on the OAK-D toy: useful
            hits 0 → 48 at 2×–5× the band (2×: 0), no change on the other scenes.
        size_power: salient: areas are ranked by ``contrast × area_frac ** size_power`` (0 = by
            contrast alone; 0.5 favours large salient objects over small salient fragments). The
            default 0.25 came from the 100-run study over the shared scenes (OR, useful hits of
            Motorcycle + KITTI + FlyingThings3D + ETH3D: 247 at 0, 297 at 0.25, 293 at 0.35, 286 at
            0.5): a small contrasty fragment or SGBM streak no longer beats a whole object.
        max_areas: how many areas are kept at most.
        min_contrast: salient: minimum contrast, as a fraction of the disparity range.
        max_area_frac, min_area_frac: size limits as fractions of the valid pixels.
    """

    similarity: float = 0.05
    connectivity: int = 4
    link: str = "image"
    spread: str = "robust"
    min_boundary: float = 0.1
    size_power: float = 0.25
    grow: bool = False
    grow_stride: int = 2
    box_coverage: float = 0.99
    box_quantile: float = 0.001
    ground_clutter: float = 3.0
    merge: float = 0.75
    min_purity: float = 0.25
    min_solidity: float = 0.25
    solidity_size: float = 0.02
    purity_candidates: int = 5
    select: str = "salient"
    max_areas: int = 1
    min_contrast: float = 0.02
    max_area_frac: float = 0.5
    min_area_frac: float = 0.01

    def __post_init__(self) -> None:
        check_positive("similarity", self.similarity)
        if self.connectivity not in (4, 8):
            raise ValueError(f"connectivity must be 4 or 8; got {self.connectivity!r}")
        check_choice("select", self.select, SELECTIONS)
        check_choice("link", self.link, LINKS)
        check_choice("spread", self.spread, SPREADS)
        check_positive("min_boundary", self.min_boundary, allow_zero=True)
        check_positive_int("grow_stride", self.grow_stride)
        if not 0 < self.box_coverage <= 1:
            raise ValueError(f"box_coverage must be in (0, 1]; got {self.box_coverage}")
        if not 0 <= self.box_quantile < 0.5:
            raise ValueError(f"box_quantile must be in [0, 0.5); got {self.box_quantile}")
        check_positive("ground_clutter", self.ground_clutter, allow_zero=True)
        check_positive("merge", self.merge, allow_zero=True)
        if not 0 <= self.min_purity <= 1:
            raise ValueError(f"min_purity must be in [0, 1]; got {self.min_purity}")
        if not 0 <= self.min_solidity <= 1:
            raise ValueError(f"min_solidity must be in [0, 1]; got {self.min_solidity}")
        if not 0 < self.solidity_size <= 0.5:
            raise ValueError(f"solidity_size must be in (0, 0.5]; got {self.solidity_size}")
        check_positive_int("purity_candidates", self.purity_candidates)
        check_positive_int("max_areas", self.max_areas)
        check_positive("min_contrast", self.min_contrast, allow_zero=True)
        check_positive("max_area_frac", self.max_area_frac)
        check_positive("min_area_frac", self.min_area_frac, allow_zero=True)
        if self.max_area_frac > 1 or self.min_area_frac >= self.max_area_frac:
            raise ValueError(f"need 0 <= min_area_frac < max_area_frac <= 1; got {self.min_area_frac}, "
                             f"{self.max_area_frac}")


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
    """

    count: torch.Tensor
    mean_d: torch.Tensor
    box: torch.Tensor
    boundary: torch.Tensor
    d_range: tuple[float, float]
    d_robust: tuple[float, float]

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
    extra: dict = field(default_factory=dict)

    def mask(self, labels: torch.Tensor) -> torch.Tensor:
        """The area's pixels: the union of its neurons' segments. ``labels`` ``(H, W)`` → ``(H, W)`` bool."""
        return torch.isin(labels, torch.tensor(self.neurons, dtype=labels.dtype, device=labels.device))


def disparity_spread(disparity: torch.Tensor, valid: torch.Tensor) -> tuple[tuple[float, float], tuple[float, float]]:
    """(min, max) and (5th, 95th percentile) of the disparity of the ``valid`` pixels (the latter on a
    ~20,000-pixel regular subsample): the ``d_range`` / ``d_robust`` of :class:`NeuronStats`.

    They depend on the segmented pixels only, not on the segments, so the members of an ensemble
    (which all segment the same pixels) can share one computation (``neuron_stats(spread=…)``).
    """
    d = disparity[valid]
    step = max(1, d.numel() // 20_000)
    sample = d[::step].double()
    n = sample.numel()
    lo_q = float(sample.kthvalue(max(1, int(0.05 * n))).values)
    hi_q = float(sample.kthvalue(max(1, int(0.95 * n))).values)
    return (float(d.min()), float(d.max())), (lo_q, hi_q)


def neuron_stats(labels: torch.Tensor, disparity: torch.Tensor, num_neurons: int, *,
                 spread: tuple[tuple[float, float], tuple[float, float]] | None = None) -> NeuronStats:
    """Statistics of the segments of one label map.

    Args:
        spread: :func:`disparity_spread` of ``disparity`` over ``labels >= 0`` if already known
            (computed here otherwise).

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
    boundary = torch.bincount(torch.cat(pairs), minlength=(k + 1) ** 2).view(k + 1, k + 1)[:k, :k].double()
    boundary.fill_diagonal_(0.0)
    boundary = boundary + boundary.T
    d_range, d_robust = spread if spread is not None else disparity_spread(disparity, valid)
    return NeuronStats(count, mean_d, box, boundary, d_range, d_robust)


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
                      cfg: AreaConfig | None = None) -> list[ObjectArea]:
    """All object areas of one SOM (connected components of similar, grid-adjacent neurons).

    Args:
        ref_disparity: reference disparity of each neuron in px ``(K,)``.
        grid_d2: squared grid distances ``(K, K)`` of the SOM (adjacent = 1, diagonal = 2), or None
            for segmenters without a grid (k-means, superpixels): their segments link through the
            image only, whatever ``cfg.link`` says.
        stats: :func:`neuron_stats` of the member's label map.
        cfg: recognition parameters.

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
    owner = torch.empty(len(ref), dtype=torch.long)
    for i, comp in enumerate(comps):
        owner[comp] = i
    onehot = torch.zeros(len(comps), len(ref), dtype=torch.float64)
    onehot[owner, torch.arange(len(ref))] = 1.0
    cnt = stats.count.double()
    md = torch.nan_to_num(stats.mean_d.double())
    n_px = onehot @ cnt
    mean = (onehot @ (md * cnt)) / n_px.clamp_min(1.0)
    border = (onehot @ stats.boundary) * (1.0 - onehot)  # (C, K) boundary with the segments outside
    b_len = border.sum(1)
    contrast = torch.where(b_len > 0, mean - (border @ md) / b_len.clamp_min(1e-300), torch.zeros_like(mean))
    nonempty = stats.count > 0
    big = torch.iinfo(torch.long).max
    x0 = torch.full((len(comps),), big).scatter_reduce(0, owner[nonempty], stats.box[nonempty, 0], "amin")
    y0 = torch.full((len(comps),), big).scatter_reduce(0, owner[nonempty], stats.box[nonempty, 1], "amin")
    x1 = torch.full((len(comps),), -1).scatter_reduce(0, owner[nonempty], stats.box[nonempty, 2], "amax")
    y1 = torch.full((len(comps),), -1).scatter_reduce(0, owner[nonempty], stats.box[nonempty, 3], "amax")
    total = float(stats.count.sum())
    areas = []
    for i, comp in enumerate(comps):
        n = float(n_px[i])
        if n == 0:
            continue
        areas.append(ObjectArea(comp, int(n), (int(x0[i]), int(y0[i]), int(x1[i]), int(y1[i])), float(mean[i]),
                                float(contrast[i]), n / total))
    return areas


def select_areas(areas: list[ObjectArea], stats: NeuronStats, cfg: AreaConfig | None = None) -> list[ObjectArea]:
    """The kept areas, best first, with ``rank`` set (see the module docstring)."""
    cfg = cfg or AreaConfig()
    if cfg.select == "nearest":
        ranked = sorted(areas, key=lambda a: -a.mean_disparity)[:1]
    else:
        ok = [a for a in areas if cfg.min_area_frac <= a.area_frac <= cfg.max_area_frac]
        if cfg.select == "salient":
            ok = [a for a in ok if a.contrast >= cfg.min_contrast * stats.spread(cfg.spread)]
            ranked = sorted(ok, key=lambda a: -a.contrast * a.area_frac ** cfg.size_power)
        else:
            ranked = sorted(ok, key=lambda a: -a.mean_disparity)
        ranked = ranked[:cfg.max_areas]
    for i, a in enumerate(ranked):
        a.rank = i
    return ranked
