"""The task baselines in ``python -m experiments.validate`` (``baselines=``): one run per frame
(they are deterministic), scored like the SOM's defaults and reported beside them, per dataset and
as the real / all macro averages (split from :mod:`experiments.validate`). A trained baseline
(``learned``) runs, on each frame, the model of the frame's fold: trained without the generated
frames of the frame's camera (``FrameSpec.camera``), so a left-out dataset's rig is never trained on."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

__all__ = ["baseline_counts", "baselines_markdown", "check_trained", "score_baselines", "summarize_baselines"]

log = logging.getLogger("somtorch.validate")


def check_trained(names: list[str], specs: list[Any]) -> None:
    """Before any work: every fold model a trained baseline will need on ``specs`` loads (a function
    with a ``model()`` loader, like ``learned``'s); a missing one is the loader's one-line error that
    names the command training it."""
    from somtorch.tasks.baselines import get_task_baseline

    for name in names:
        entry = get_task_baseline(name)
        if entry.left_out is None:
            continue
        for cam in sorted({s.camera for s in specs}, key=str):  # None: a frame of no generator camera
            load = getattr(entry.without(cam).fn, "model", None)
            if callable(load):
                load()


def score_baselines(caches: list[Any], names: list[str], reduction: Any,
                    keys: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """``{frame: {baseline: counts}}`` for every frame cache (``experiments.validate_cache.SceneCache``),
    keyed by ``keys`` (default: the frames' names; one frame on several grids has a key per grid);
    a baseline that does not apply to a frame (no metric camera) gets None."""
    keys = keys or [c.spec.name for c in caches]
    if not names:  # nothing to run: no frame read, no log line
        return {key: {} for key in keys}
    out: dict[str, dict[str, Any]] = {}
    for c, key in zip(caches, keys):
        # (the scene is not kept: 352 frames' maps would stay in memory)
        out[key] = per = baseline_counts(c.fresh_scene(), names, reduction, c.spec.camera)
        log.info("%s: baselines %s", key, ", ".join(
            f"{n} {'–' if p is None else 'useful' if p['useful_hits'] else 'miss'}" for n, p in per.items()))
    return out


def baseline_counts(scene: Any, names: list[str], reduction: Any, camera: str | None) -> dict[str, Any]:
    """``{baseline: counts}`` of one run of each baseline of ``names`` on ``scene`` (None where it
    does not apply, e.g. no metric camera); ``camera``: the frame's generator camera (a trained
    baseline runs the model of its fold)."""
    from somtorch.evaluation import all_objects, single_box_hit
    from somtorch.saliency_metrics import saliency_scores

    from .real_scenes import run_baseline

    per: dict[str, Any] = {}
    for name in names:
        t0 = time.perf_counter()
        runs = run_baseline(name, scene, reduction, left_out=camera)
        if runs is None:
            per[name] = None
            continue
        (r,) = runs
        target = all_objects(scene)
        tol = {"tolerance_px": reduction.tolerance_px, "tolerance_frac": reduction.tolerance_frac,
               "tolerance_image": reduction.tolerance_image}
        per[name] = {"runs": 1, "useful_hits": int(r.score.useful_hit),
                     # one of its boxes alone useful: the ceiling of a perfect choice among them
                     "best_box_hits": int(single_box_hit(r.candidates, scene.main_object_mask, scene.valid,
                                                         r.score.x_opt, **tol)),
                     "identified_95": int(r.score.identified_95),
                     "all_objects_hits": int(target.hit(r.reduction)) if target is not None else 0,
                     "no_object": int(r.no_object), "reduction": r.score.reduction_union,
                     "saliency": saliency_scores(r.reduction.mask, scene.objects > 0),
                     "wall_s": time.perf_counter() - t0}
    return per


def summarize_baselines(table: Any, rows: list[dict[str, Any]], names: list[str]) -> dict[str, Any]:
    """Per baseline: per dataset the useful / all-objects rates and mean F / MAE / S, and the macro
    averages (real, all) with the protocol's frame weighting (:class:`experiments.protocol.FrameTable`).
    A dataset whose frames a baseline skipped (no metric camera) reads NaN. Beside them two ceilings:
    ``best_box_hits``, the runs in which one of the baseline's boxes alone would be useful, and, where
    the rows carry the SOM's selection ceiling, ``either_best``: the runs in which one SOM area or one
    baseline box would be (a perfect choice among both candidate sets; the baseline's boxes are the
    same in every run of a frame)."""
    out: dict[str, Any] = {}
    nan = float("nan")
    som_best = (np.array([r["default"]["best_area_hits"] / r["default"]["runs"] for r in rows])
                if all("best_area_hits" in r["default"] for r in rows) else None)
    for name in names:
        got = [r["baselines"][name] for r in rows]
        arr = {m: np.array([nan if g is None else g[m] / g["runs"] for g in got])
               for m in ("useful_hits", "all_objects_hits", "no_object", "best_box_hits")}
        if som_best is not None:
            arr["either_best"] = np.where(np.isnan(arr["best_box_hits"]), som_best,
                                          np.maximum(arr["best_box_hits"], som_best))
        sal = {k: np.array([nan if g is None else g["saliency"][k] for g in got])
               for k in ("f_measure", "mae", "s_measure")}
        per = {m: table.per_dataset(v) for m, v in {**arr, **sal}.items()}
        out[name] = {"datasets": {d: {m: per[m][d] for m in per} for d in table.names},
                     **{f"macro_{label}": {m: table.macro(v, real_only)[0] for m, v in arr.items()}
                        for label, real_only in (("real", True), ("all", False))}}
    return out


def _pct(x: float) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.1f}"


def _num(x: float, digits: int) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def baselines_markdown(report: dict[str, Any]) -> str:
    """The table of the task baselines beside the SOM's defaults (empty without baselines), with the
    ceilings of a perfect choice: among each method's own candidates, and among both."""
    base = report.get("baselines_summary") or {}
    if not base:
        return ""
    sm = report["summary"]
    out = ["", "Task baselines beside the SOM's defaults (one run per frame; % of frames, frames weighted as "
           "in the protocol; – = not applicable, e.g. no metric camera). *Best single box*: the runs in "
           "which one candidate alone (with the tolerance) would be a useful hit — a SOM area, or one of "
           "the baseline's ranked boxes (it keeps the first); *either*: one SOM area or one baseline box, "
           "the ceiling of a perfect choice among both candidate sets:", "",
           "| dataset | method | useful | best single box | either | all-obj | no object | F | MAE | S |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for d, r in sm["datasets"].items():
        out.append(f"| {d} | SOM defaults | {_pct(r['default_useful_hits'])} | "
                   f"{_pct(r.get('default_best_area_hits'))} | | {_pct(r['default_all_objects_hits'])} | "
                   f"| {_num(r.get('f_measure', float('nan')), 2)} | {_num(r.get('mae', float('nan')), 3)} | "
                   f"{_num(r.get('s_measure', float('nan')), 2)} |")
        for name, b in base.items():
            x = b["datasets"][d]
            out.append(f"| | {name} | {_pct(x['useful_hits'])} | {_pct(x['best_box_hits'])} | "
                       f"{_pct(x.get('either_best'))} | {_pct(x['all_objects_hits'])} | "
                       f"{_pct(x['no_object'])} | {_num(x['f_measure'], 2)} | {_num(x['mae'], 3)} | "
                       f"{_num(x['s_measure'], 2)} |")
    for label in ("real", "all"):
        m = sm[f"macro_{label}"]
        out.append(f"| **macro, {label}** | SOM defaults | {_pct(m['default_useful_hits'])} | "
                   f"{_pct(m.get('default_best_area_hits'))} | | "
                   f"{_pct(m['default_all_objects_hits'])} | | | | |")
        for name, b in base.items():
            x = b[f"macro_{label}"]
            out.append(f"| | {name} | {_pct(x['useful_hits'])} | {_pct(x['best_box_hits'])} | "
                       f"{_pct(x.get('either_best'))} | {_pct(x['all_objects_hits'])} | "
                       f"{_pct(x['no_object'])} | | | |")
    return "\n".join(out) + "\n"
