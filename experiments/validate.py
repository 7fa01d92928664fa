"""``python -m experiments.validate``: leave-one-dataset-out validation of the object rule.

Every frame of the dataset registry (``conf/datasets.yaml``; ``datasets=`` / ``frames=`` select) is
run with ``ensemble`` seeds; each is scored with the defaults and with each value of ``grid`` (one
knob changed at a time, the same seeds: a paired comparison). The adoption rule of
:mod:`experiments.protocol` (the real-data macro average improves with a bootstrap interval that
excludes zero, neither reading drops, no dataset loses more than a stated margin) then decides:

* **in-sample** — the knobs adopted on every dataset, scored on the same frames (fitted);
* **left-out** — for each dataset in turn, the knobs adopted on all the *other* datasets, scored
  on it (what a dataset nobody tuned to can expect); reported per dataset and as the macro average
  over the real datasets beside the in-sample figure;
* per knob, its verdict: **adopt** a value, **remove** the check (its neutral value, ``neutral``,
  is non-inferior: switching it off costs nothing the protocol can see), or **keep** it.

Segmentations are computed once per frame and upstream setting (features, ground, SOM, training),
so a grid of object-step knobs costs one object step per value.

    python -m experiments.validate                                    # the grid of conf/validate.yaml
    python -m experiments.validate 'datasets=[oakd,kitti2015]' ensemble=5
    python -m experiments.validate '~grid' '+grid={objects.merge: [0.5, 1.0]}'

Writes ``validate.json`` (every per-frame figure, every decision, every fold's choice) and
``validate.md`` into the Hydra run folder.
"""

from __future__ import annotations

if __name__ == "__main__":  # signals and --help answered before the heavy imports (torch, Hydra)
    from .entry import start

    start("validate")

import json
import logging
import math
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Optional

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig

from . import CONF
from .schema import RunConfig, register
from .validate_cache import (UPSTREAM, GridCache, Protocol, SceneCache, _default_of, _key, _overrides,
                             frames_progress, merge_scores, scorable, score_caches, score_missing)
from .validate_fresh import (SHIFT_KEY, check_shifts, grid_name, per_grid_macros, score_fresh_seeds,
                             shift_checked, shifted_frame)
from .validate_report import gallery, summarize, to_markdown, verdict

CONF_DIR = str(CONF)
log = logging.getLogger("somtorch.validate")


