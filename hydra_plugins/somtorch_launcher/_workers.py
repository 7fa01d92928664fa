"""The worker processes of the somtorch launcher (:mod:`.launcher`): one pipe each, jobs handed out
one at a time, results, exits and deaths collected in the launching process.

(A leading underscore: Hydra's plugin scan skips this module; the workers import it by name.)
"""

from __future__ import annotations

import importlib
import logging
import math
import multiprocessing
import os
import pickle
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any, Optional

from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, filter_overrides, run_job, setup_globals
from hydra.types import HydraContext, TaskFunction
from hydra.utils import get_method
from omegaconf import DictConfig, open_dict

log = logging.getLogger("hydra_plugins.somtorch_launcher.launcher")
ENV_PROGRESS = "SOMTORCH_PROGRESS"  # "0" in the workers: their bars would overwrite each other
STOP_WAIT_S = 20.0  # how long stopped workers get to mark their folders before they are killed


def _task_reference(fn: TaskFunction) -> tuple[str, str]:
    """(module, name) a worker imports the task function by; ``__main__`` by the name it was run as."""
    module = fn.__module__
    if module == "__main__":
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        module = spec.name if spec is not None else "__mp_main__"  # a script: spawn imports it so
    return module, fn.__qualname__


def _task_function(module: str, name: str) -> TaskFunction:
    fn = getattr(importlib.import_module(module), name)
    return getattr(fn, "__wrapped__", fn)  # the function under @hydra.main, as Hydra calls it


def _portable(ret: JobReturn) -> JobReturn:
    """``ret`` with a return value or exception that survives pickling (else its text)."""
    try:
        pickle.dumps(ret._return_value)
    except Exception:  # noqa: BLE001 - any unpicklable value is replaced by its text
        value = ret._return_value
        ret._return_value = RuntimeError(f"{type(value).__name__}: {value}") if ret.status == JobStatus.FAILED \
            else repr(value)
    return ret


def compose(loader: Any, master: DictConfig, idx: int, overrides: Sequence[str]) -> DictConfig:
    """Job ``idx``'s config, composed as Hydra's sweepers compose it."""
    cfg = loader.load_sweep_config(master, list(overrides))
    with open_dict(cfg):
        cfg.hydra.job.id = idx
        cfg.hydra.job.num = idx
    return cfg


def locate(path: Optional[str]) -> Optional[Callable[[DictConfig], Any]]:
    """The estimate function named by its dotted ``path`` (None: no estimate, or it cannot be imported)."""
    if not path:
        return None
    try:
        return get_method(path)
    except (ImportError, ValueError) as e:
        log.warning("no time estimate: %s cannot be imported (%s)", path, e)
        return None


def refused_too(nums: Sequence[int]) -> str:
    """The tail of a refused sweep's error line for the jobs refused after the first (numbers, the
    first ten): a user who edits the sweep finds them all at once."""
    if not nums:
        return ""
    shown = ", ".join(f"#{n}" for n in nums[:10]) + (", ..." if len(nums) > 10 else "")
    return f"; {len(nums)} more job(s) refused too ({shown})"


class JobRefused(Exception):
    """Raised by a sweep's estimate function for a job whose input no run of it can use (its message:
    one line naming the input and the problem): the launcher refuses the whole sweep before any job
    runs, as for a bad config (:func:`config_error`), instead of the job failing in its turn."""


def estimate(fn: Optional[Callable[[DictConfig], Any]], cfg: DictConfig) -> Optional[tuple[float, int]]:
    """``fn``'s (seconds, peak bytes) for one composed job, or None (an estimate never stops a sweep:
    only a :class:`JobRefused` it raises goes through)."""
    if fn is None:
        return None
    job = cfg.copy()
    with open_dict(job):
        del job["hydra"]  # its ${hydra:...} values need a running job
    try:
        est = fn(job)
    except JobRefused:
        raise
    except Exception as e:  # noqa: BLE001 - the job fails with its own message when its turn comes
        log.debug("no estimate for job %s: %s", cfg.hydra.job.num, e)
        return None
    return None if est is None else (float(est[0]), int(est[1]))


