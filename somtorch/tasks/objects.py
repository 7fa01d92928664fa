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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from ..validation import check_choice, check_positive, check_positive_int, check_tensor

SELECTIONS = ("nearest", "salient", "all")


@dataclass
class AreaConfig:
    """Parameters of object-area recognition (see the module docstring).

    Attributes:
        similarity: two grid-adjacent neurons are similar if their reference disparities differ by
            less than ``similarity × (d_max − d_min)`` of the map.
        connectivity: 4 (grid rows/columns only) or 8 (diagonals too) for rectangular maps.
        select: ``"nearest"``, ``"salient"`` or ``"all"``.
        max_areas: how many areas are kept at most.
        min_contrast: salient: minimum contrast, as a fraction of the disparity range.
        max_area_frac, min_area_frac: size limits as fractions of the valid pixels.
    """

    similarity: float = 0.1
    connectivity: int = 4
    select: str = "salient"
    max_areas: int = 1
    min_contrast: float = 0.02
    max_area_frac: float = 0.5
    min_area_frac: float = 0.002

    def __post_init__(self) -> None:
        check_positive("similarity", self.similarity)
        if self.connectivity not in (4, 8):
            raise ValueError(f"connectivity must be 4 or 8; got {self.connectivity!r}")
        check_choice("select", self.select, SELECTIONS)
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
    """

    count: torch.Tensor
    mean_d: torch.Tensor
    box: torch.Tensor
    boundary: torch.Tensor
    d_range: tuple[float, float]


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


def neuron_stats(labels: torch.Tensor, disparity: torch.Tensor, num_neurons: int) -> NeuronStats:
    """Statistics of the segments of one label map.

    Shape:
        ``labels`` ``(H, W)`` long (−1 invalid), ``disparity`` ``(H, W)``.
    """
    check_tensor("labels", labels, ndim=2, dtype=torch.long)
    if disparity.shape != labels.shape:
        raise ValueError(f"disparity {tuple(disparity.shape)} and labels {tuple(labels.shape)} differ in shape")
    k = num_neurons
    h, w = labels.shape
    valid = labels >= 0
    lab = labels[valid]
    d = disparity[valid].double()
    count = torch.bincount(lab, minlength=k).double()
    mean_d = torch.zeros(k, dtype=torch.float64).index_add_(0, lab, d) / count
    ys, xs = valid.nonzero(as_tuple=True)
    box = torch.empty(k, 4, dtype=torch.long)
    box[:, 0] = torch.full((k,), w, dtype=torch.long).scatter_reduce(0, lab, xs, "amin")
    box[:, 1] = torch.full((k,), h, dtype=torch.long).scatter_reduce(0, lab, ys, "amin")
    box[:, 2] = torch.full((k,), -1, dtype=torch.long).scatter_reduce(0, lab, xs, "amax")
    box[:, 3] = torch.full((k,), -1, dtype=torch.long).scatter_reduce(0, lab, ys, "amax")
    pairs = []
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        m = (a >= 0) & (b >= 0) & (a != b)
        pairs.append(a[m] * k + b[m])
    flat = torch.cat(pairs)
    boundary = torch.bincount(flat, minlength=k * k).view(k, k).double()
    boundary = boundary + boundary.T
    return NeuronStats(count, mean_d, box, boundary, (float(d.min()), float(d.max())))


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


def find_object_areas(ref_disparity: torch.Tensor, grid_d2: torch.Tensor, stats: NeuronStats,
                      cfg: AreaConfig | None = None) -> list[ObjectArea]:
    """All object areas of one SOM (connected components of similar, grid-adjacent neurons).

    Args:
        ref_disparity: reference disparity of each neuron in px ``(K,)``.
        grid_d2: squared grid distances ``(K, K)`` of the SOM (adjacent = 1, diagonal = 2).
        stats: :func:`neuron_stats` of the member's label map.
        cfg: recognition parameters.

    Returns:
        areas with at least one pixel, in no particular order (see :func:`select_areas`).
    """
    cfg = cfg or AreaConfig()
    lo, hi = stats.d_range
    tau = cfg.similarity * max(hi - lo, 1e-9)
    reach = 1.0 + 1e-6 if cfg.connectivity == 4 else 2.0 + 1e-6
    ref = ref_disparity.double().cpu()
    adj = (grid_d2.cpu() <= reach) & ((ref[:, None] - ref[None, :]).abs() < tau)
    adj.fill_diagonal_(False)
    total = float(stats.count.sum())
    areas = []
    for comp in _components(adj):
        idx = torch.tensor(comp)
        n = float(stats.count[idx].sum())
        if n == 0:
            continue
        cnt = stats.count[idx]
        mean_d = float((torch.nan_to_num(stats.mean_d[idx]) * cnt).sum() / n)
        inside = torch.zeros(len(ref), dtype=torch.bool)
        inside[idx] = True
        border = stats.boundary[idx][:, ~inside].sum(0)  # (K_outside,) boundary with outside segments
        outside_d = torch.nan_to_num(stats.mean_d[~inside])
        contrast = (mean_d - float((border * outside_d).sum() / border.sum())) if border.sum() > 0 else 0.0
        b = stats.box[idx]
        nonempty = cnt > 0
        box = (int(b[nonempty, 0].min()), int(b[nonempty, 1].min()), int(b[nonempty, 2].max()),
               int(b[nonempty, 3].max()))
        areas.append(ObjectArea(comp, int(n), box, mean_d, contrast, n / total))
    return areas


def select_areas(areas: list[ObjectArea], stats: NeuronStats, cfg: AreaConfig | None = None) -> list[ObjectArea]:
    """The kept areas, best first, with ``rank`` set (see the module docstring)."""
    cfg = cfg or AreaConfig()
    lo, hi = stats.d_range
    if cfg.select == "nearest":
        ranked = sorted(areas, key=lambda a: -a.mean_disparity)[:1]
    else:
        ok = [a for a in areas if cfg.min_area_frac <= a.area_frac <= cfg.max_area_frac]
        if cfg.select == "salient":
            ok = [a for a in ok if a.contrast >= cfg.min_contrast * max(hi - lo, 1e-9)]
            ranked = sorted(ok, key=lambda a: -a.contrast)
        else:
            ranked = sorted(ok, key=lambda a: -a.mean_disparity)
        ranked = ranked[:cfg.max_areas]
    for i, a in enumerate(ranked):
        a.rank = i
    return ranked
