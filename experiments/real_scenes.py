"""``python -m experiments.real_scenes``: the pipeline on a list of named scenes, scored.

The frames come from the dataset registry (``conf/datasets.yaml``): ``datasets=`` and ``frames=``
select (default: the real datasets). Each frame is run with ``ensemble`` seeds trained at once.

* A scene with a mask is scored: Table 1 counts, useful and all-objects hits, fail-safe runs,
  every labelled object separately.
* A scene without a mask cannot be scored; what is counted is how often the kept area is junk the
  checks are meant to reject — box purity or relative solidity below ``junk_bound``.

Writes ``metrics.json`` (schema ``somtorch.scenes/1``: one row per scene, the resolved config)
and ``results.md`` into the Hydra run folder, both staged and moved in only when every scene ran.

    python -m experiments.real_scenes                                  # the real datasets, 20 runs
    python -m experiments.real_scenes 'frames=[kitti_est,motorcycle_q_sgbm,eth3d_terrace_sgbm,flyingthings3d_sgbm]'
    python -m experiments.real_scenes 'datasets=[oakd]' objects.min_solidity=0
    python -m experiments.real_scenes +preset=paper
    python -m experiments.real_scenes 'methods=[som,plane_components,uv_disparity,dsw]'   # task baselines beside it

``methods``: ``som`` is the configured pipeline (any ``method=`` segmenter); every other name is a
task baseline of the registry :mod:`somtorch.tasks.baselines` (``uv_disparity``, ``dsw``,
``plane_components``, …: one run per scene; one that needs a metric camera, such as ``dsw``, is
skipped where the scene has none), scored the same way. Every
scored row also carries the salient-object metrics (F-measure, MAE, S-measure of the kept mask
against the union of the labelled objects, :mod:`somtorch.saliency_metrics`), means over the runs.
"""

from __future__ import annotations

if __name__ == "__main__":  # signals and --help answered before the heavy imports (torch, Hydra)
    from .entry import start

    start("real_scenes")

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from . import CONF
from .datasets import frames, load_frame
from .schema import RunConfig

# absolute, so that the console script and python -m find the same configs from any directory
CONF_DIR = str(CONF)
SCHEMA = "somtorch.scenes/1"
log = logging.getLogger("somtorch.real_scenes")


@dataclass
class ScenesConfig(RunConfig):
    """The pipeline config plus which frames of the registry: ``datasets`` (None = the real ones)
    and ``frames`` (names; None = every frame of those datasets)."""

    datasets: Optional[list[str]] = None
    frames: Optional[list[str]] = None
    junk_bound: float = 0.25
    methods: list[str] = field(default_factory=lambda: ["som"])


ConfigStore.instance().store(name="real_scenes_schema", node=ScenesConfig)


def _median(values: list[float]) -> float | None:
    import numpy as np

    return float(np.median(values)) if values else None


def score_scene(scene: Any, members: list, cfg: ScenesConfig) -> dict[str, Any]:
    """One row: scores for a masked scene, junk counts for an unlabelled one."""
    from somtorch.evaluation import all_objects, summary_stats
    from somtorch.tasks.scoring import score_reduction

    found = [m for m in members if not m.no_object and m.kept]
    row: dict[str, Any] = {"runs": len(members), "no_object": sum(bool(m.no_object) for m in members),
                           "kept_areas_mean": sum(len(m.kept) for m in members) / len(members)}
    purity = [m.kept[0].purity for m in found if m.kept[0].purity is not None]
    solid = [m.kept[0].solidity_rel for m in found if m.kept[0].solidity_rel is not None]
    row.update({"low_purity": sum(p < cfg.junk_bound for p in purity),
                "low_solidity": sum(s < cfg.junk_bound for s in solid),
                "median_purity": _median(purity), "median_solidity": _median(solid)})
    if scene.objects is None:
        return row
    scores = [m.score for m in members]
    target = all_objects(scene)
    row.update({
        "identified_100": sum(s.identified_100 for s in scores), "identified_95": sum(s.identified_95 for s in scores),
        "useful_hits": sum(s.useful_hit for s in scores),
        "all_objects_hits": sum(target.hit(m.reduction) for m in members),
        "mean_identified_fraction": sum(s.identified_fraction for s in scores) / len(scores),
        "reduction_95": summary_stats([s.reduction_union for s in scores if s.identified_95]),
        "x_opt": scores[0].x_opt, "per_object": {},
        "saliency": _saliency(scene, members),
    })
    for info in scene.object_info:
        mask = scene.object_mask(info.id)
        if not bool((mask & scene.valid).any()):
            continue
        s_obj = [score_reduction(m.reduction, mask, scene.valid) for m in members]
        row["per_object"][str(info.id)] = {"name": info.name, "identified_95": sum(s.identified_95 for s in s_obj),
                                           "mean_identified_fraction": sum(s.identified_fraction for s in s_obj)
                                           / len(s_obj)}
    return row