@dataclass
class ValidateConfig(RunConfig):
    """The pipeline config plus which frames, the grid of values tried and the adoption rule's margins.

    Attributes:
        datasets: the registry's datasets scored (conf/datasets.yaml; None = all).
        frames: single frames of the registry scored instead (None = every frame of the datasets).
        grid: ``{"group.field": [values]}`` tried instead of each default, one knob at a time.
        neutral: ``{"group.field": value}`` that switches a check off; always tried (a removal candidate).
        gallery: a folder: one picture of member 0 per frame (defaults); None = no pictures.
        n_boot: bootstrap resamples of the adoption rule's interval.
        workers: frames scored in this many processes (1 = in this one).
        loss_margin: the largest drop of one dataset's hit rate a change may cost.
        ni_margin: non-inferiority margin of a removal (and of the all-objects reading).
        transforms: robustness checks: every frame transformed (``flip``, ``resample:F``, ``noise:S``,
            ``quantize:Q``, ``scale:F``, ``bowl:P``, ``blotch:S``, ``smear:S``, ``relief:F``, ``wide:F``,
            ``shift:N``, ``pole``, ``border``, ``specks``;
            experiments.scenes.add_junk) and scored with the defaults.
        baselines: task baselines (somtorch.tasks.baselines) scored beside the defaults, one run per frame.
        fresh_seeds: also score the defaults, and the in-sample choice where one is adopted, on the
            next ``ensemble`` seeds (:func:`score_fresh_seeds`; off: a quicker trial).
        fresh_shift: that second pass reads every frame on a pixel grid shifted by this many px
            further than the largest of ``frame_shifts`` (the ``shift:N`` transform: the strided
            steps read other pixels of the same scene, which the rules were not chosen on either);
            0 = the fresh seeds alone, on the last grid.
        frame_shifts: the pixel grids the protocol decides on: every frame read shifted by each of
            these many px (``shift:N``; 0 = as given), a candidate's runs summed over them, so that
            a choice is decided on the pixels of several grids at once (session 41; session 40
            found a real figure 4–5 points apart between grids 3–7 px apart). The gallery and the
            transforms read the first grid.
    """

    datasets: Optional[list[str]] = None
    frames: Optional[list[str]] = None
    grid: dict[str, list[Any]] = field(default_factory=dict)
    neutral: dict[str, Any] = field(default_factory=dict)
    gallery: Optional[str] = None  # a folder: one picture of member 0 per frame (defaults)
    n_boot: int = 2000
    workers: int = 2  # frames scored in this many processes (1 = in this one)
    scores_out: Optional[str] = None  # write the per-frame scores of every candidate here (JSON) ...
    resume: Optional[str] = None  # ... and read them back instead of scoring again
    loss_margin: float = 0.10  # the largest drop of one dataset's hit rate a change may cost
    ni_margin: float = 0.02  # non-inferiority margin of a removal (and of the all-objects reading)
    # robustness: every frame transformed (experiments.scenes.add_junk: "flip", "resample:F", "noise:S",
    # "bowl:P", "blotch:S", ...) and scored with the defaults, beside the frames as they are
    transforms: list[str] = field(default_factory=list)
    # task baselines scored beside the defaults (one run per frame; those that need no checkpoint)
    baselines: list[str] = field(default_factory=lambda: ["plane_components", "uv_disparity"])
    # the defaults (and an adopted choice) scored again on the next `ensemble` seeds: runs nothing was
    # chosen on (score_fresh_seeds); a choice is confirmed where it is adopted there too
    fresh_seeds: bool = True
    # ... each frame on a grid shifted this many px further than the last of frame_shifts (add_junk
    # "shift:N"; 3: a phase of the training grid (stride 10) and of the object step's (stride 2) that
    # neither 0 nor 5 reads; 0 = the fresh seeds alone)
    fresh_shift: int = 3
    # the pixel grids the protocol decides on: every frame shifted by each (add_junk "shift:N"; 0 = as
    # given), a candidate's runs summed over them
    frame_shifts: list[int] = field(default_factory=lambda: [0, 5])


