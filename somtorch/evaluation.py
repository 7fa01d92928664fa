"""One evaluation layer: per-run records, per-object scores, the all-objects reading, summaries.

Used by ``somtorch-run``, the studies, the validation protocol and the scripts, so every table is
scored by the same code (:mod:`somtorch.tasks.scoring` scores one reduction against one mask).

* **useful hit** (main object): ≥ 95 % of the scored object inside the kept boxes and a reduction
  ≥ 0.75 × x_opt (the reduction of keeping exactly the object's box);
* **all-objects hit**: *every* labelled object with a valid pixel ≥ 95 % inside the kept union
  and a reduction ≥ 0.75 × the reduction of keeping exactly the union of the objects' boxes;
* **ground-object share**: share of the objects' valid pixels that the ground mask removed
  (they can then never be kept as an object; the target is ≈ 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .disparity.scene import Scene
from .tasks.ground import GroundPlane
from .tasks.reduction import Reduction, box_count, expand_box, reduce_map, valid_integral
from .tasks.scoring import IDENTIFIED, USEFUL_FACTOR, object_box, score_reduction

__all__ = ["GAP_REASONS", "AllObjects", "all_objects", "ground_object_share", "grouping_ceiling",
           "merge_runs", "per_object_scores", "run_records", "segment_f1", "selection_ceiling",
           "selection_gap", "single_box_hit", "summarize_runs", "summary_stats"]


def summary_stats(values: list[float]) -> dict[str, float | int | None]:
    """``n``, ``min``, ``mean``, ``max`` and ``median`` of a list (None for an empty one)."""
    if not values:
        return {"n": 0, "min": None, "mean": None, "max": None, "median": None}
    a = np.asarray(values, dtype=np.float64)
    return {"n": int(a.size), "min": float(a.min()), "mean": float(a.mean()), "max": float(a.max()),
            "median": float(np.median(a))}



@dataclass
class AllObjects:
    """The labelled objects of a scene as one target: their masks and the union-of-boxes reduction."""

    masks: list[torch.Tensor]
    valid: torch.Tensor
    x_opt: float  # reduction in % when exactly the union of the objects' boxes is kept

    def hit(self, reduction: Reduction, *, useful_factor: float = USEFUL_FACTOR,
            min_fraction: float = IDENTIFIED) -> bool:
        """Every object ≥ ``min_fraction`` inside the kept union and reduction ≥ factor × x_opt."""
        for m in self.masks:
            obj = m & self.valid
            if int((obj & reduction.mask).sum()) < min_fraction * int(obj.sum()):
                return False
        return reduction.reduction_union >= useful_factor * self.x_opt


def all_objects(scene: Scene) -> AllObjects | None:
    """:class:`AllObjects` of ``scene`` (objects without a valid pixel are left out), None if unlabelled."""
    if scene.objects is None:
        return None
    masks = [scene.object_mask(o.id) for o in scene.object_info]
    masks = [m for m in masks if bool((m & scene.valid).any())]
    if not masks:
        return None
    x_opt = reduce_map([object_box(m) for m in masks], scene.valid, tolerance_px=0.0, tolerance_frac=0.0,
                       tolerance_image=0.0).reduction_union
    return AllObjects(masks, scene.valid, x_opt)


def ground_object_share(ground: GroundPlane | None, scene: Scene) -> float:
    """Share of the labelled objects' valid pixels inside the ground mask (0 without a plane)."""
    if ground is None or scene.objects is None:
        return 0.0
    obj = (scene.objects > 0) & scene.valid
    n = int(obj.sum())
    return int((obj & ground.mask).sum()) / n if n else 0.0


def selection_ceiling(members: list, object_mask: torch.Tensor, valid: torch.Tensor, x_opt: float, *,
                      tolerance_px: float, tolerance_frac: float, tolerance_image: float,
                      useful_factor: float = USEFUL_FACTOR) -> int:
    """How many of ``members`` (pipeline :class:`~somtorch.results.MemberResult`) had, among their
    kept areas and every area the grouping produced, one whose box alone — with the reduction's
    tolerance — is a useful hit: the ceiling of a perfect choice among the step's candidates
    (a run counted here may still miss: the step kept another area, or more than one).

    Each box is scored in O(1) from integral images: the same counts as
    :func:`~somtorch.tasks.reduction.reduce_map` and :func:`~somtorch.tasks.scoring.score_reduction`
    of that box alone.

    Shape:
        ``object_mask``, ``valid`` ``(H, W)`` bool.
    """
    useful = _useful_box(object_mask, valid, x_opt, tolerance_px=tolerance_px, tolerance_frac=tolerance_frac,
                         tolerance_image=tolerance_image, useful_factor=useful_factor)
    if useful is None:
        return 0
    return sum(_holds_useful(m, useful) for m in members)


