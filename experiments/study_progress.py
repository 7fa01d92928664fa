"""What a study sweep says before and while it runs (a Hydra callback, ``conf/study.yaml``).

Before the first job: the number of jobs and a rough time estimate (each job's config composed as
the sweeper will compose it, its scene read once per data set, and the time of
:func:`somtorch.resources.estimate` summed; the largest peak memory too). While the jobs run: one
progress bar across the jobs (the basic launcher runs them in this process; a launcher that runs
them elsewhere gets the line, not the bar). Inside a job the training bar counts the epochs (steps
of the online rule) and, with ``execution=separate``, a bar counts the runs. Every bar is off with
``--quiet`` or when stderr is not a terminal (``experiments.cli.show_progress``).
"""

from __future__ import annotations

import logging
import sys
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger("somtorch.study")


def sweep_jobs(config: DictConfig) -> list[list[str]]:
    """The override list of every job of the sweep, as Hydra's basic sweeper builds them."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = config.hydra.sweeper.get("params") or {}
    args = [f"{k}={v}" for k, v in params.items()] + list(config.hydra.overrides.task)
    parsed = OverridesParser.create().parse_overrides(args)
    return [job for batch in BasicSweeper.split_arguments(parsed, None) for job in batch]


def estimate_jobs(config: DictConfig, jobs: list[list[str]]) -> tuple[float, int, int]:
    """``(seconds, largest peak bytes, jobs estimated)`` of the sweep's jobs; a job whose config
    or scene cannot be read is left out (it fails with its own message when its turn comes)."""
    import dataclasses

    from hydra.core.global_hydra import GlobalHydra

    from .run import load_input
    from somtorch.pipeline import resource_estimate

    loader = GlobalHydra.instance().config_loader()
    scenes: dict[str, Any] = {}
    seconds, peak, done = 0.0, 0, 0
    for job in jobs:
        try:
            composed = loader.load_sweep_config(config, list(job))
            with open_dict(composed):
                del composed["hydra"]  # its ${hydra:...} values need a running job
            cfg = OmegaConf.to_object(composed)
            key = repr(OmegaConf.to_container(OmegaConf.structured(cfg.data))) + repr(cfg.resize)
            if key not in scenes:
                scene = load_input(cfg)
                if cfg.resize is not None:
                    from somtorch.disparity.resize import resize_scene

                    scene = resize_scene(scene, int(cfg.resize[0]), int(cfg.resize[1]))
                scenes[key] = scene
            separate = cfg.execution == "separate" and cfg.runs > 1
            one = dataclasses.replace(cfg, ensemble=1) if separate else cfg
            est = resource_estimate(scenes[key], one).times((cfg.runs if separate else 1)
                                                            * (cfg.repeats + (cfg.repeats > 1)))
        except Exception as e:  # noqa: BLE001 - an estimate must never stop the sweep
            log.debug("no estimate for job %s: %s", job, e)
            continue
        seconds += est.seconds
        peak = max(peak, est.peak_bytes)
        done += 1
    return seconds, peak, done


class StudyProgress(Callback):
    """Job count and time estimate first, then a progress bar across the jobs."""

    def __init__(self) -> None:
        self.bar = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from tqdm.auto import tqdm

        from .cli import quiet, show_progress
        from somtorch.resources import fmt_bytes, fmt_seconds

        jobs = sweep_jobs(config)
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