def evaluate(cfg: ValidateConfig, runs_log: Path | None = None) -> dict[str, Any]:
    """Run the protocol of the module docstring; returns the JSON-ready report. ``runs_log``: the
    file the worker processes write their pipeline warnings into (:mod:`experiments.warning_log`)."""
    from somtorch import interrupt

    from .cli import announce
    from .datasets import frames, load_frame
    from .scenes import check_junk_kind

    from .real_scenes import check_methods

    for kind in cfg.transforms:  # before any work: a typo must not cost the whole protocol
        check_junk_kind(kind)
    shifts = check_shifts(cfg)
    check_methods(cfg.baselines, "baselines")
    specs = frames(cfg.datasets, cfg.frames)
    if not specs:
        raise ValueError(f"no frame selected (datasets={cfg.datasets}, frames={cfg.frames})")
    from .datasets import missing_corpus

    missing = missing_corpus(specs)  # a fresh clone: the generated frames are not there yet
    if missing is not None:
        raise FileNotFoundError(missing)
    from .validate_baselines import check_trained

    check_trained(cfg.baselines, specs)  # a trained baseline's fold models exist, before any work
    data_dir = Path(to_absolute_path(cfg.paths.data_dir))
    grid = {k: list(v) for k, v in cfg.grid.items()}
    for k, v in cfg.neutral.items():  # a knob's neutral value is always tried
        if k not in grid:
            raise ValueError(f"neutral: {k!r} is not a key of the grid ({sorted(grid)})")
        if v not in grid[k]:
            grid[k].append(v)
    base = cfg  # a ValidateConfig is a PipelineConfig: the extra fields do not reach the pipeline
    defaults = {k: _default_of(base, k) if "+" not in k else [_default_of(base, n) for n in k.split("+")]
                for k in grid}
    keys = [({}, True)] + [(_overrides(k, v, defaults), False) for k, values in grid.items() for v in values]
    specs = _scorable(specs, data_dir)  # every file read (and checked) before any training
    from .run import check_resources

    upstream = 1 + sum(len(v) for k, v in grid.items() if k.split(".")[0] in UPSTREAM)

    def jobs():  # one frame at a time: a segmentation per upstream setting, an object step per candidate
        for spec in specs:
            given = load_frame(spec, data_dir)  # (read again: _scorable keeps no map in memory)
            for shift in shifts:  # every grid checked before any work
                scene = shift_checked(given, spec, shift, "frame_shifts")
                yield scene, base, upstream
                yield scene, base, len(keys)
            if cfg.fresh_seeds:  # the defaults once more on the next seeds (score_fresh_seeds)
                yield shift_checked(given, spec, max(shifts) + cfg.fresh_shift, "fresh_shift"), base, 1

    on_more = f" x {len(shifts)} grids" if len(shifts) > 1 else ""
    what = f"{len(specs)} frames x {len(keys)} candidates{on_more}"
    est = check_resources(jobs(), cfg.resources, f"validation over {what}")
    announce("validate", what + (f", {cfg.workers} workers" if cfg.workers > 1 else ""),
             est.seconds / max(1, min(cfg.workers, len(specs))))
    t0 = time.perf_counter()
    resumed = json.loads(Path(cfg.resume).read_text()) if cfg.resume else {}
    if cfg.resume and resumed.get(SHIFT_KEY, [0]) != shifts:
        raise ValueError(f"resume={cfg.resume}: its scores were read with frame_shifts="
                         f"{resumed.get(SHIFT_KEY, [0])}, this run reads frame_shifts={shifts}")
    progress = frames_progress(len(specs) * len(shifts))
    on_grids = [SceneCache(s, None, base, loader=partial(shifted_frame, s, data_dir, shift))
                for s in specs for shift in shifts]  # frame by frame, each on every grid
    names = [grid_name(s.name, shift) for s in specs for shift in shifts]  # their keys in a scores file
    todo = []
    for i, c in enumerate(on_grids):
        c.scores = dict(resumed.get(names[i], {}))  # what an earlier run scored is not scored again
        if all(_key(ov) in c.scores for ov, _ in keys):
            progress.update(1)
        else:
            todo.append(i)
    missing = {i: [(ov, sal) for ov, sal in keys if _key(ov) not in on_grids[i].scores] for i in todo}
    interrupt.note(f"after {progress.n} of {len(on_grids)} frames")
    score_caches(on_grids, missing, cfg.workers, runs_log, progress)
    if cfg.scores_out:  # the per-frame scores, so that a later run can resume from them
        Path(cfg.scores_out).parent.mkdir(parents=True, exist_ok=True)
        out: dict[str, Any] = {n: c.scores for n, c in zip(names, on_grids)}
        if shifts != [0]:  # scores of shifted frames resume only a run on the same grids
            out[SHIFT_KEY] = shifts
        Path(cfg.scores_out).write_text(json.dumps(out))
    progress.close()
    caches = [GridCache(on_grids[i:i + len(shifts)]) for i in range(0, len(on_grids), len(shifts))]
    log.info("%d frames scored with %d candidates on %d grid(s) in %.0f s", len(caches), len(keys),
             len(shifts), time.perf_counter() - t0)
    proto = Protocol(caches, cfg, grid, defaults, runs_log)
    in_sample, in_sample_steps = proto.choose()
    score_missing(caches, in_sample, True, cfg.workers, runs_log)  # its saliency, in the workers
    # left-out: each dataset scored with the choice made on all the others
    folds = {}
    for d in proto.table.names:
        keep = [n for n in proto.table.names if n != d]
        choice, steps = proto.choose(proto.table.subset(keep)) if keep else ({}, [])
        folds[d] = {"choice": choice, "steps": steps}
    rows = []
    for c in caches:
        fold = folds[c.spec.dataset]["choice"]
        rows.append({"frame": c.spec.name, "dataset": c.spec.dataset, "real": c.spec.real, "group": c.spec.group,
                     "default": c.score({}), "in_sample": c.score(in_sample), "left_out": c.score(fold)})
    knobs = {}
    for k, values in grid.items():
        entries = []
        for v in values:
            ov = _overrides(k, v, defaults)
            if ov:
                entries.append({"value": v, "neutral": k in cfg.neutral and v == cfg.neutral[k],
                                **proto.decide(ov, {}).as_dict()})
        knobs[k] = {"default": defaults[k], "values": entries,
                    "verdict": verdict(k, entries, in_sample, cfg.neutral)}
    summary = summarize(proto.table, rows)
    fresh = (score_fresh_seeds(specs, cfg, grid, defaults, in_sample, data_dir, runs_log) if cfg.fresh_seeds
             else None)
    if fresh is not None and fresh["confirmed"] is False:  # adopted on the seeds it was chosen on only
        for kn in knobs.values():
            if kn["verdict"].startswith("adopt"):
                kn["verdict"] += " (not confirmed on fresh seeds)"
    from .validate_baselines import score_baselines, summarize_baselines

    per_grid = score_baselines(on_grids, cfg.baselines, cfg.reduction, names)
    for row, c in zip(rows, caches):
        row["baselines"] = {n: merge_scores([per_grid[grid_name(c.spec.name, s)][n] for s in shifts])
                            for n in cfg.baselines}
    if cfg.gallery is not None:
        for c in caches:
            gallery(c, Path(to_absolute_path(cfg.gallery)) / f"{c.spec.name}.png")
            c.release()  # (the picture's segmentation: one frame's at a time)
    robustness = {t: transformed(caches, t, cfg.baselines, cfg.reduction, data_dir) for t in cfg.transforms}
    return {"grid": grid, "defaults": defaults, "neutral": dict(cfg.neutral), "in_sample_choice": in_sample,
            "in_sample_steps": in_sample_steps, "folds": folds, "rows": rows, "summary": summary, "knobs": knobs,
            "rule": {"n_boot": cfg.n_boot, "loss_margin": cfg.loss_margin, "ni_margin": cfg.ni_margin,
                     "ensemble": cfg.ensemble, "seed": cfg.seed, "frame_shifts": shifts},
            "grids": per_grid_macros(proto.table, on_grids, shifts),
            "candidates": {c.spec.name: {k: {m: v[m] for m in ("runs", "useful_hits", "all_objects_hits")}
                                         for k, v in c.scores.items()} for c in caches},
            "fresh_seeds": fresh, "robustness": robustness,
            "baselines_summary": summarize_baselines(proto.table, rows, cfg.baselines),
            "wall_s": time.perf_counter() - t0}


