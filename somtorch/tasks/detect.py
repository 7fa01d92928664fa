"""Paper step 1c as one capability: from one member's segmentation to its kept object areas.

:func:`find_objects` is the entry point. What does not depend on the member (the valid-mask
integral image, the disparity spread, the map's own solidity, the ground residual) lives in a
:class:`~somtorch.tasks.context.MapContext` built once per map (:mod:`somtorch.tasks.context`) and
shared by every member of an ensemble. Per member it

1. computes the segments' statistics (:func:`~somtorch.tasks.objects.neuron_stats`),
2. finds the object areas (:func:`~somtorch.tasks.objects.find_object_areas`),
3. ranks the candidates (:func:`~somtorch.tasks.objects.select_areas`; on a support-verified map
   only the areas standing on the support or above it, :func:`standing_areas`) and, in rank order,
   joins, refines and checks each (:func:`kept_areas`),
4. and, when nothing convincing is left under the ``salient`` rule, keeps the whole map and flags
   ``no_object`` — for a system meant to keep obstacles, dropping everything is the worst outcome.

What became of each candidate (kept, refused by a check and which, skipped by the keep budget, …)
is recorded as a :class:`Candidate` per area the selection looked at (``metrics.json``'s
``candidates``): why an object was not kept, without a debugger.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import torch

from ..config import AreaConfig
from ..config.objects import CONTINUOUS_SHARE
from ..core.label_stats import native_label_stats
from .candidates import OUTCOMES, Candidate, unranked_areas, verdict
from .context import MapContext
from .objects import (NeuronStats, ObjectArea, find_object_areas, label_mask, neuron_stats, rank_score,
                      salient_order, select_areas)
from .reduction import reduce_map
from .refine import (_opened_share, box_purity, merge_adjacent, refine_box, solidity_square,
                     with_grown_contrast)

__all__ = ["OUTCOMES", "Candidate", "ObjectResult", "find_objects", "first_place", "kept_areas",
           "linkable_segments", "rank_score", "standing_areas"]


def linkable_segments(labels: torch.Tensor, stats: NeuronStats, ctx: MapContext, cfg: AreaConfig) -> torch.Tensor:
    """The segments that may link by depth continuity (see :class:`~somtorch.config.AreaConfig`)
    ``(K,)`` bool: those standing above the ground plane's clutter band (mean ``|d − plane|`` over
    ``ctx.clutter_band``; every segment where there is no residual) that lie in one island
    (``ctx.islands``) of the segmented pixels, the island holding at least ``cfg.box_coverage`` of
    their pixels.

    Shape:
        ``labels`` ``(H, W)`` long (−1 not segmented).
    """
    k = int(stats.count.shape[0])
    n_isl = ctx.n_islands
    weights = [] if ctx.ground_residual is None else [ctx.ground_residual]
    one = native_label_stats(labels, k, weights, groups=ctx.islands, n_groups=n_isl)
    if one is not None:  # one pass: the residual's sums and the (segment, island) table
        res, table = (one.sums[0] if weights else None), one.groups
    else:
        lab = torch.where(labels >= 0, labels, k).view(-1)
        res = None if not weights else \
            torch.bincount(lab, weights=ctx.ground_residual.reshape(-1).double(), minlength=k + 1)[:k]
        # (segment, island) of every pixel; the unsegmented ones in row K, left out
        table = torch.bincount(lab * n_isl + ctx.islands.view(-1),
                               minlength=(k + 1) * n_isl).view(k + 1, n_isl)[:k]
    ok = torch.ones(k, dtype=torch.bool)
    if res is not None:
        ok &= res > ctx.clutter_band * stats.count  # left-over ground pixels chain everything they touch
    ok &= table.amax(1).double() >= cfg.box_coverage * stats.count  # a straddling segment chains two objects
    return ok


def standing_areas(areas: list[ObjectArea], labels: torch.Tensor, stats: NeuronStats, ctx: MapContext
                   ) -> list[ObjectArea]:
    """The candidates of a support-verified map (``ctx.ground_height`` set): the areas that stand on
    the support or above it, their pixels on average no further beneath its plane than its clutter
    band (``ctx.clutter_band``). What lies beneath a verified support (the floor past a table top's
    edge, past a parcel that fills the view) is nothing standing on it, and its size × nearness
    would outrank what is. ``areas`` itself where the context has no height.

    Shape:
        ``labels`` ``(H, W)`` long (−1 not segmented).
    """
    if ctx.ground_height is None:
        return areas
    k = int(stats.count.shape[0])
    one = native_label_stats(labels, k, [ctx.ground_height])
    if one is not None:
        h_sum = one.sums[0]
    else:
        lab = torch.where(labels >= 0, labels, k).view(-1)
        h_sum = torch.bincount(lab, weights=ctx.ground_height.reshape(-1).double(), minlength=k + 1)[:k]
    cnt = stats.count.double()
    return [a for a in areas if float(h_sum[a.neurons].sum()) >= -ctx.clutter_band * float(cnt[a.neurons].sum())]


@dataclass
class ObjectResult:
    """One member's object step: every area, the kept ones (best first), and whether it fell back;
    ``candidates``: the ranked candidates and the areas beneath a verified support that would have
    outranked the last of them, each with its verdict (:class:`Candidate`); ``unranked``: how many
    areas the ranking left out, by reason (those beneath the support listed in ``candidates``
    included)."""

    stats: NeuronStats
    areas: list[ObjectArea]
    kept: list[ObjectArea]
    no_object: bool = False
    candidates: list[Candidate] = field(default_factory=list)
    unranked: dict[str, int] = field(default_factory=dict)


def find_objects(labels: torch.Tensor, ref_disparity: torch.Tensor, grid_d2: torch.Tensor | None,
                 ctx: MapContext, cfg: AreaConfig | None = None) -> ObjectResult:
    """Step 1c on one member (see the module docstring).

    Shape:
        ``labels`` ``(H, W)`` long (−1 not segmented); ``ref_disparity`` ``(K,)`` px;
        ``grid_d2`` ``(K, K)`` or None.
    """
    cfg = cfg or AreaConfig()
    on_support = ctx.islands is not None  # a support-verified plane was cut: link by continuity too
    stats = neuron_stats(labels, ctx.disparity, int(ref_disparity.shape[-1]), spread=ctx.spread,
                         surround=ctx.surround, continuity=ctx.continuity)
    if on_support:
        areas = find_object_areas(ref_disparity, grid_d2, stats, cfg, continuous=CONTINUOUS_SHARE,
                                  linkable=linkable_segments(labels, stats, ctx, cfg))
    else:
        areas = find_object_areas(ref_disparity, grid_d2, stats, cfg)
    standing = standing_areas(areas, labels, stats, ctx)  # all where no support
    trace: list[Candidate] = []
    kept = kept_areas(standing, stats, labels, cfg, ctx, trace=trace)
    unranked = unranked_areas(areas, standing, trace, cfg, on_support)
    if kept:
        return ObjectResult(stats, areas, kept, candidates=trace, unranked=unranked)
    # nothing convincing: keep the whole map rather than nothing
    ys, xs = ctx.valid.nonzero(as_tuple=True)
    box = (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())) if ys.numel() else (0, 0, -1, -1)
    whole = ObjectArea(sorted({int(v) for v in labels.unique().tolist()} - {-1}), int(ctx.valid.sum()), box,
                       float(torch.masked_select(ctx.disparity, ctx.valid).mean()) if ys.numel() else 0.0, 0.0, 1.0, 0, confidence=0.0)
    return ObjectResult(stats, areas, [whole], no_object=True, candidates=trace, unranked=unranked)


def first_place(areas: list[ObjectArea], stats: NeuronStats, labels: torch.Tensor, cfg: AreaConfig,
                ctx: MapContext, useful: Callable[[list[ObjectArea]], bool]) -> bool:
    """Whether a perfect ranking of this member's candidates would have made it useful: each candidate
    the ranking sees (``areas`` as :func:`find_objects` found them; on a support-verified map those
    standing on it) is tried first, in rank order, the others following it, and joined, refined,
    checked and budgeted by :func:`kept_areas` as the step does, until ``useful(kept)`` holds (an
    empty ``kept``: the step keeps the whole map). The ceiling of the ranking alone: unlike
    :func:`~somtorch.evaluation.selection_ceiling`, which scores each area's bare box, it counts what
    the step would keep. The areas are copied: their ``rank`` is not touched.

    Shape:
        ``labels`` ``(H, W)`` long (−1 not segmented).
    """
    standing = [replace(a) for a in standing_areas(areas, labels, stats, ctx)]
    if cfg.rule == "paper":
        return useful(kept_areas(standing, stats, labels, cfg, ctx))
    order = salient_order(standing, cfg, on_support=ctx.islands is not None)  # (before the grown contrast)
    memo: dict = {}  # each try joins and refines mostly the same candidates: once each (session 42)
    return any(useful(kept_areas(standing, stats, labels, cfg, ctx, try_first=a.neurons, memo=memo))
               for a in order)


def _window(box: tuple[int, int, int, int], shape: tuple[int, ...], margin: int
            ) -> tuple[tuple[slice, slice], tuple[int, int]]:
    """The ``(rows, cols)`` slices of ``box`` (x0, y0, x1, y1, inclusive) widened by ``margin`` px and
    clipped to a map of ``shape`` ``(H, W)``, and the window's top-left ``(x, y)``."""
    h, w = shape[-2:]
    x0, y0 = max(box[0] - margin, 0), max(box[1] - margin, 0)
    x1, y1 = min(box[2] + margin, w - 1), min(box[3] + margin, h - 1)
    return (slice(y0, y1 + 1), slice(x0, x1 + 1)), (x0, y0)