def _holds_useful(member: Any, useful: Any) -> bool:
    """Whether one of ``member``'s kept areas or of the areas its grouping formed has a box that
    ``useful`` (a :func:`_useful_box` test) counts."""
    return any(useful(a.box) for a in list(member.kept) + list(member.areas))


def single_box_hit(boxes: list[tuple[int, int, int, int]], object_mask: torch.Tensor, valid: torch.Tensor,
                   x_opt: float, *, tolerance_px: float, tolerance_frac: float, tolerance_image: float,
                   useful_factor: float = USEFUL_FACTOR) -> bool:
    """Whether one of ``boxes`` (``(x0, y0, x1, y1)``, inclusive) alone — with the reduction's
    tolerance — is a useful hit: :func:`selection_ceiling` for a method that returns ranked boxes (a
    task baseline's every component, not only the first it keeps).

    Shape:
        ``object_mask``, ``valid`` ``(H, W)`` bool.
    """
    useful = _useful_box(object_mask, valid, x_opt, tolerance_px=tolerance_px, tolerance_frac=tolerance_frac,
                         tolerance_image=tolerance_image, useful_factor=useful_factor)
    return useful is not None and any(useful(tuple(b)) for b in boxes)


#: The reasons :func:`selection_gap` tells apart, in the order it checks them.
GAP_REASONS = ("kept, with further boxes", "kept, its box changed", "over the keep budget",
               "refused by a check", "not tried", "beneath the support", "behind its surroundings",
               "below the max_areas best")


def selection_gap(members: list, object_mask: torch.Tensor, valid: torch.Tensor, x_opt: float, *,
                  tolerance_px: float, tolerance_frac: float, tolerance_image: float,
                  useful_factor: float = USEFUL_FACTOR) -> dict[str, int]:
    """Why the runs that :func:`selection_ceiling` counts and that still missed did miss: per run,
    what became of its best-ranked area whose box alone would have been a useful hit, from the
    member's :class:`~somtorch.tasks.candidates.Candidate` verdicts (:data:`GAP_REASONS`): kept, but with
    further boxes that cost the reduction; kept, but its box changed (``merge`` grew it, the refinement
    cut it, the parts split it); over the keep budget; refused by the purity or solidity check; not
    tried (``max_areas`` kept already, or its segments joined to an area kept before); beneath a
    verified support; or no candidate at all: behind its surroundings (contrast < 0) or below the
    ``max_areas`` best. The counts sum to the missed runs that had such an area.

    Shape:
        ``object_mask``, ``valid`` ``(H, W)`` bool.
    """
    useful = _useful_box(object_mask, valid, x_opt, tolerance_px=tolerance_px, tolerance_frac=tolerance_frac,
                         tolerance_image=tolerance_image, useful_factor=useful_factor)
    counts = dict.fromkeys(GAP_REASONS, 0)
    if useful is None:
        return counts
    for m in members:
        hit = m.score is not None and m.score.useful_hit
        if not hit and any(useful(a.box) for a in list(m.kept) + list(m.areas)):
            counts[_gap_reason(m, useful)] += 1
    return counts


def _gap_reason(member, useful) -> str:
    """The :data:`GAP_REASONS` entry of a missed run that had a useful single area
    (:func:`selection_gap`)."""
    if any(useful(a.box) for a in member.kept):
        return "kept, with further boxes"
    reasons = {"kept": "kept, its box changed", "refused": "refused by a check",
               "skipped": "over the keep budget", "not tried": "not tried", "left out": "beneath the support"}
    for c in member.candidates:
        if useful(c.area.box):
            return reasons[c.outcome]
    area = next((a for a in member.areas if useful(a.box)), None)
    return "behind its surroundings" if area is not None and area.contrast < 0 else "below the max_areas best"


def _useful_box(object_mask: torch.Tensor, valid: torch.Tensor, x_opt: float, *, tolerance_px: float,
                tolerance_frac: float, tolerance_image: float, useful_factor: float):
    """A test ``box -> bool``: that box alone, with the reduction's tolerance, is a useful hit (O(1)
    per box from integral images); None where the object or the map has no valid pixel."""
    obj = object_mask & valid
    n_obj, n_valid = int(obj.sum()), int(valid.sum())
    if n_obj == 0 or n_valid == 0:
        return None
    iv, io = valid_integral(valid), valid_integral(obj)
    shape = tuple(valid.shape)

    def useful(box: tuple[int, int, int, int]) -> bool:
        if box[2] < box[0] or box[3] < box[1]:
            return False
        b = expand_box(box, shape, tolerance_px=tolerance_px, tolerance_frac=tolerance_frac,
                       tolerance_image=tolerance_image)
        reduction = 100.0 * (1.0 - box_count(iv, b) / n_valid)
        return box_count(io, b) / n_obj >= IDENTIFIED and reduction >= useful_factor * x_opt

    return useful


