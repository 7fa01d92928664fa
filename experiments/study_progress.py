"""What a study sweep says before and while it runs.

The default launcher (``hydra/launcher=somtorch``, ``hydra_plugins/somtorch_launcher``) prints the
number of jobs, a rough time estimate with its worker count and the largest peak memory, then counts
the jobs with a bar; it asks :func:`job_estimate` about each job (its scene read once per data set,
:func:`somtorch.pipeline.resource_estimate` times its runs). With another launcher (basic, joblib,
Ray, SLURM) the callback :class:`StudyProgress` (``conf/study.yaml``) first checks every job's
config (:func:`refuse_bad_jobs`: one bad job ends the sweep in one line before any runs), then
prints the same line, summed over the jobs, and a bar when the jobs run in this process. Inside a job the training bar counts
the epochs (steps of the online rule) and, with ``execution=separate``, a bar counts the runs. Every
bar is off with ``--quiet``, when stderr is not a terminal, and in the launcher's workers
(``experiments.cli.show_progress``).
"""

from __future__ import annotations

import logging
import sys
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger("somtorch.study")
SOMTORCH_LAUNCHER = "hydra_plugins.somtorch_launcher."


def sweep_jobs(config: DictConfig) -> list[list[str]]:
    """The override list of every job of the sweep, as Hydra's basic sweeper builds them."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = config.hydra.sweeper.get("params") or {}
    args = [f"{k}={v}" for k, v in params.items()] + list(config.hydra.overrides.task)
    parsed = OverridesParser.create().parse_overrides(args)
    return [job for batch in BasicSweeper.split_arguments(parsed, None) for job in batch]


_scenes: dict[str, Any] = {}  # the last scenes read for estimates, by data config (at most SCENES_KEPT)
SCENES_KEPT = 4
# a study job's own work beside the pipeline: reading the scene, scoring the runs, the pictures and
# files (measured 1.2-4.5 s a job on the table1 study, median ~1.5 s, one thread)
JOB_S = 1.5


def job_estimate(composed: DictConfig) -> tuple[float, int]:
    """``(seconds, peak bytes)`` of one job from its composed config (without the ``hydra`` node):
    :func:`somtorch.pipeline.resource_estimate` of its scene, times its runs and repeats. Raises
    when the config or the scene cannot be read (the caller leaves the job out of the estimate), and
    ``JobRefused`` (``hydra_plugins.somtorch_launcher._workers``) where no run of the job can be
    scored (:func:`somtorch.pipeline.unscorable`): the launcher refuses the sweep then."""
    import dataclasses

    from .run import load_input
    from somtorch.pipeline import resource_estimate

    cfg = OmegaConf.to_object(composed)
    resize = getattr(cfg, "resize", None)
    key = repr(OmegaConf.to_container(OmegaConf.structured(cfg.data))) + repr(resize)
    if key not in _scenes:
        scene = load_input(cfg)
        if resize is not None:
            from somtorch.disparity.resize import resize_scene

            scene = resize_scene(scene, int(resize[0]), int(resize[1]))
        if len(_scenes) >= SCENES_KEPT:  # a big map is not held for the whole sweep
            _scenes.pop(next(iter(_scenes)))
        _scenes[key] = scene
    from hydra_plugins.somtorch_launcher._workers import JobRefused

    from somtorch.pipeline import unscorable

    why = unscorable(_scenes[key], getattr(cfg, "object_id", None))
    if why is not None:  # no run of it can be scored: the sweep is refused before any job runs
        raise JobRefused(f"{why}; leave this job out of the sweep")
    separate = getattr(cfg, "execution", "ensemble") == "separate" and cfg.runs > 1
    repeats = getattr(cfg, "repeats", 1)
    one = dataclasses.replace(cfg, ensemble=1) if separate else cfg
    calls = (cfg.runs if separate else 1) * (repeats + (repeats > 1))
    est = resource_estimate(_scenes[key], one).times(calls)
    return est.seconds + JOB_S * calls, est.peak_bytes


def estimate_jobs(config: DictConfig, jobs: list[list[str]]) -> tuple[float, int, int]:
    """``(seconds, largest peak bytes, jobs estimated)`` of the sweep's jobs; a job whose config
    or scene cannot be read is left out (it fails with its own message when its turn comes); a job
    no run of which can be scored refuses the sweep in one line, exit status 2, before any runs."""
    from hydra.core.global_hydra import GlobalHydra

    from hydra_plugins.somtorch_launcher._workers import JobRefused

    loader = GlobalHydra.instance().config_loader()
    seconds, peak, done = 0.0, 0, 0
    refused = []
    for i, job in enumerate(jobs):
        try:
            composed = loader.load_sweep_config(config, list(job))
            with open_dict(composed):
                del composed["hydra"]  # its ${hydra:...} values need a running job
            s, p = job_estimate(composed)
        except JobRefused as e:  # an input no run can use
            refused.append((i, job, str(e)))
            continue
        except Exception as e:  # noqa: BLE001 - an estimate must never stop the sweep
            log.debug("no estimate for job %s: %s", job, e)
            continue
        seconds += s
        peak = max(peak, p)
        done += 1
    _refuse(refused)
    return seconds, peak, done


def _refuse(refused: list[tuple[int, list[str], str]]) -> None:
    """End the sweep in one line, exit status 2, where any job was refused (before any job runs)."""
    from hydra_plugins.somtorch_launcher._workers import refused_too

    if refused:
        i, job, why = refused[0]
        more = refused_too([n for n, _, _ in refused[1:]])
        print(f"error: job #{i} ({' '.join(job)}): {why}{more}; no job of the sweep was run", file=sys.stderr,
              flush=True)
        raise SystemExit(2)


def refuse_bad_jobs(config: DictConfig, jobs: list[list[str]]) -> None:
    """Compose every job's config and check it (schema, rules, no NaN / infinity: the somtorch
    launcher's check) before any job runs; a bad one ends the sweep in one line, exit status 2."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra_plugins.somtorch_launcher._workers import config_error

    loader = GlobalHydra.instance().config_loader()
    refused = []
    for i, job in enumerate(jobs):
        try:
            why = config_error(loader.load_sweep_config(config, list(job)))
        except Exception:  # noqa: BLE001 - a job Hydra cannot compose fails with Hydra's message when it runs
            why = None
        if why is not None:
            refused.append((i, job, why))
    _refuse(refused)


class StudyProgress(Callback):
    """Job count and time estimate first, then a progress bar across the jobs."""

    def __init__(self) -> None:
        self.bar = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from tqdm.auto import tqdm

        if str(config.hydra.launcher.get("_target_", "")).startswith(SOMTORCH_LAUNCHER):
            return  # the somtorch launcher says it (with its worker count) and counts the jobs itself

        from .cli import quiet, show_progress
        from somtorch.resources import fmt_bytes, fmt_seconds

        jobs = sweep_jobs(config)
        refuse_bad_jobs(config, jobs)
        seconds, peak, done = estimate_jobs(config, jobs)
        if done:
            est = (f"estimated ~{fmt_seconds(seconds)} in all (rough: from the sizes of {done} job(s)), "
                   f"largest peak memory ~{fmt_bytes(peak)}")
        else:
            est = "no time estimate (no job's config and scene could be read ahead)"
        name = config.get("study", "study")
        if not quiet():
            print(f"study {name}: {len(jobs)} jobs, {est}", file=sys.stderr, flush=True)
        self.bar = tqdm(total=len(jobs), desc=f"{name} jobs", unit="job", disable=not show_progress(),
                        position=0, dynamic_ncols=True)

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        if self.bar is not None:
            self.bar.update()

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
