"""A study job that runs a task baseline instead of the pipeline (``task_baseline=plane_components``).

The baseline is run once (the registry's baselines are deterministic) and its ``metrics.json`` has
the study schema (``somtorch.study/1``), so ``python -m experiments.aggregate`` prints it in Tables 1
and 2 beside the paper and the SOM, named by the baseline (split from :mod:`experiments.study`).
Fields that only a SOM has (grid, segments, quantization error) read ``"–"`` / None; the
segmentation precision of a baseline is that of its kept mask against the object.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import torch

__all__ = ["baseline_job"]

log = logging.getLogger("somtorch.study")


def _records(scene: Any, run: Any, obj_mask: torch.Tensor | None, seconds: float) -> dict[str, list]:
    """The per-run values of :func:`somtorch.evaluation.run_records` for the baseline's one run."""
    from somtorch.evaluation import all_objects

    kept = run.reduction.mask & scene.valid
    px = int(kept.sum())
    runs: dict[str, list] = {"seed": [0], "kept_areas": [0 if run.no_object else 1], "n_areas": [None],
                             "area_px": [px], "area_frac": [px / max(scene.n_valid, 1)],
                             "reduction_union": [run.reduction.reduction_union],
                             "reduction_crops": [run.reduction.reduction_crops], "runtime_s": [seconds],
                             "no_object": [run.no_object], "quantization_error": [None], "topographic_error": [None]}
    if obj_mask is not None:
        s, obj = run.score, obj_mask & scene.valid
        tp = int((kept & obj).sum())
        prec, rec = (tp / px if px else 0.0), tp / max(int(obj.sum()), 1)
        everything = all_objects(scene)
        runs.update({"identified_fraction": [s.identified_fraction], "identified_100": [s.identified_100],
                     "identified_95": [s.identified_95], "useful_hit": [s.useful_hit], "area_precision": [prec],
                     "segment_precision": [prec], "segment_recall": [rec],
                     "segment_f1": [2 * prec * rec / (prec + rec) if prec + rec else 0.0],
                     "all_objects_hit": [everything.hit(run.reduction) if everything is not None else False],
                     "ground_object_frac": [None]})
    return runs


def baseline_job(cfg: Any, scene: Any, obj_mask: torch.Tensor | None, config: dict[str, Any], chash: str,
                 schema: str) -> dict[str, Any]:
    """The metrics of the study job ``cfg`` (a StudyConfig whose ``task_baseline`` is set) on ``scene``."""
    from somtorch.evaluation import summarize_runs
    from somtorch.tasks.scoring import score_reduction

    from .real_scenes import run_baseline

    t0 = time.perf_counter()
    got = run_baseline(cfg.task_baseline, scene, cfg.reduction)
    if got is None:
        raise ValueError(f"task_baseline={cfg.task_baseline!r} needs a metric camera; scene {scene.name!r} has none")
    (run,) = got
    if obj_mask is not None and obj_mask is not scene.main_object_mask:  # object_id= scores another object
        run.score = score_reduction(run.reduction, obj_mask, scene.valid)
    seconds = time.perf_counter() - t0
    runs = _records(scene, run, obj_mask, seconds)
    x_opt = run.score.x_opt if run.score is not None else None
    log.info("%s %s: useful %s, no object %s, %.2f s", scene.name, cfg.task_baseline,
             run.score.useful_hit if run.score is not None else "–", run.no_object, seconds)
    return {"schema": schema, "study": cfg.study, "config_hash": chash, "label": cfg.label,
            "method": cfg.task_baseline, "execution": "once", "mode": "all px", "grid": "–", "segments": None,
            "scene": {"name": cfg.data.name or scene.name, "height": scene.height, "width": scene.width,
                      "valid_pixels": scene.n_valid, "has_objects": scene.objects is not None,
                      "object_id": cfg.object_id, "source": scene.source},
            "pixels": {"train": 0, "segmented": scene.n_valid}, "ground_found": None,
            "runs": runs, "summary": summarize_runs(runs, x_opt), "per_object": {},
            "timings_s": {"baseline": seconds, "wall": seconds}, "timings_repeats_s": [{"baseline": seconds,
                                                                                      "wall": seconds}],
            "output_timings_s": {}, "config": config}