def _shift(box: tuple[int, int, int, int], dx: int, dy: int) -> tuple[int, int, int, int]:
    return box[0] + dx, box[1] + dy, box[2] + dx, box[3] + dy


def _parts(own: torch.Tensor, uncut: torch.Tensor | None, coverage: float, residual: torch.Tensor | None,
           band: float) -> list[torch.Tensor]:
    """An area's pixels ``own`` split by the cut ground and wide invalid gaps: one mask per region of
    ``uncut`` (:func:`~somtorch.tasks.context._regions`) that holds more than ``1 − coverage`` of
    them and does not lie flat on the ground (most of its pixels within ``band`` px of the plane,
    ``residual`` = |d − plane|: :func:`refine_box`'s ground clutter), largest first; ``[own]`` where
    ``uncut`` is None (the ``paper`` rule), one region holds all, or every part lies on the ground."""
    if uncut is None:
        return [own]
    vals = uncut[own]
    tally = torch.bincount(vals)  # pixels per region id, the ids ascending (torch.unique's order)
    ids = tally.nonzero().squeeze(1)
    counts = tally[ids]
    if ids.numel() <= 1:
        return [own]
    order = torch.argsort(counts, descending=True, stable=True).tolist()
    total = float(vals.numel())
    big = (counts > (1 - coverage) * total).tolist()  # one comparison for all regions, not one per region
    chosen = [i for i in order if i == order[0] or big[i]]
    if residual is not None and band > 0:  # each region's pixels within the band, counted at once
        low = torch.bincount(uncut[own & (residual < band)], minlength=tally.numel()).tolist()
        n_l, id_l = tally.tolist(), ids.tolist()
        chosen = [i for i in chosen if low[id_l[i]] / n_l[id_l[i]] <= 0.5]
    parts = [own & (uncut == ids[i]) for i in chosen]
    return parts or [own]


