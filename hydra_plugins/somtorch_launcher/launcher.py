"""``hydra/launcher=somtorch``: the jobs of a sweep side by side on the cores that are free.

The default launcher of ``somtorch-study`` (``conf/study.yaml``). Before the first job it

1. measures the cores free to this process (its affinity mask and cgroup quota, less what other
   processes keep busy over 60 ms) and starts that many spawned workers (``n_jobs`` if given;
   negative counts as joblib does: −1 = every core; at most the number of jobs);
2. has them compose and check every job's config (contiguous shares, as Hydra's sweepers compose
   them; a share a worker cannot compose is composed here, with its error): a job whose config
   its schema refuses, or that holds a NaN or an infinity, refuses the whole sweep in one line,
   exit status 2, before any job runs; then they ask ``estimate`` (a
   function named by its dotted path, called with a job's composed config without its ``hydra``
   node; it returns ``(seconds, peak_bytes)`` or None) about each job: ~90 ms of Hydra a job,
   spread over the workers while they are needed for nothing else;
3. keeps as many workers as run side by side: at most what the memory available holds at the
   largest estimated peak (``resources.max_memory_frac`` of it), and 1 when a job runs on a GPU
   (one device, not one per worker) or is timed (``repeats > 1``: the runtime study measures each
   job alone on every core);
4. prints one line: the job count, the estimated wall time with that many workers (longest jobs
   first), the largest peak memory, the workers and the threads each job gets (a sweeper that
   launches in batches, as Optuna's, gets it for its first batch only).

The jobs then run longest-first in spawned worker processes, each on ``cores // workers`` torch
threads (a job reads ``hydra.launcher.n_jobs``: ``experiments.cli.launcher_jobs``); a bar in this
process counts the jobs, the workers show none. With one worker the jobs run here, in order, as
Hydra's basic launcher runs them. The worker count never changes a result: every job gives the
same bits at any thread count (tests/core), and tests/experiments compares this launcher's sweep
with the basic launcher's.

Hydra's job callbacks run in this process: ``on_job_start`` when a job is handed to a worker,
``on_job_end`` when its result is back. A job that raises is reported after the sweep, as the
basic sweeper does; a job that exits (a bad input's one-line error, status 2) lets the running
jobs finish, starts no other and ends the sweep with its status. SIGINT / SIGTERM stop the
running jobs (each marks its folder ``FAILED``) and end the sweep with one line and 130 / 143. A
worker that dies (killed, out of memory) fails its job with the signal's name; a new worker
takes the next job.
"""

from __future__ import annotations

import heapq
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple, Optional

from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

from ._workers import ENV_PROGRESS, Pool, plan_jobs, refused_too

log = logging.getLogger(__name__)


class Plan(NamedTuple):
    """How a sweep runs: the order jobs are handed out, the workers, threads per job, the estimate.

    (A NamedTuple, not a dataclass: Hydra's plugin scan runs this module outside ``sys.modules``.)
    """

    order: list[int]
    workers: int
    threads: int
    wall_s: Optional[float]
    peak_bytes: Optional[int]
    estimated: int


def makespan(seconds: Sequence[float], workers: int) -> float:
    """Wall time of jobs of ``seconds`` handed longest first to ``workers`` (each takes the next
    job when it is free)."""
    loads = [0.0] * max(1, workers)
    for s in sorted(seconds, reverse=True):
        heapq.heapreplace(loads, loads[0] + s)
    return max(loads)