def _saliency(scene: Any, members: list) -> dict[str, float]:
    """Mean F-measure / MAE / S-measure of the kept masks against the union of the objects."""
    from somtorch.saliency_metrics import saliency_scores

    union = scene.objects > 0
    per = [saliency_scores(m.reduction.mask, union) for m in members]
    return {k: sum(p[k] for p in per) / len(per) for k in per[0]}


@dataclass
class BaselineRun:
    """The one run of a deterministic baseline, shaped like a pipeline member for the scorers."""

    reduction: Any
    score: Any
    kept: list = field(default_factory=list)
    no_object: bool = False
    candidates: list = field(default_factory=list)  # every box it found, ranked (it keeps the first)


def check_methods(methods: list[str], what: str = "methods") -> None:
    """Raise a one-line error unless every name is ``som`` or a registered task baseline
    (:data:`somtorch.tasks.baselines.TASK_BASELINES`; the message lists them)."""
    from somtorch.tasks.baselines import task_baseline_names

    known = ["som", *task_baseline_names()] if what == "methods" else task_baseline_names()
    unknown = [m for m in methods if m not in known]
    if unknown:
        raise ValueError(f"{what}={list(methods)}: unknown {unknown}; choose from {', '.join(known)}")


def run_baseline(name: str, scene: Any, reduction: Any, left_out: str | None = None) -> list[BaselineRun] | None:
    """The task baseline ``name`` (:mod:`somtorch.tasks.baselines`) on ``scene``: its first box, reduced
    with the pipeline's tolerance (``reduction``, a ReductionConfig), scored on the main object (every
    box it found in ``candidates``, for the ceiling of a perfect choice among them). None
    where it does not apply (it needs a metric camera and the scene has none). Nothing found: the
    whole map is kept and the run is flagged ``no_object``, as the pipeline's fail-safe does.
    ``left_out``: a generator camera whose frames a trained baseline must not have seen (its
    leave-one-dataset-out fold, :meth:`~somtorch.tasks.baselines.TaskBaseline.without`)."""
    from somtorch.tasks.baselines import get_task_baseline
    from somtorch.tasks.reduction import reduce_map
    from somtorch.tasks.scoring import score_reduction

    baseline = get_task_baseline(name).without(left_out)
    if not baseline.applies(scene.camera):
        return None
    found = baseline(scene.disparity, scene.valid, scene.camera)
    boxes = [found[0].box] if found else []
    if not boxes:  # nothing detected: keep the whole map, as the pipeline's fail-safe does
        ys, xs = scene.valid.nonzero(as_tuple=True)
        boxes = [(int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))]
    red = reduce_map(boxes, scene.valid, tolerance_px=reduction.tolerance_px, tolerance_frac=reduction.tolerance_frac,
                     tolerance_image=reduction.tolerance_image)
    score = score_reduction(red, scene.main_object_mask, scene.valid) if scene.main_object_mask is not None else None
    return [BaselineRun(red, score, no_object=not found, candidates=[o.box for o in found])]


def evaluate(cfg: ScenesConfig) -> dict[str, Any]:
    """Run every scene (all files read first); returns the content of ``metrics.json``."""
    from somtorch.pipeline import run_pipeline
    from somtorch.tasks.baselines import get_task_baseline

    specs = frames(cfg.datasets, cfg.frames, real=True if cfg.datasets is None and cfg.frames is None else None)
    data_dir = Path(to_absolute_path(cfg.paths.data_dir))
    if not cfg.methods:
        raise ValueError("methods=[]: name at least one method (som or a task baseline)")
    check_methods(cfg.methods)
    scenes = [load_frame(s, data_dir) for s in specs]  # every file checked before any training
    from somtorch.pipeline import resource_estimate

    from .cli import announce, progress_bar

    som_s = sum(resource_estimate(scene, cfg).seconds for scene in scenes) if "som" in cfg.methods else 0.0
    announce("scenes", f"{len(scenes)} scenes x {len(cfg.methods)} method(s)", som_s)
    bar = progress_bar(len(scenes) * len(cfg.methods), "scenes", "run")
    rows = []
    for spec, scene in zip(specs, scenes):
        for method in cfg.methods:
            t0 = time.perf_counter()
            head = {"scene": spec.name, "dataset": spec.dataset, "method": method, "folder": spec.folder, "disparity": spec.disparity,
                    "junk": spec.junk, "mode": "OR" if cfg.features.train_stride > 1 else "NOR"}
            if method == "som":
                res = run_pipeline(scene, cfg, metrics=False)
                row = {**head, "grid": f"{cfg.som.rows}x{cfg.som.cols}", "train_px": len(res.train_features),
                       "ground_found": res.ground is not None, **score_scene(scene, res.members, cfg),
                       "timings_ms": {k: 1e3 * v for k, v in res.timings.items()}}
            else:
                runs = run_baseline(method, scene, cfg.reduction)
                if runs is None:
                    log.info("%s: %s skipped (no metric camera)", spec.name, method)
                    bar.update()
                    continue
                row = {**head, "mode": "all pixels", "deterministic": get_task_baseline(method).deterministic,
                       **score_scene(scene, runs, cfg)}
            row["wall_s"] = time.perf_counter() - t0
            row["group"], row["real"] = spec.group, spec.real
            rows.append(row)
            bar.update()
            log.info("%s [%s]: %s", spec.name, method, ", ".join(
                f"{k} {row[k]}" for k in ("useful_hits", "all_objects_hits", "low_solidity", "no_object") if k in row))
    bar.close()
    return {"schema": SCHEMA, "label": cfg.label, "datasets": cfg.datasets, "rows": rows,
            "summary": macro_summary(rows), "config": OmegaConf.to_container(OmegaConf.structured(cfg))}


