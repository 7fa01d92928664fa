"""``python -m experiments.study``: one job of a study = one configuration run ``ensemble`` times.

A study is a Hydra sweep (``conf/experiment/<name>.yaml``: table1, table2, runtime, stability,
grid, baselines, optuna); each job scores ``ensemble`` executions (seeds ``seed … seed+ensemble−1``)
of one configuration and writes ``metrics.json`` (per-run values, summary, timings) plus TensorBoard
events with the hparams plugin. ``python -m experiments.aggregate <sweep dir>`` turns the
``metrics.json`` files of a sweep into the paper's tables and plots.

Executions: ``execution=ensemble`` (default) trains all runs as ONE ensemble (one tensor op);
``execution=separate`` runs them one after another as the paper did (each member of an ensemble is
bitwise the separate run with its seed, so both give the same per-run results; only time differs).

Fault tolerance: the sweep directory is fixed by the study name and every job's folder by its
overrides, and ``metrics.json`` is written last and atomically. Re-running a killed sweep with the
same command skips every job whose ``metrics.json`` is complete and was made by the same config
and the same library code (:func:`job_hash`), recomputes the others and loses nothing; after the
code changed, every job runs again.

    python -m experiments.study +experiment=table1
    python -m experiments.study +experiment=runtime
    python -m experiments.study data=kitti2015 ensemble=20 +preset=paper      # one job
"""

from __future__ import annotations

if __name__ == "__main__":  # signals and --help answered before the heavy imports (torch, Hydra)
    from .entry import start

    start("study")

import dataclasses
import json
import logging
import os
import platform
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from .run import CONF_DIR, load_input
from .schema import RunConfig, register
from .metrics_schema import SCHEMA, config_hash, files_digest
from somtorch.evaluation import merge_runs, per_object_scores, run_records, summarize_runs
from somtorch.pipeline import unscorable

log = logging.getLogger("somtorch.study")
register()
EXECUTIONS = ("ensemble", "separate")


@dataclass
class StudyConfig(RunConfig):
    """A study job: the run config plus how the runs are executed and measured.

    Attributes:
        study: the study's name (``table1``, ``runtime``, …); names the sweep folder.
        execution: ``"ensemble"`` (all runs in one tensor op) or ``"separate"`` (one pipeline call
            per seed, as in the paper; per-run runtimes are then measured, not amortised).
        repeats: the whole job is timed this many times (runtime study; after one untimed warm-up run);
            results come from the first.
        resize: ``[width, height]``: resample the scene first (nearest-neighbour disparity, scaled).
        skip_complete: skip the job if its folder holds a complete ``metrics.json`` of the same config
            and the same library code (:func:`job_hash`).
        task_baseline: run this task baseline (somtorch.tasks.baselines, e.g. ``plane_components``) once
            instead of the pipeline; aggregate prints it beside the paper and the SOM (None = the pipeline).
    """

    study: str = "adhoc"
    execution: str = "ensemble"
    repeats: int = 1
    resize: Optional[list[int]] = None
    skip_complete: bool = True
    task_baseline: Optional[str] = None

    def __post_init__(self) -> None:
        super().__post_init__()
        from somtorch.validation import check_choice, check_positive_int

        if self.task_baseline is not None:
            from .real_scenes import check_methods

            check_methods([self.task_baseline], "task_baseline")

        check_choice("execution", self.execution, EXECUTIONS)
        check_positive_int("repeats", self.repeats)
        if self.resize is not None and (len(self.resize) != 2 or min(self.resize) < 1):
            raise ValueError(f"resize must be [width, height] with positive sizes; got {self.resize}")


ConfigStore.instance().store(name="study_schema", node=StudyConfig)