def config_error(cfg: DictConfig) -> Optional[str]:
    """Why a composed job's config is refused, in one line, or None: its schema's types and rules
    (the dataclasses built as the job builds them) and no NaN or infinity anywhere."""
    from omegaconf import OmegaConf
    from omegaconf.errors import InterpolationResolutionError, OmegaConfBaseException

    from somtorch.config.constraints import nonfinite

    job = cfg.copy()
    with open_dict(job):
        del job["hydra"]  # its ${hydra:...} values need a running job
    try:
        tree = OmegaConf.to_container(job, resolve=True)
        bad = nonfinite(tree)
        if bad is not None:
            return f"{bad[0]}={bad[1]}: expected a finite number (NaN and infinities are not config values)"
        if OmegaConf.get_type(job) is not dict:  # a structured config: build it, its rules run
            OmegaConf.to_object(job)
    except InterpolationResolutionError:  # a value only a running job can resolve: the job will say
        return None
    except (ValueError, TypeError, OmegaConfBaseException) as e:
        text = str(e).strip()
        return text.splitlines()[0] if text else type(e).__name__
    except Exception:  # noqa: BLE001 - not a config problem (an import, a resolver): the job will say
        return None
    return None


def plan_jobs(loader: Any, master: DictConfig, items: Sequence[tuple[int, Sequence[str]]],
              estimate_path: Optional[str]
              ) -> list[tuple[int, DictConfig, Optional[tuple[float, int]], Optional[str]]]:
    """Compose, check and estimate the jobs ``items`` = [(idx, overrides)]: [(idx, config,
    estimate, why the job is refused or None)] — its config (:func:`config_error`), or its input
    (the estimate raised :class:`JobRefused`)."""
    fn = locate(estimate_path)
    out = []
    for idx, overrides in items:
        cfg = compose(loader, master, idx, overrides)
        error, est = config_error(cfg), None
        if error is None:
            try:
                est = estimate(fn, cfg)
            except JobRefused as e:  # an input no run can use: refused like a bad config
                error = str(e)
        out.append((idx, cfg, est, error))
    return out


def _send(conn: Any, msg: tuple[str, Any]) -> bool:
    """Send ``msg`` to the launcher; False where a signal or a closed pipe stopped it on its way (the
    launcher then counts the job as not done, and this worker has nothing left to clean up)."""
    try:
        conn.send(msg)
    except BaseException:  # noqa: BLE001 - an Interrupted raised inside the write, or EPIPE
        return False
    return True