def choose_workers(n_jobs: Optional[int], jobs: int, *, cores: int, free: Optional[int],
                   peak_bytes: Optional[int], memory_bytes: Optional[float], alone: bool) -> int:
    """The number of jobs to run side by side (see the module docstring); ``alone``: each job runs
    by itself (on a GPU, or timed)."""
    if jobs <= 1 or alone:
        return 1
    if n_jobs is not None and int(n_jobs) != 0:
        n = int(n_jobs)
        return max(1, min(jobs, cores + 1 + n if n < 0 else n))
    n = min(jobs, cores if free is None else max(1, min(cores, free)))
    if peak_bytes and memory_bytes:
        n = min(n, max(1, int(memory_bytes // peak_bytes)))
    return max(1, n)


class SomtorchLauncher(Launcher):
    """Runs a sweep's jobs in worker processes, as many side by side as cores are free.

    Args:
        n_jobs: jobs side by side; None = as many as cores are free (see the module docstring).
        estimate: dotted path of ``f(config) -> (seconds, peak_bytes) | None`` for one job.
    """

    def __init__(self, n_jobs: Optional[int] = None, estimate: Optional[str] = None) -> None:
        self.n_jobs = n_jobs
        self.estimate = estimate
        self.launches = 0  # a sweeper that asks for batches (Optuna) calls launch() once per batch
        self.config: Optional[DictConfig] = None
        self.task_function: Optional[TaskFunction] = None
        self.hydra_context: Optional[HydraContext] = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config, self.hydra_context, self.task_function = config, hydra_context, task_function

    # ------------------------------------------------------------------ planning
    def _plan(self, configs: list[DictConfig], estimates: list[Optional[tuple[float, int]]],
              free: Optional[int]) -> Plan:
        from somtorch.core.threads import available_cores
        from somtorch.resources import available_memory

        cores = available_cores()
        known = [e for e in estimates if e is not None]
        peak = max((e[1] for e in known), default=None)
        frac = float(OmegaConf.select(configs[0], "resources.max_memory_frac", default=0.8) or 0.8)
        memory = available_memory()[0] * frac if peak else None
        gpu = any(not str(OmegaConf.select(c, "device", default="cpu") or "cpu").startswith("cpu") for c in configs)
        # a timing study (jobs timed several times, `repeats`) measures each job alone on every core
        timing = any(int(OmegaConf.select(c, "repeats", default=1) or 1) > 1 for c in configs)
        workers = choose_workers(self.n_jobs, len(configs), cores=cores, free=free, peak_bytes=peak,
                                 memory_bytes=memory, alone=gpu or timing)
        threads = max(1, cores // workers)
        order = list(range(len(configs)))
        wall = None
        if known:
            # jobs without an estimate count as the mean of the others (for the order and the wall time)
            mean = sum(e[0] for e in known) / len(known)
            secs = [e[0] if e is not None else mean for e in estimates]
            if workers > 1:
                order.sort(key=lambda i: -secs[i])
            wall = makespan(secs, workers)
        return Plan(order, workers, threads, wall, peak, len(known))

    def _announce(self, plan: Plan, jobs: int) -> None:
        from somtorch.resources import fmt_bytes, fmt_seconds

        assert self.config is not None
        name = self.config.get("study") or self.config.hydra.job.name
        if plan.estimated:
            est = (f"estimated ~{fmt_seconds(plan.wall_s or 0.0)} in all (rough: from the sizes of "
                   f"{plan.estimated} job(s)), largest peak memory ~{fmt_bytes(plan.peak_bytes or 0)}")
        else:
            est = "no time estimate (no job's config and scene could be read ahead)"
        side = (f"; {plan.workers} side by side, {plan.threads} thread(s) each" if plan.workers > 1
                else "; one after another")
        if os.environ.get("SOMTORCH_QUIET") != "1":
            print(f"study {name}: {jobs} jobs, {est}{side}", file=sys.stderr, flush=True)

    # ------------------------------------------------------------------ running
    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from somtorch.core.threads import available_cores

        setup_globals()
        assert self.config is not None and self.hydra_context is not None and self.task_function is not None
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        items = [(initial_job_idx + i, list(ov)) for i, ov in enumerate(job_overrides)]
        cores = available_cores()
        free = _free_cores(cores)  # before any worker of ours runs
        # as many workers as the jobs could use; they compose and estimate the jobs, then run them
        most = choose_workers(self.n_jobs, len(items), cores=cores, free=free, peak_bytes=None,
                              memory_bytes=None, alone=False)
        pool = Pool(self, most) if most > 1 else None
        try:
            planned = (pool.plan(items, self.config, self.estimate) if pool is not None
                       else plan_jobs(self.hydra_context.config_loader, self.config, items, self.estimate))
            refused = [(cfg, why) for _, cfg, _, why in planned if why is not None]
            if refused:  # one bad job refuses the sweep before any job runs
                cfg, why = refused[0]
                more = refused_too([c.hydra.job.num for c, _ in refused[1:]])
                print(f"error: job #{cfg.hydra.job.num} ({' '.join(filter_overrides(cfg.hydra.overrides.task))}): "
                      f"{why}{more}; no job of the sweep was run", file=sys.stderr, flush=True)
                raise SystemExit(2)
            configs = [cfg for _, cfg, _, _ in planned]
            plan = self._plan(configs, [est for _, _, est, _ in planned], free)
            for cfg in configs:
                with open_dict(cfg):
                    cfg.hydra.launcher.n_jobs = plan.workers  # the job's thread share (experiments.cli.launcher_jobs)
            if self.launches == 0:  # the first batch says what the sweep will cost; later ones do not repeat it
                self._announce(plan, len(configs))
            self.launches += 1
            log.info("Launching %d jobs locally%s", len(configs),
                     f", {plan.workers} side by side" if plan.workers > 1 else "")
            for idx, ov in items:
                log.info("\t#%d : %s", idx, " ".join(filter_overrides(ov)))
            bar = _bar(len(configs), self.config)
            try:
                if plan.workers == 1:
                    if pool is not None:
                        pool.close()
                    return self._in_process(configs, bar)
                assert pool is not None  # plan.workers <= most
                return pool.run(configs, plan, bar)
            finally:
                bar.close()
        finally:
            if pool is not None:
                pool.close()

    def _in_process(self, configs: list[DictConfig], bar: Any) -> list[JobReturn]:
        assert self.config is not None and self.hydra_context is not None and self.task_function is not None
        runs = []
        for cfg in configs:
            runs.append(run_job(hydra_context=self.hydra_context, task_function=self.task_function, config=cfg,
                                job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir"))
            configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
            bar.update()
        return runs


def _bar(total: int, config: DictConfig) -> Any:
    from tqdm.auto import tqdm

    shown = (total > 1 and os.environ.get("SOMTORCH_QUIET") != "1" and os.environ.get(ENV_PROGRESS) != "0"
             and sys.stderr.isatty())
    name = config.get("study") or config.hydra.job.name
    return tqdm(total=total, desc=f"{name} jobs", unit="job", disable=not shown, position=0, dynamic_ncols=True)


def _free_cores(cores: int, window_s: float = 0.05) -> Optional[int]:
    """Cores other processes leave free, measured over ``window_s`` (None off Linux)."""
    import time

    from somtorch.core.threads import FreeCoreMonitor

    monitor = FreeCoreMonitor(window_s=window_s)
    monitor.free(cores)
    time.sleep(window_s * 1.2)  # a full window: the monitor re-samples only after one
    return monitor.free(cores)