def macro_summary(rows: list[dict[str, Any]], n_boot: int = 2000) -> dict[str, Any]:
    """Per method: the useful-hit rate per dataset and its macro average over the real datasets with
    the protocol's 95 % bootstrap interval (:class:`experiments.protocol.FrameTable`: frames weighted
    through their scenes, the scenes resampled), over the masked frames every method scored."""
    import numpy as np

    from .protocol import FrameTable

    out: dict[str, Any] = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        got = [r for r in rows if r["method"] == method and "useful_hits" in r]
        if not got:
            continue
        table = FrameTable([r["dataset"] for r in got], [r["group"] for r in got], [r["real"] for r in got],
                           n_boot=n_boot)
        rate = np.array([r["useful_hits"] / r["runs"] for r in got])
        point, lo, hi = table.macro(rate, real_only=True)
        out[method] = {"frames": len(got), "datasets": table.per_dataset(rate),
                       "macro_real": {"useful": point, "lo": lo, "hi": hi}}
    return out


def to_markdown(results: dict[str, Any]) -> str:
    """The tables: masked scenes (scores, per object) and unlabelled ones (junk counts)."""
    masked = [r for r in results["rows"] if "useful_hits" in r]
    other = [r for r in results["rows"] if "useful_hits" not in r]
    lines = []
    if results.get("summary"):
        lines += ["| method | frames | macro useful, real [95 % interval] | per dataset |", "|---|---|---|---|"]
        for method, m in results["summary"].items():
            mr = m["macro_real"]
            per = ", ".join(f"{d} {100 * v:.1f}" for d, v in m["datasets"].items())
            lines.append(f"| {results['label'] if method == 'som' else method} | {m['frames']} | "
                         f"{100 * mr['useful']:.1f} [{100 * mr['lo']:.1f}, {100 * mr['hi']:.1f}] | {per} |")
        lines.append("")
    if masked:
        lines += ["| scene | method | mode | runs | ≥95 % identified | 100 % | useful hits | all-objects hits | "
                  "no object | mean reduction (≥95 % runs) | x_opt | F-measure | MAE | S-measure |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in masked:
            red = r["reduction_95"]["mean"]
            method = results["label"] if r.get("method", "som") == "som" else r["method"]
            sal = r["saliency"]
            lines.append(f"| {r['scene']} | {method} | {r['mode']} | {r['runs']} | {r['identified_95']} | "
                         f"{r['identified_100']} | {r['useful_hits']} | {r['all_objects_hits']} | {r['no_object']} | "
                         f"{'–' if red is None else f'{red:.1f} %'} | {r['x_opt']:.1f} % | {sal['f_measure']:.3f} | "
                         f"{sal['mae']:.3f} | {sal['s_measure']:.3f} |")
        lines += ["", "| scene | object | runs with ≥95 % identified | mean identified fraction |", "|---|---|---|---|"]
        for r in masked:
            for oid, o in r["per_object"].items():
                if r.get("method", "som") != "som":
                    continue
                lines.append(f"| {r['scene']} | {oid}: {o['name']} | {o['identified_95']}/{r['runs']} | "
                             f"{o['mean_identified_fraction']:.2f} |")
    if other:
        b = results["config"]["junk_bound"]
        lines += ["", f"| scene (no mask) | runs | purity < {b} | solidity < {b} | no object | median purity | "
                      "median solidity |", "|---|---|---|---|---|---|---|"]
        for r in other:
            mp, ms = r["median_purity"], r["median_solidity"]
            lines.append(f"| {r['scene']} | {r['runs']} | {r['low_purity']} | {r['low_solidity']} | {r['no_object']} | "
                         f"{'–' if mp is None else f'{mp:.2f}'} | {'–' if ms is None else f'{ms:.2f}'} |")
    return "\n".join(lines) + "\n"


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="real_scenes")
def main(dcfg: DictConfig) -> dict:
    from .cli import configure_threads, interruptible, marked_if_failed

    configure_threads()
    from .schema import one_line_errors, to_config
    from somtorch.atomic import write_staged

    out = Path(HydraConfig.get().runtime.output_dir)
    with marked_if_failed(out), interruptible(out), one_line_errors(log):  # Ctrl-C / kill: one line, FAILED, 130 / 143
        cfg: ScenesConfig = to_config(dcfg)
        results = evaluate(cfg)
    write_staged(out, {"results.md": to_markdown(results).encode(), "metrics.json": results})
    log.info("tables in %s", out / "results.md")
    return results


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, ScenesConfig)


if __name__ == "__main__":
    cli()