def _scorable(specs: list[Any], data_dir: Path) -> list[Any]:
    """The frames whose main object has a valid disparity pixel (an SGBM map may have none on a
    textureless object: such a frame cannot be scored, and is left out with a warning)."""
    from .datasets import load_frame

    out, dropped = [], []
    for s in specs:
        if not scorable(load_frame(s, data_dir)):
            dropped.append(s.name)
        else:
            out.append(s)
    if dropped:
        log.warning("%d frame(s) left out: no main object or no valid disparity on it: %s", len(dropped),
                    ", ".join(dropped))
    if not out:
        raise ValueError("no frame can be scored")
    return out


def transformed(caches: list[SceneCache], kind: str, baselines: list[str] | None = None,
                reduction: Any = None, data_dir: str | Path | None = None) -> dict[str, dict[str, Any]]:
    """The default scores of every scene of ``caches`` transformed by ``add_junk(scene, kind)``,
    by scene name, each with ``"baselines"``: the task baselines of ``baselines`` run once on the
    same transformed scene (:func:`~experiments.validate_baselines.baseline_counts`; ``reduction``:
    the reduction config they are scored with), so that a probe reads the pipeline and its peers
    side by side. A transform is a check of the rule (a mirrored or resampled scene is as easy
    as the original; a pole in front of the object is a failure class), not a tuning scene: the
    folds never see it. Scenes already resampled are skipped by a resampling transform; ``sgbm:NAME``
    matches each frame's stereo pair again (:func:`~experiments.scenes.rematched`, pairs under
    ``data_dir`` or in the corpus) and skips the frames whose map is not SGBM's; a transformed frame
    whose object has no valid pixel left is skipped with a warning."""
    from .scenes import add_junk, rematched
    from .validate_baselines import baseline_counts

    out = {}
    for c in caches:
        if kind.startswith("resample:") and (c.spec.junk or "").startswith("resample:"):
            continue
        t0 = time.perf_counter()
        if kind.startswith("sgbm:"):
            scene = rematched(c.spec, c.scene, kind[5:], data_dir or ".")
            if scene is None:
                continue
        else:
            scene = add_junk(c.scene, kind, seed=sum(map(ord, c.spec.name)))
        if not scorable(scene):  # the transform took every valid pixel of its object: nothing to score
            log.warning("%s (%s): the main object has no valid pixel left; not scored", c.spec.name, kind)
            continue
        tc = SceneCache(c.spec, scene, c.base)
        out[c.spec.name] = sc = tc.score({})
        sc["baselines"] = baseline_counts(scene, baselines, reduction, c.spec.camera) if baselines else {}
        log.info("%s (%s): default %d useful of %d (%.1f s)", c.spec.name, kind, sc["useful_hits"],
                 sc["runs"], time.perf_counter() - t0)
    return out