def _object_segments(labels: torch.Tensor, obj: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(pixels per segment, object pixels per segment, segments mostly on the object)``, each
    ``(K,)``, of one label map ``(H, W)`` (−1 = no segment) and an object mask."""
    k = max(int(labels.max()) + 1, 1) if labels.numel() else 1
    lab = torch.where(labels >= 0, labels, k).reshape(-1).long()  # unsegmented pixels in bin k, dropped
    cnt = torch.bincount(lab, minlength=k + 1)[:k]  # pixels per segment
    hit = torch.bincount(lab, weights=obj.reshape(-1).double(), minlength=k + 1)[:k].long()  # object pixels
    return cnt, hit, hit * 2 > cnt


def grouping_ceiling(labels: torch.Tensor, object_mask: torch.Tensor, valid: torch.Tensor, x_opt: float, *,
                     tolerance_px: float, tolerance_frac: float, tolerance_image: float,
                     members: list | None = None, useful_factor: float = USEFUL_FACTOR) -> int:
    """How many members of ``labels`` ``(E, H, W)`` (segment per pixel, −1 = none) hold a useful hit
    in a grouping of their segments: the box of the segments lying mostly on the object (more than
    half of their pixels; the rule of :func:`segment_f1`), with the reduction's tolerance, is a
    useful hit — or, given the pipeline's ``members`` (one per label map), one of the areas its
    grouping formed is (:func:`selection_ceiling`). An oracle's grouping of the same segments beside
    the step's own: a run counted here and not by :func:`selection_ceiling` lost the object in the
    grouping (linked to other things, or split), not in the segmentation. (The oracle's box is not
    refined, so it can miss where the step's refined box does: hence the step's own areas count too.)

    Shape:
        ``labels`` ``(E, H, W)``; ``object_mask``, ``valid`` ``(H, W)`` bool.
    """
    useful = _useful_box(object_mask, valid, x_opt, tolerance_px=tolerance_px, tolerance_frac=tolerance_frac,
                         tolerance_image=tolerance_image, useful_factor=useful_factor)
    if useful is None:
        return 0
    if members is not None and len(members) != len(labels):
        raise ValueError(f"grouping_ceiling: {len(members)} members for {len(labels)} label maps")
    obj = object_mask & valid
    n = 0
    for e, lab in enumerate(labels):
        if members is not None and _holds_useful(members[e], useful):
            n += 1
            continue
        _, _, major = _object_segments(lab, obj)
        on = (lab >= 0) & major[lab.long().clamp_min(0)] & valid
        ys, xs = on.nonzero(as_tuple=True)
        n += bool(ys.numel()) and useful((int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())))
    return n


def segment_f1(labels, obj) -> tuple[float, float, float]:
    """Segmentation precision against the object mask: the union of the segments whose pixels are
    mostly object pixels, scored as precision / recall / F1 of the object's valid pixels. Finer
    segmentations follow the object's outline more closely (the paper's Fig. 13)."""
    cnt, hit, major = _object_segments(labels, obj)  # major: segments mostly on the object
    tp = int(hit[major].sum())  # object pixels in those segments
    p = tp / max(int(cnt[major].sum()), 1)
    r = tp / max(int(hit.sum()), 1)
    return p, r, (2 * p * r / (p + r) if p + r > 0 else 0.0)


def run_records(scene, result, obj_mask, per_run_s: list[float] | None) -> dict[str, list]:
    """Per-run values of one pipeline result (one entry per member)."""
    runs: dict[str, list] = {k: [] for k in (
        "seed", "identified_fraction", "identified_100", "identified_95", "useful_hit", "reduction_union",
        "reduction_crops", "kept_areas", "area_px", "area_frac", "area_precision", "segment_precision",
        "segment_recall", "segment_f1", "n_areas", "quantization_error", "topographic_error", "runtime_s",
        "no_object", "all_objects_hit", "ground_object_frac")}
    everything = all_objects(scene) if obj_mask is not None else None
    ground_frac = ground_object_share(result.ground, scene) if obj_mask is not None else None
    t = result.timings
    e_n = len(result.members)
    shared = sum(v for k, v in t.items() if k not in ("objects", "reduction")) / e_n
    own = (t.get("objects", 0.0) + t.get("reduction", 0.0)) / e_n
    for e, m in enumerate(result.members):
        runs["seed"].append(m.seed)
        runs["n_areas"].append(len(m.areas))
        runs["kept_areas"].append(len(m.kept))
        area_mask = torch.zeros_like(scene.valid)
        for a in m.kept:
            area_mask |= a.mask(result.labels[e])
        px = int(area_mask.sum())
        runs["area_px"].append(px)
        runs["area_frac"].append(px / max(scene.n_valid, 1))
        runs["reduction_union"].append(m.reduction.reduction_union)
        runs["reduction_crops"].append(m.reduction.reduction_crops)
        q, te = float(result.quantization_error[e]), float(result.topographic_error[e])
        runs["quantization_error"].append(q if q == q else None)
        runs["topographic_error"].append(te if te == te else None)
        runs["runtime_s"].append(per_run_s[e] if per_run_s is not None else shared + own)
        runs["no_object"].append(m.no_object)
        if obj_mask is not None:
            s = m.score
            obj = obj_mask & scene.valid
            runs["identified_fraction"].append(s.identified_fraction)
            runs["identified_100"].append(s.identified_100)
            runs["identified_95"].append(s.identified_95)
            runs["useful_hit"].append(s.useful_hit)
            runs["area_precision"].append(int((area_mask & obj).sum()) / px if px else 0.0)
            p, r, f1 = segment_f1(result.labels[e], obj)
            runs["segment_precision"].append(p)
            runs["segment_recall"].append(r)
            runs["segment_f1"].append(f1)
            runs["all_objects_hit"].append(everything.hit(m.reduction) if everything is not None else False)
            runs["ground_object_frac"].append(ground_frac)
    return {k: v for k, v in runs.items() if v}


def merge_runs(parts: list[dict[str, list]]) -> dict[str, list]:
    """Concatenate the per-run lists of several parts (e.g. scenes or workers) key by key."""
    out: dict[str, list] = {}
    for p in parts:
        for k, v in p.items():
            out.setdefault(k, []).extend(v)
    return out


def summarize_runs(runs: dict[str, list], x_opt: float | None) -> dict[str, Any]:
    """The Table 1 / Table 2 numbers of one job from its per-run values."""

    n = len(runs["seed"])
    out: dict[str, Any] = {"runs": n, "reduction_all": summary_stats(runs["reduction_union"]),
                           "runtime_s": summary_stats(runs["runtime_s"]), "area_frac": summary_stats(runs["area_frac"])}
    if "identified_fraction" not in runs:
        return out
    id100, id95, useful = runs["identified_100"], runs["identified_95"], runs["useful_hit"]
    pick = lambda key, flags: [v for v, f in zip(runs[key], flags) if f]  # noqa: E731
    tradeoff = [f * max(0.0, min(1.0, r / x_opt)) if x_opt else 0.0
                for f, r in zip(id95, runs["reduction_union"])]
    out.update({
        "identified_100": int(sum(id100)), "identified_95": int(sum(id95)), "useful_hits": int(sum(useful)),
        "x_opt": x_opt,
        "mean_identified_fraction": float(sum(runs["identified_fraction"]) / n),
        # Table 2: over the runs with complete identification (the paper), and over the >= 95 % runs
        "reduction_complete": summary_stats(pick("reduction_union", id100)),
        "reduction_crops_complete": summary_stats(pick("reduction_crops", id100)),
        "reduction_95": summary_stats(pick("reduction_union", id95)),
        "reduction_crops_95": summary_stats(pick("reduction_crops", id95)),
        "segment_f1": summary_stats(runs["segment_f1"]), "area_precision": summary_stats(runs["area_precision"]),
        # in [0, 1]: mean over runs of [>= 95 % identified] * min(1, reduction / x_opt) (Optuna's objective)
        "tradeoff": float(sum(tradeoff) / n),
    })
    if "all_objects_hit" in runs:
        out["all_objects_hits"] = int(sum(runs["all_objects_hit"]))
        out["ground_object_frac"] = runs["ground_object_frac"][0]
    if "no_object" in runs:
        out["no_object"] = int(sum(runs["no_object"]))
    return out


def per_object_scores(scene, results: list) -> dict[str, Any]:
    """Per labelled object of ``scene`` (with valid pixels): its name, whether it is main, and how many of the
    runs in ``results`` identified it."""
    out = {}
    for info in scene.object_info:
        mask = scene.object_mask(info.id)
        if not bool((mask & scene.valid).any()):
            continue
        s = [score_reduction(m.reduction, mask, scene.valid) for r in results for m in r.members]
        out[str(info.id)] = {"name": info.name, "main": info.main, "identified_95": sum(x.identified_95 for x in s),
                             "identified_100": sum(x.identified_100 for x in s),
                             "mean_identified_fraction": sum(x.identified_fraction for x in s) / len(s),
                             "x_opt": s[0].x_opt}
    return out