def _serve(conn: Any, task: tuple[str, str], loader: bytes, state: bytes) -> None:
    """A worker: run the composed configs that arrive on ``conn`` until None (or the pipe closes)."""
    from hydra._internal.callbacks import Callbacks
    from hydra.core.plugins import Plugins
    from tqdm.std import tqdm

    # tqdm's default write lock is a multiprocessing semaphore; a worker shows no bars, and a worker
    # killed while holding one leaves the resource tracker a "leaked semaphore" warning
    tqdm.set_lock(threading.RLock())
    from somtorch import interrupt

    interrupt.leave_to_parent()  # the launcher stops its workers with SIGTERM (Pool._stop), once
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked since the spawn (Pool._start)
    setup_globals()  # Hydra's resolvers; the task's module registers its own when imported (next)
    task_function = _task_function(*task)
    Singleton._instances = pickle.loads(state)  # as Singleton.set_state, without the resolvers: closures
    Plugins.instance()                          # do not pickle, and the imports above made them
    context = HydraContext(config_loader=pickle.loads(loader), callbacks=Callbacks())  # callbacks run in the parent
    while True:
        try:
            msg = conn.recv()
        except BaseException:  # noqa: BLE001 - the pipe closed, or a signal between jobs: nothing to clean
            return
        if msg is None:
            return
        kind, payload = msg
        if kind == "plan":  # compose and estimate a share of the sweep's jobs
            master, estimate_path, items = pickle.loads(payload)
            try:
                planned = plan_jobs(context.config_loader, master, items, estimate_path)
                reply = ("planned", pickle.dumps(planned)) if planned is not None else ("unplanned", None)
            except BaseException:  # noqa: BLE001 - the launcher composes these itself and says why
                reply = ("unplanned", None)
            if not _send(conn, reply):
                return
            continue
        config = pickle.loads(payload)
        HydraConfig.instance().set_config(config)
        try:
            ret = run_job(hydra_context=context, task_function=task_function, config=config,
                          job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
        except SystemExit as e:  # the job's one-line error or an interrupt: it has said why
            _send(conn, ("exit", e.code if isinstance(e.code, int) else 1))
            return
        except BaseException as e:  # noqa: BLE001 - a signal outside the job's handler
            _send(conn, ("exit", 128 + int(getattr(e, "signum", signal.SIGINT))))
            return
        try:  # packing a large result takes a while: a SIGTERM may land here as well as in _send
            done = ("done", pickle.dumps(_portable(ret)))
        except BaseException:  # noqa: BLE001 - a signal while it was packed: the launcher counts the job lost
            return
        if not _send(conn, done):  # a signal while it was on its way
            return


def _reply(conn: Any) -> tuple[str, Any]:
    """What a worker whose pipe or process became ready sent, or ``("died", None)``."""
    try:
        return conn.recv() if conn.poll() else ("died", None)
    except (EOFError, OSError):
        return "died", None


class Pool:
    """The workers of one launch, one pipe each: first they compose and estimate shares of the
    sweep's jobs (:meth:`plan`), then they run the jobs, handed out one at a time (:meth:`run`)."""

    def __init__(self, launcher: Any, workers: int) -> None:
        assert launcher.hydra_context is not None and launcher.task_function is not None
        self.launcher = launcher
        self.callbacks = launcher.hydra_context.callbacks
        self.args = (_task_reference(launcher.task_function), pickle.dumps(launcher.hydra_context.config_loader),
                     pickle.dumps(Singleton.get_state()["instances"]))
        self.ctx = multiprocessing.get_context("spawn")
        self.workers: dict[Any, tuple[Any, Optional[int]]] = {}  # process -> (pipe, job position or None)
        self.configs: list[DictConfig] = []
        self.results: list[Optional[JobReturn]] = []
        self.todo: list[int] = []
        self.exit_code: Optional[int] = None
        self.bar: Any = None
        for _ in range(workers):
            self._start()

    def _start(self) -> Any:
        parent, child = self.ctx.Pipe()
        proc = self.ctx.Process(target=_serve, args=(child, *self.args), daemon=True)
        old = os.environ.get(ENV_PROGRESS)
        os.environ[ENV_PROGRESS] = "0"  # inherited by the spawned worker only
        # spawned with SIGINT blocked (the mask is inherited): a Ctrl-C to the process group while the
        # worker still imports cannot print its traceback; _serve then ignores SIGINT and unblocks it
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            if old is None:
                os.environ.pop(ENV_PROGRESS, None)
            else:
                os.environ[ENV_PROGRESS] = old
        child.close()
        self.workers[proc] = (parent, None)
        return proc

    # ------------------------------------------------------------------ planning
    def plan(self, items: list[tuple[int, Sequence[str]]], master: DictConfig, estimate_path: Optional[str]
             ) -> list[tuple[int, DictConfig, Optional[tuple[float, int]], Optional[str]]]:
        """[(idx, config, estimate, refusal)] of ``items`` = [(idx, overrides)], in their order, composed by the
        workers in contiguous shares (consecutive jobs usually share a scene, which each reads once);
        a share whose worker fails or dies is composed here."""
        from multiprocessing.connection import wait

        from somtorch import interrupt

        interrupt.install()
        size = max(1, math.ceil(len(items) / (3 * max(1, len(self.workers)))))
        shares = [items[i:i + size] for i in range(0, len(items), size)]
        pending = list(range(len(shares)))
        out: dict[int, list] = {}
        busy: dict[Any, int] = {}  # pipe -> share
        procs = {conn: proc for proc, (conn, _) in self.workers.items()}
        try:
            idle = list(procs)
            while pending or busy:
                while pending and idle:
                    conn = idle.pop()
                    share = pending.pop(0)
                    conn.send(("plan", pickle.dumps((master, estimate_path, shares[share]))))
                    busy[conn] = share
                if not busy:  # every worker died: the rest is composed here
                    loader = self.launcher.hydra_context.config_loader
                    for share in pending:
                        out[share] = plan_jobs(loader, master, shares[share], estimate_path)
                    break
                ready = wait(list(busy) + [procs[c].sentinel for c in busy])
                for conn in list(busy):
                    proc = procs[conn]
                    if conn not in ready and proc.sentinel not in ready:
                        continue
                    share = busy.pop(conn)
                    kind, value = _reply(conn)
                    if kind == "planned":
                        out[share] = pickle.loads(value)
                        idle.append(conn)
                        continue
                    loader = self.launcher.hydra_context.config_loader
                    out[share] = plan_jobs(loader, master, shares[share], estimate_path)  # here, with its error
                    if kind == "unplanned":
                        idle.append(conn)
                    else:  # a worker that died planning is not replaced until the jobs need it
                        del self.workers[proc]
                        conn.close()
        except (interrupt.Interrupted, KeyboardInterrupt) as e:
            self.close()
            raise interrupt.Interrupted(getattr(e, "signum", signal.SIGINT), "while composing the jobs") from None
        return [row for share in range(len(shares)) for row in out[share]]

    # ------------------------------------------------------------------ running
    def run(self, configs: list[DictConfig], plan: Any, bar: Any) -> list[JobReturn]:
        """Run ``configs`` in ``plan.order`` on ``plan.workers`` workers; their JobReturns in job order."""
        from multiprocessing.connection import wait

        from somtorch import interrupt

        interrupt.install()  # SIGINT / SIGTERM here raise Interrupted at once (no deferred region)
        self.configs, self.bar = configs, bar
        self.results = [None] * len(configs)
        self.todo = list(plan.order)
        try:
            for proc in list(self.workers)[plan.workers:]:  # planning needed more hands than the jobs can use
                self._retire(proc)
            while len(self.workers) < plan.workers:
                self._start()
            for proc in list(self.workers):
                self._hand_out(proc)
            while any(job is not None for _, job in self.workers.values()):
                busy = {conn: proc for proc, (conn, job) in self.workers.items() if job is not None}
                ready = wait(list(busy) + [p.sentinel for p in busy.values()])
                for proc in dict.fromkeys([busy[r] for r in ready if r in busy]
                                          + [p for p in busy.values() if p.sentinel in ready]):
                    self._collect(proc)  # its result, or its death
        except (interrupt.Interrupted, KeyboardInterrupt) as e:
            done = sum(r is not None for r in self.results)
            self._stop(signal.SIGTERM)
            signum = getattr(e, "signum", signal.SIGINT)
            raise interrupt.Interrupted(signum, f"with {done} of {len(self.configs)} jobs done") from None
        finally:
            self._stop(None)
        if self.exit_code is not None:
            raise SystemExit(self.exit_code)
        assert all(r is not None for r in self.results)
        return [r for r in self.results if r is not None]

    def close(self) -> None:
        """End the workers (idle ones: at once)."""
        self._stop(None)

    def _retire(self, proc: Any) -> None:
        conn, _ = self.workers.pop(proc)
        try:
            conn.send(None)
        except (OSError, ValueError):
            pass
        proc.join(STOP_WAIT_S)
        if proc.is_alive():
            proc.kill()
        conn.close()

    def _hand_out(self, proc: Any) -> None:
        conn, _ = self.workers[proc]
        if not self.todo or self.exit_code is not None:
            self.workers[proc] = (conn, None)
            return
        i = self.todo.pop(0)
        self.callbacks.on_job_start(config=self.configs[i], task_function=self.launcher.task_function)
        conn.send(("run", pickle.dumps(self.configs[i])))
        self.workers[proc] = (conn, i)

    def _finish(self, i: int, ret: JobReturn) -> None:
        self.results[i] = ret
        self.callbacks.on_job_end(config=self.configs[i], job_return=ret)
        self.bar.update()

    def _collect(self, proc: Any) -> None:
        conn, i = self.workers[proc]
        assert i is not None
        kind, value = _reply(conn)
        if kind == "done":
            self._finish(i, pickle.loads(value))
            self._hand_out(proc)
            return
        del self.workers[proc]
        conn.close()
        if kind == "exit":
            self.exit_code = self.exit_code or int(value)
            proc.join(5)
            return
        proc.join(5)
        code = proc.exitcode
        why = f"signal {signal.Signals(-code).name}" if code is not None and code < 0 else f"exit status {code}"
        overrides = list(self.configs[i].hydra.overrides.task)
        ret = JobReturn(overrides=overrides, cfg=self.configs[i], status=JobStatus.FAILED)
        ret.return_value = RuntimeError(f"the worker running job #{self.configs[i].hydra.job.num} died ({why}"
                                        + ("; out of memory?" if code == -signal.SIGKILL else "") + ")")
        print(f"{ret._return_value}: {' '.join(filter_overrides(overrides))}", file=sys.stderr, flush=True)
        self._finish(i, ret)
        if self.todo and self.exit_code is None:
            self._hand_out(self._start())

    def _stop(self, signum: Optional[int]) -> None:
        """End every worker: ``signum`` first to the busy ones (they mark their folders), then None
        down the pipe; whatever is still alive after ``STOP_WAIT_S`` is killed."""
        for proc, (conn, job) in list(self.workers.items()):
            if signum is not None and job is not None and proc.is_alive():
                os.kill(proc.pid, signum)
            try:
                conn.send(None)
            except (OSError, ValueError):
                pass
        for proc, (conn, _) in list(self.workers.items()):
            proc.join(STOP_WAIT_S)
            if proc.is_alive():
                proc.kill()
                proc.join(5)
            conn.close()
        self.workers.clear()