def _nulls_for_nan(obj: Any) -> Any:
    """``obj`` with every NaN float replaced by ``None``: a macro over no real dataset is undefined,
    and JSON has no NaN."""
    if isinstance(obj, float):
        return None if math.isnan(obj) else obj
    if isinstance(obj, dict):
        return {k: _nulls_for_nan(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nulls_for_nan(v) for v in obj]
    return obj


ConfigStore.instance().store(name="validate_schema", node=ValidateConfig)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="validate")
def main(dcfg: DictConfig) -> int:
    from .cli import configure_threads, interruptible, marked_if_failed

    configure_threads()
    from .schema import one_line_errors, to_config
    from somtorch.atomic import write_staged

    out = Path(HydraConfig.get().runtime.output_dir)
    from .warning_log import warnings_to_file

    with marked_if_failed(out), interruptible(out), one_line_errors(log):  # Ctrl-C / kill: one line, FAILED, 130 / 143
        cfg: ValidateConfig = to_config(dcfg)
        with warnings_to_file(out / "runs.log", "validate"):  # thousands of runs: their warnings in a file
            report = evaluate(cfg, out / "runs.log")
    write_staged(out, {"validate.md": to_markdown(report).encode(), "validate.json": _nulls_for_nan(report)})
    m = report["summary"]["macro_real"]
    if not any(r["real"] for r in report["rows"]):
        log.warning("no real dataset among the frames: the real macro is undefined (null in validate.json) "
                    "and the protocol adopts nothing; tables in %s", out / "validate.md")
        return 0
    log.info("real macro useful-hit rate: default %.1f %%, in-sample %.1f %%, left-out %.1f %% (all-objects "
             "%.1f / %.1f / %.1f %%); tables in %s", *(100 * m[f"{p}_{r}"] for r in ("useful_hits", "all_objects_hits")
                                                   for p in ("default", "in_sample", "left_out")), out / "validate.md")
    if "default_best_grouping_hits" in m:
        log.info("real macro ceilings of the defaults: a perfect choice among each run's maps %.1f %%, a "
                 "perfect ranking of the candidates %.1f %%, a perfect choice among the areas %.1f %%, a "
                 "perfect grouping of the segments %.1f %%", 100 * m.get("default_best_map_hits", math.nan),
                 100 * m.get("default_first_place_hits", math.nan), 100 * m["default_best_area_hits"],
                 100 * m["default_best_grouping_hits"])
    fresh = report.get("fresh_seeds")
    if fresh:  # the same frames on runs nothing was chosen on
        f = fresh["macro_real"]
        log.info("on fresh seeds (%d-%d, grid shifted %d px): real macro useful-hit rate of the defaults "
                 "%.1f %% (%.1f %% on the seeds chosen on)%s", *fresh["seeds"], fresh.get("shift", 0),
                 100 * f["default_useful_hits"], 100 * m["default_useful_hits"],
                 "" if fresh["confirmed"] is None else
                 f"; the in-sample choice {'is' if fresh['confirmed'] else 'is NOT'} confirmed there")
    tot = m.get("default_misses")
    if tot:  # how the other real runs missed (validate.md: per dataset)
        log.info("real runs of the defaults: %d useful of %d; the others kept < 50 %% of the main object (%d), "
                 "50-95 %% of it (%d), or all of it with too much beside it (%d)", tot["useful"], sum(tot.values()),
                 tot["wrong"], tot["partial"], tot["too_much"])
    return 0


register()
def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, ValidateConfig)


if __name__ == "__main__":
    cli()