# keys that do not change a job's results (where files go, whether to skip)
def complete_metrics(path: Path, chash: str) -> dict | None:
    """The metrics of a finished job in ``path`` made by the config with hash ``chash``, else None."""
    f = path / "metrics.json"
    try:
        m = json.loads(f.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("schema") != SCHEMA or m.get("config_hash") != chash:
        return None
    return m


_SOURCE_SUFFIXES = (".py", ".cpp", ".h", ".cu")


def source_digest(root: Path) -> str:
    """A digest of the source files under ``root`` (``.py`` and the native extension's ``.cpp`` /
    ``.h`` / ``.cu``, by relative path and bytes, in path order): 16 hex digits."""
    return files_digest(root, (q for q in root.rglob("*") if q.suffix in _SOURCE_SUFFIXES and q.is_file()))


_CODE_DIGEST: dict[str, str] = {}  # a plain dict, not functools.lru_cache: a launcher pickles this
# module's functions by value when it runs as __main__, and a cache object would go by reference


def code_digest() -> str:
    """:func:`source_digest` of the installed ``somtorch`` package, computed once per process."""
    import somtorch

    root = Path(somtorch.__file__).parent
    if str(root) not in _CODE_DIGEST:
        _CODE_DIGEST[str(root)] = source_digest(root)
    return _CODE_DIGEST[str(root)]


def job_hash(cfg: StudyConfig, config: dict[str, Any]) -> str:
    """The job's hash: of ``config`` and of the library's code (:func:`code_digest`), and for a
    trained task baseline also of the model it scores (its registry entry's ``identity``), so that a
    study re-runs a job after the code or the model changed instead of skipping it as complete (the
    same config gives other results under other code)."""
    keyed = {**config, "code": code_digest()}
    if cfg.task_baseline is not None:
        from somtorch.tasks.baselines import get_task_baseline

        identity = get_task_baseline(cfg.task_baseline).identity
        if identity is not None:
            return config_hash({**keyed, "task_baseline_model": identity()})
    return config_hash(keyed)


def execute(cfg: StudyConfig, out_dir: Path, config: dict[str, Any]) -> dict[str, Any]:
    """Run one study job into ``out_dir`` (see the module docstring); returns its metrics.

    The job holds its folder (:func:`somtorch.locks.exclusive_folder`): a second study into the same
    output root that reaches a job the first is running waits for it, then skips it (its
    ``metrics.json`` is complete) or, if the first failed, runs it. No job runs twice at once.
    """
    from somtorch.locks import exclusive_folder

    with exclusive_folder(out_dir, wait=True):
        return _execute(cfg, out_dir, config)


def _execute(cfg: StudyConfig, out_dir: Path, config: dict[str, Any]) -> dict[str, Any]:
    import torch

    from somtorch import __version__
    from somtorch.atomic import commit_staged, write_json
    from somtorch.disparity.resize import resize_scene
    from somtorch.fallbacks import fallback_summary
    from somtorch.outputs import train_strides, write_maps
    from somtorch.pipeline import run_pipeline

    chash = job_hash(cfg, config)
    if cfg.skip_complete:
        done = complete_metrics(out_dir, chash)
        if done is not None:
            log.info("skipping %s: complete metrics.json of the same config and code (hash %s)", out_dir, chash)
            return done
    t_start = time.perf_counter()
    scene = load_input(cfg)  # every file check before any work
    if cfg.resize is not None:
        scene = resize_scene(scene, int(cfg.resize[0]), int(cfg.resize[1]))
    if cfg.object_id is not None and scene.objects is None:
        raise ValueError(f"object_id={cfg.object_id} but scene {scene.name!r} has no object mask")
    obj_mask = None
    if scene.objects is not None:
        obj_mask = scene.scored_mask(cfg.object_id)
        why = unscorable(scene, cfg.object_id)
        if why is not None:
            raise ValueError(f"{why}; leave this job out of the sweep")
    if cfg.task_baseline is not None:  # one deterministic run, no training
        from somtorch.atomic import write_staged

        from .study_baseline import baseline_job

        metrics = baseline_job(cfg, scene, obj_mask, config, chash, SCHEMA)
        metrics["wall_s"] = time.perf_counter() - t_start
        write_staged(out_dir, {"metrics.json": metrics})
        (out_dir / "FAILED").unlink(missing_ok=True)
        return metrics
    from .run import check_resources

    separate = cfg.execution == "separate" and cfg.runs > 1
    job = dataclasses.replace(cfg, ensemble=1) if separate else cfg
    check_resources([(scene, job, (cfg.runs if separate else 1) * (cfg.repeats + (cfg.repeats > 1)))],
                    cfg.resources, f"job {out_dir.name} ({scene.name} {scene.width}x{scene.height}, "
                                   f"{cfg.runs} runs, {cfg.execution})")
    out_dir.mkdir(parents=True, exist_ok=True)
    for stale in out_dir.glob(".partial-*"):  # left by a killed attempt of this same job
        shutil.rmtree(stale, ignore_errors=True)
    stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=out_dir))
    try:
        from tqdm.auto import tqdm

        from .cli import launcher_jobs, show_progress

        repeats: list[dict[str, float]] = []
        results, per_run_s = [], None
        per_rep = 1 if cfg.execution == "ensemble" or cfg.runs == 1 else cfg.runs
        bar = tqdm(total=cfg.repeats * per_rep, desc=f"{scene.name} runs", unit="run", leave=False,
                   disable=not show_progress())  # updated between timed runs only
        with fallback_summary(scene.name):  # one warning line for the job, not one per run
            if cfg.repeats > 1:  # timing study: one untimed warm-up (kernel compile/load, allocator, caches)
                run_pipeline(scene, dataclasses.replace(cfg, ensemble=1), metrics=False)
            for rep in range(cfg.repeats):
                t0 = time.perf_counter()
                if cfg.execution == "ensemble" or cfg.runs == 1:
                    res = [run_pipeline(scene, cfg, metrics=True, progress=show_progress())]  # epochs bar
                    times = None
                    bar.update()
                else:
                    res, times = [], []
                    for e in range(cfg.runs):
                        te = time.perf_counter()
                        solo = dataclasses.replace(cfg, ensemble=1, seed=cfg.seed + e)
                        res.append(run_pipeline(scene, solo, metrics=True))
                        times.append(time.perf_counter() - te)
                        bar.update()
                wall = time.perf_counter() - t0
                stages: dict[str, float] = {}
                for r in res:
                    for k, v in r.timings.items():
                        stages[k] = stages.get(k, 0.0) + v
                repeats.append({**stages, "wall": wall})
                if rep == 0:
                    results, per_run_s = res, times
        bar.close()
        runs = merge_runs([run_records(scene, r, obj_mask, None if per_run_s is None else per_run_s[i:i + 1])
                            for i, r in enumerate(results)])
        first = results[0].members[0].score
        x_opt = first.x_opt if first is not None else None
        metrics: dict[str, Any] = {
            "schema": SCHEMA, "study": cfg.study, "config_hash": chash, "label": cfg.label,
            "method": cfg.method, "execution": cfg.execution,
            "mode": "OR" if cfg.features.train_stride > 1 else "NOR",
            "grid": f"{cfg.som.rows}x{cfg.som.cols}", "segments": results[0].num_segments,
            "scene": {"name": cfg.data.name or scene.name, "height": scene.height, "width": scene.width,
                      "valid_pixels": scene.n_valid, "has_objects": scene.objects is not None,
                      "object_id": cfg.object_id, "source": scene.source},
            "pixels": {"train": len(results[0].train_features), "segmented": len(results[0].features),
                       **train_strides(scene, results[0])},
            "ground_found": results[0].ground is not None,
            "runs": runs, "summary": summarize_runs(runs, x_opt),
            "per_object": per_object_scores(scene, results) if scene.objects is not None else {},
            "timings_s": repeats[0], "timings_repeats_s": repeats,
            "job": _job_info(),
            "env": {"somtorch": __version__, "torch": torch.__version__, "threads": torch.get_num_threads(),
                    "jobs_side_by_side": launcher_jobs(),  # its runtimes were measured beside that many jobs
                    "python": platform.python_version(), "host": platform.node(),
                    "native_kernel": os.environ.get("SOMTORCH_NATIVE", "1") != "0"},
            "config": config,
        }
        out_t: dict[str, float] = {}  # writing pictures and files, apart from the compute in timings_s
        if cfg.output.maps:
            t0 = time.perf_counter()
            write_maps(scene, results[0], stage, member=0)
            out_t["maps"] = time.perf_counter() - t0
        if cfg.output.tensorboard:  # written and closed before anything moves out of the staging folder
            t0 = time.perf_counter()
            _tensorboard(stage, cfg, metrics)
            out_t["tensorboard"] = time.perf_counter() - t0
        metrics["output_timings_s"] = out_t
        metrics["wall_s"] = time.perf_counter() - t_start
        write_json(stage / "metrics.json", metrics)
        commit_staged(stage, out_dir)  # metrics.json last: its presence marks a complete job
        (out_dir / "FAILED").unlink(missing_ok=True)  # left by an earlier, failed or interrupted attempt
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    s = metrics["summary"]
    name = cfg.label if cfg.method == "som" else f"{cfg.label}/{cfg.method}"
    if "identified_95" in s:
        log.info("%s %s %s: >=95 %% %d/%d, 100 %% %d, useful %d, x_opt %.1f %%, %.1f s", metrics["scene"]["name"],
                 metrics["mode"], name, s["identified_95"], s["runs"], s["identified_100"], s["useful_hits"],
                 s["x_opt"], metrics["wall_s"])
    else:
        log.info("%s %s: %d runs, %.1f s", metrics["scene"]["name"], metrics["mode"], s["runs"], metrics["wall_s"])
    return metrics