def _refined(joined: ObjectArea, part: torch.Tensor, labels: torch.Tensor, win: tuple[slice, slice],
             origin: tuple[int, int], residual: torch.Tensor | None, square: int, confidence: float,
             cfg: AreaConfig, ctx: MapContext) -> ObjectArea:
    """``joined`` restricted to the pixels ``part`` of the window ``win`` (top-left ``origin``;
    ``residual``: the ground residual on it): its refined box (:func:`refine_box`), purity,
    solidity and confidence, in map coordinates."""
    x0, y0 = origin
    n = int(part.sum())
    local = replace(joined, box=_shift(joined.box, -x0, -y0), segment_box=None)
    if n != joined.pixels:  # a part of the area: its own pixels and extent
        ys, xs = part.nonzero(as_tuple=True)
        local = replace(local, pixels=n, area_frac=joined.area_frac * n / max(joined.pixels, 1),
                        box=(int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())),
                        mean_disparity=float(ctx.disparity[win][part].double().mean()))
    done = refine_box(local, labels[win], coverage=cfg.box_coverage, quantile=cfg.box_quantile,
                      ground_residual=residual, clutter_band=ctx.clutter_band,
                      drop_specks=cfg.rule != "paper", mask=part)
    done = replace(done, box=_shift(done.box, x0, y0), segment_box=joined.segment_box
                   if done.segment_box is None else _shift(done.segment_box, x0, y0))
    solid = _opened_share(part, square)  # in [0, 1]: the opening keeps a subset of the pixels
    return replace(done, purity=box_purity(done, labels, ctx.integral, part, origin=origin), solidity=solid,
                   solidity_rel=solid / ctx.solidity, confidence=confidence)


