"""The worker processes of the somtorch launcher (:mod:`.launcher`): one pipe each, jobs handed out
one at a time, results, exits and deaths collected in the launching process.

(A leading underscore: Hydra's plugin scan skips this module; the workers import it by name.)
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import pickle
import signal
import sys
import threading
from typing import Any, Optional

from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, filter_overrides, run_job, setup_globals
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig

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


def _serve(conn: Any, task: tuple[str, str], loader: bytes, state: bytes) -> None:
    """A worker: run the composed configs that arrive on ``conn`` until None (or the pipe closes)."""
    from hydra._internal.callbacks import Callbacks
    from hydra.core.plugins import Plugins
    from tqdm.std import tqdm

    # tqdm's default write lock is a multiprocessing semaphore; a worker shows no bars, and a worker
    # killed while holding one leaves the resource tracker a "leaked semaphore" warning
    tqdm.set_lock(threading.RLock())
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
        config = pickle.loads(msg)
        HydraConfig.instance().set_config(config)
        try:
            ret = run_job(hydra_context=context, task_function=task_function, config=config,
                          job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
        except SystemExit as e:  # the job's one-line error or an interrupt: it has said why
            conn.send(("exit", e.code if isinstance(e.code, int) else 1))
            return
        except BaseException as e:  # noqa: BLE001 - a signal outside the job's handler
            conn.send(("exit", 128 + int(getattr(e, "signum", signal.SIGINT))))
            return
        conn.send(("done", pickle.dumps(_portable(ret))))


class Pool:
    """The workers of one launch: one pipe each, jobs handed out one at a time."""

    def __init__(self, launcher: Any, configs: list[DictConfig], plan: Any, bar: Any) -> None:
        assert launcher.hydra_context is not None and launcher.task_function is not None
        self.launcher, self.configs, self.plan, self.bar = launcher, configs, plan, bar
        self.callbacks = launcher.hydra_context.callbacks
        self.args = (_task_reference(launcher.task_function), pickle.dumps(launcher.hydra_context.config_loader),
                     pickle.dumps(Singleton.get_state()["instances"]))
        self.ctx = multiprocessing.get_context("spawn")
        self.workers: dict[Any, tuple[Any, Optional[int]]] = {}  # process -> (pipe, job position or None)
        self.results: list[Optional[JobReturn]] = [None] * len(configs)
        self.todo = list(plan.order)
        self.exit_code: Optional[int] = None

    def _start(self) -> None:
        parent, child = self.ctx.Pipe()
        proc = self.ctx.Process(target=_serve, args=(child, *self.args), daemon=True)
        old = os.environ.get(ENV_PROGRESS)
        os.environ[ENV_PROGRESS] = "0"  # inherited by the spawned worker only
        try:
            proc.start()
        finally:
            if old is None:
                os.environ.pop(ENV_PROGRESS, None)
            else:
                os.environ[ENV_PROGRESS] = old
        child.close()
        self.workers[proc] = (parent, None)

    def _hand_out(self, proc: Any) -> None:
        conn, _ = self.workers[proc]
        if not self.todo or self.exit_code is not None:
            self.workers[proc] = (conn, None)
            return
        i = self.todo.pop(0)
        self.callbacks.on_job_start(config=self.configs[i], task_function=self.launcher.task_function)
        conn.send(pickle.dumps(self.configs[i]))
        self.workers[proc] = (conn, i)

    def _finish(self, i: int, ret: JobReturn) -> None:
        self.results[i] = ret
        self.callbacks.on_job_end(config=self.configs[i], job_return=ret)
        self.bar.update()

    def run(self) -> list[JobReturn]:
        from multiprocessing.connection import wait

        from somtorch import interrupt

        interrupt.install()  # SIGINT / SIGTERM here raise Interrupted at once (no deferred region)
        try:
            for _ in range(self.plan.workers):
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

    def _collect(self, proc: Any) -> None:
        conn, i = self.workers[proc]
        assert i is not None
        try:
            kind, value = conn.recv() if conn.poll() else ("died", None)
        except (EOFError, OSError):
            kind, value = "died", None
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
            self._start()
            self._hand_out(list(self.workers)[-1])

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