def _job_info() -> dict[str, Any]:
    try:
        hc = HydraConfig.get()
    except ValueError:
        return {}
    return {"override_dirname": hc.job.override_dirname, "num": hc.job.get("num"),
            "overrides": list(hc.overrides.task)}


def _tensorboard(stage: Path, cfg: StudyConfig, metrics: dict[str, Any]) -> None:
    """Histograms over the runs and the hparams-plugin record of the job, in ``stage/tb`` (closed on return)."""
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(stage / "tb"))
    try:
        _write_tensorboard(writer, cfg, metrics)
    finally:
        writer.close()


def _write_tensorboard(writer, cfg: StudyConfig, metrics: dict[str, Any]) -> None:
    import torch

    runs = metrics["runs"]
    for key in ("reduction_union", "area_frac", "runtime_s", "identified_fraction"):
        if key in runs and runs[key]:
            writer.add_histogram(f"runs/{key}", torch.tensor(runs[key], dtype=torch.float64), 0)
    hp = {"scene": metrics["scene"]["name"], "method": cfg.method, "label": cfg.label, "mode": metrics["mode"],
          "grid": metrics["grid"], "train_mode": cfg.train.mode, "order": cfg.train.order, "init": cfg.som.init,
          "lr": cfg.train.lr, "sigma": cfg.train.sigma if cfg.train.sigma is not None else -1.0,
          "tolerance_frac": cfg.reduction.tolerance_frac,
          "tolerance_image": cfg.reduction.tolerance_image, "runs": cfg.runs, "execution": cfg.execution}
    s = metrics["summary"]
    res = {"hparam/reduction_mean": s["reduction_all"]["mean"], "hparam/runtime_s": s["runtime_s"]["mean"]}
    if "identified_95" in s:
        res.update({"hparam/identified_100_rate": s["identified_100"] / s["runs"],
                    "hparam/identified_95_rate": s["identified_95"] / s["runs"],
                    "hparam/useful_hit_rate": s["useful_hits"] / s["runs"], "hparam/tradeoff": s["tradeoff"]})
    writer.add_hparams(hp, res, run_name=".")


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="study")
def main(dcfg: DictConfig) -> float:
    """Hydra entry point; returns the job's objective (``summary.tradeoff``; 0 without an object mask)."""
    from .cli import configure_threads, interruptible, marked_if_failed
    from .schema import one_line_errors, to_config

    configure_threads()
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with marked_if_failed(out_dir), interruptible(out_dir), one_line_errors(log):  # Ctrl-C / kill: one line, FAILED in the job's folder
        cfg: StudyConfig = to_config(dcfg)
        metrics = execute(cfg, out_dir, OmegaConf.to_container(dcfg, resolve=True))
    return float(metrics["summary"].get("tradeoff", 0.0))


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, StudyConfig)


if __name__ == "__main__":
    cli()