def _refined_parts(joined: ObjectArea, labels: torch.Tensor, square: int, confidence: float, cfg: AreaConfig,
                   ctx: MapContext) -> list[ObjectArea]:
    """The parts of ``joined`` (:func:`_parts`), each refined (:func:`_refined`): what
    :func:`kept_areas` checks of a candidate once it is joined."""
    # every check reads the window of the area's segments (their box, widened by half the
    # opening's square where the map goes on), not the whole map: the same result
    win, origin = _window(joined.box, labels.shape, square // 2 + 1)
    own = label_mask(labels[win], joined.neurons)  # refine_box moves the box, not the neurons
    residual = None if ctx.ground_residual is None else ctx.ground_residual[win]
    uncut = None if ctx.uncut is None else ctx.uncut[win]
    return [_refined(joined, part, labels, win, origin, residual, square, confidence, cfg, ctx)
            for part in _parts(own, uncut, cfg.box_coverage, residual, ctx.clutter_band)]


def _memo_key(area: ObjectArea) -> tuple:
    """Every field of ``area`` (its neurons as a tuple): two joined areas with the same key refine
    to the same parts."""
    return tuple(tuple(v) if isinstance(v, list) else v for v in vars(area).values())


def kept_areas(areas: list[ObjectArea], stats: NeuronStats, labels: torch.Tensor, cfg: AreaConfig,
               ctx: MapContext, *, trace: list[Candidate] | None = None,
               try_first: list[int] | None = None, memo: dict | None = None) -> list[ObjectArea]:
    """Select, join, refine and check the candidates in rank order.

    Each candidate is joined with its adjacent segments (:func:`merge_adjacent`, never with segments of
    an area kept before it) and, where the cut ground or a wide invalid gap separates its pixels, split
    into parts (``ctx.uncut``; :func:`_parts`), each then treated as a candidate of its own: its box
    refined (:func:`refine_box`), and kept if its :func:`box_purity` reaches ``cfg.min_purity`` and its
    segments' solidity reaches ``cfg.min_solidity ×`` the map's (so a sparse map is not held to a dense
    map's standard). After the first kept area, a further one must, with ``cfg.keep_budget < 1``, leave
    the union of the kept boxes, each with the reduction's margins (``ctx.margins``: what the reduced
    map keeps), within that share of the valid pixels (else it is skipped and the next candidate tried).
    At most ``cfg.max_areas`` areas are kept (the parts of one count once), out of the ``cfg.max_areas``
    best-ranked candidates (a failed check leaves room for the next of them). If none passed: nothing
    under the ``salient`` rule (the caller keeps the whole map), the paper rule's nearest area under
    ``rule="paper"`` (the paper always keeps it).

    Every kept area carries its ``purity``, ``solidity`` (the opened share of its pixels, ≤ 1),
    ``solidity_rel`` (that share over the map's own, which may exceed 1: the area is more solid than
    the map) and
    ``confidence`` (rank score over the best candidate's).

    ``trace``: a list that receives a :class:`Candidate` per ranked candidate, in rank order, with
    what became of it (kept, refused by which check, skipped by the budget, not tried).

    ``try_first``: the neurons of one of ``areas`` to try first, whatever its rank (an analysis of the
    ranking: :func:`first_place`); the others follow in rank order, ``cfg.max_areas`` in all. Not
    used under ``rule="paper"``, which keeps one area.

    ``memo``: a dict shared by calls on the same ``areas``, ``stats``, ``labels``, ``cfg`` and ``ctx``
    (:func:`first_place`'s tries): a candidate's join and refined parts, which depend on nothing
    else but the segments kept before it, are computed once per such state (the same result).

    Shape:
        ``labels`` ``(H, W)``.
    """
    on_support = ctx.islands is not None  # a support-verified plane was cut: size × nearness
    if not on_support and cfg.rule != "paper":  # ranked by contrast: of the area and of what merge keeps
        areas = with_grown_contrast([a for a in areas if a.contrast >= 0], stats, cfg)
    if try_first is not None and cfg.rule != "paper":
        pool = salient_order(areas, cfg, on_support=on_support)
        lead = [a for a in pool if a.neurons == try_first]
        if not lead:
            raise ValueError(f"kept_areas(try_first={try_first}): no candidate area has these neurons")
        ranked = (lead + [a for a in pool if a is not lead[0]])[:cfg.max_areas]
        for i, a in enumerate(ranked):
            a.rank = i
    else:
        ranked = select_areas(areas, stats, cfg, on_support=on_support)
    taken = torch.zeros(int(stats.count.shape[0]), dtype=torch.bool)
    kept, first, n_areas = [], None, 0
    square = solidity_square(labels.shape, cfg.solidity_size, 1)
    best = max((rank_score(a, cfg, on_support=on_support) for a in ranked), default=0.0)
    verdicts: list[tuple[str, str]] = []
    for cand in ranked:
        if n_areas == cfg.max_areas:
            verdicts.append((f"not tried: max_areas ({cfg.max_areas}) areas kept already", "not tried"))
            continue
        if bool(taken[torch.tensor(cand.neurons)].any()):
            verdicts.append(("not tried: some of its segments went into an area kept before it", "not tried"))
            continue
        confidence = rank_score(cand, cfg, on_support=on_support) / best if best > 0 else 1.0
        # memo: the join depends on the segments kept before it, the refinement on the joined area alone
        key = None if memo is None else ("join", tuple(cand.neurons), taken.numpy().tobytes())
        joined = None if key is None else memo.get(key)
        if joined is None:
            joined = merge_adjacent([cand], stats, ratio=cfg.merge, min_boundary=cfg.min_boundary,
                                    exclude=taken)[0]
            if key is not None:
                memo[key] = joined
        if memo is None:
            refined = _refined_parts(joined, labels, square, confidence, cfg, ctx)
        else:  # copies, with this try's confidence: what a try keeps is its own
            key = ("parts", _memo_key(joined))
            if key not in memo:
                memo[key] = _refined_parts(joined, labels, square, confidence, cfg, ctx)
            refined = [replace(d, confidence=confidence) for d in memo[key]]
        any_kept = False
        outcomes = []
        for done in refined:
            if first is None:
                first = done
            if done.purity < cfg.min_purity:
                outcomes.append(("refused", f"refused: purity {done.purity:.2f} < min_purity "
                                            f"{cfg.min_purity:g}"))
                continue
            if done.solidity_rel < cfg.min_solidity:
                outcomes.append(("refused", f"refused: solidity {done.solidity_rel:.2f} × the map's < "
                                            f"min_solidity {cfg.min_solidity:g}"))
                continue
            if kept and cfg.keep_budget < 1:
                m_px, m_frac, m_image = ctx.margins
                union = reduce_map([a.box for a in kept] + [done.box], ctx.valid, tolerance_px=m_px,
                                   tolerance_frac=m_frac, tolerance_image=m_image, integral=ctx.integral)
                if union.kept_union > cfg.keep_budget * max(union.valid_total, 1):
                    share = 100 * union.kept_union / max(union.valid_total, 1)
                    outcomes.append(("skipped", f"skipped: the kept boxes would hold {share:.0f} % of the "
                                                f"valid pixels > keep_budget {100 * cfg.keep_budget:g} %"))
                    continue  # it would not fit the reduction budget; a smaller one may
            kept.append(done)
            outcomes.append(("kept", "kept"))
            any_kept = True
        verdicts.append(verdict(outcomes, joined, cand))
        if any_kept:  # the parts of one area count as one of the max_areas
            taken[torch.tensor(joined.neurons)] = True
            n_areas += 1
    if not kept and first is not None and cfg.rule == "paper":
        kept = [first]
        verdicts[0] = ("kept: the paper rule keeps its nearest area", "kept")
    if trace is not None:
        trace.extend(Candidate(c, rank_score(c, cfg, on_support=on_support), i, v, kind)
                     for i, (c, (v, kind)) in enumerate(zip(ranked, verdicts)))
    for i, a in enumerate(kept):
        a.rank = i
    return kept
