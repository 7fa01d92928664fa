"""Stopping a run cleanly on SIGINT (Ctrl-C) or SIGTERM (``kill``, a scheduler's pre-emption).

A signal handler installed by :func:`install` (the command-line entry points call it) does not
raise where the signal happens to land. Inside the long loops (training epochs and blocks, BMU
chunks, the object step's members: regions marked with :func:`deferred`) it only sets a flag, and
the loop raises :class:`Interrupted` at its next :func:`checkpoint`, a fraction of a second later;
elsewhere it raises at once. A second signal always raises at once. The exception carries the
signal and where the run was (``"after epoch 3/10"``), so that the caller can print one line, mark
its output folder and exit with ``128 + signal`` (130 for SIGINT, 143 for SIGTERM).

Without :func:`install` (the library used from Python) nothing changes: Ctrl-C raises
``KeyboardInterrupt`` as usual, and :func:`checkpoint` costs one attribute read.

:func:`worker_pool` is the process pool of the commands that farm work out (``somtorch-validate``,
``somtorch-synth``, tiled runs): its workers leave SIGINT to the parent (a terminal's Ctrl-C reaches
the whole process group), and a signal or an error in the parent cancels the queued jobs and
ends the workers at once, instead of waiting for every pending job (``ProcessPoolExecutor``'s
``with`` block) and leaving idle workers behind.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

__all__ = ["Interrupted", "checkpoint", "deferred", "install", "leave_to_parent", "note", "requested", "reset",
           "where", "worker_pool"]


class Interrupted(BaseException):
    """The run was asked to stop by a signal (a ``BaseException``: ``except Exception`` lets it through).

    Attributes:
        signum: the signal number. where: the last progress note (``"after epoch 3/10"``).
    """

    def __init__(self, signum: int, where: str) -> None:
        self.signum, self.where = signum, where
        super().__init__(f"interrupted ({self.signal_name}) {where}".strip())

    @property
    def signal_name(self) -> str:
        """The signal's name (``SIGINT``, ``SIGTERM``), or ``signal <n>`` when it has none."""
        try:
            return signal.Signals(self.signum).name
        except ValueError:
            return f"signal {self.signum}"

    @property
    def exit_code(self) -> int:
        """The shell's exit status for the signal: 128 + its number."""
        return 128 + self.signum


class _State:
    signum: int | None = None
    where: str = ""
    defer: int = 0
    installed: bool = False
    left: frozenset[int] = frozenset()  # signals this process leaves to its parent (leave_to_parent)
    hook: Callable[[Any], None] | None = None  # the sys.unraisablehook install() put in place


_state = _State()


def _handler(signum: int, frame: object) -> None:
    first = _state.signum is None
    _state.signum = signum
    if not first or _state.defer == 0:
        raise Interrupted(signum, _state.where)


def _unraisable(hook: Callable[[Any], None]) -> Callable[[Any], None]:
    """A ``sys.unraisablehook`` that says nothing of an :class:`Interrupted` raised where Python
    cannot pass an exception on — a weakref callback (the import system's module locks), a
    ``__del__`` — and hands everything else to ``hook``, the hook it replaces. Python would print
    "Exception ignored in …" and a traceback; the signal's flag is set by then, so the next
    :func:`checkpoint` (or a second signal) raises it where it stops the run, with its one line."""
    def unraisable(info: Any) -> None:
        if not isinstance(info.exc_value, Interrupted):
            hook(info)
    return unraisable


def install(signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> bool:
    """Route ``signals`` through the flag (see the module docstring); False (and nothing done)
    outside the main thread, where Python cannot install handlers. An :class:`Interrupted` that
    lands where Python only reports exceptions (a weakref callback during an import) is not
    printed: the pending flag stops the run at the next checkpoint."""
    if threading.current_thread() is not threading.main_thread():
        return False
    for s in signals:
        if s not in _state.left:
            signal.signal(s, _handler)
    if sys.unraisablehook is not _state.hook:  # once per hook in place (pytest swaps its own in and out)
        _state.hook = _unraisable(sys.unraisablehook)
        sys.unraisablehook = _state.hook
    _state.installed = True
    return True


def leave_to_parent(signals: tuple[int, ...] = (signal.SIGINT,)) -> None:
    """Ignore ``signals`` in this process, now and in every later :func:`install`: for a worker
    whose parent decides when it stops. A terminal's Ctrl-C reaches the whole process group, and
    the parent then sends the worker a signal of its own; a worker that also took the Ctrl-C would
    take that second signal as "stop at once" and could die while marking its output folder."""
    _state.left = _state.left | frozenset(signals)
    for s in signals:
        signal.signal(s, signal.SIG_IGN)


def reset() -> None:
    """Forget a pending request and the progress note (a new job in the same process)."""
    _state.signum, _state.where, _state.defer = None, "", 0


def requested() -> int | None:
    """The pending signal's number, or None."""
    return _state.signum


def where() -> str:
    """The last progress note (:func:`note`)."""
    return _state.where


def note(where: str) -> None:
    """Record how far the run got (``"after epoch 3/10"``, ``"during labelling"``) for the message."""
    _state.where = where


def checkpoint(where: str | None = None) -> None:
    """Record ``where`` (if given) and raise :class:`Interrupted` if a signal is pending."""
    if where is not None:
        _state.where = where
    if _state.signum is not None:
        raise Interrupted(_state.signum, _state.where)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A region whose loops call :func:`checkpoint`: a first signal only sets the flag there."""
    _state.defer += 1
    try:
        yield
    finally:
        _state.defer -= 1
    checkpoint()  # a signal that came after the region's last checkpoint


def _worker_start(initializer: Callable[..., Any] | None, initargs: tuple) -> None:
    leave_to_parent()  # the parent decides, and ends the workers
    # tqdm's default write lock is a multiprocessing semaphore: a worker terminated while it exists
    # leaves the resource tracker a "leaked semaphore" warning; a worker shows no bars anyway
    from tqdm.std import tqdm

    tqdm.set_lock(threading.RLock())
    if initializer is not None:
        initializer(*initargs)


@contextlib.contextmanager
def worker_pool(workers: int, initializer: Callable[..., Any] | None = None,
                initargs: tuple = ()) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` of ``workers`` spawned processes that an exception in the block
    (:class:`Interrupted`, ``KeyboardInterrupt``, an error) ends at once: the queued jobs are
    cancelled and the workers terminated (SIGTERM, then SIGKILL after 5 s) before it propagates.
    The workers ignore SIGINT. A block that ends normally waits for its jobs, as usual."""
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial
    from multiprocessing import get_context

    pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn"),
                               initializer=partial(_worker_start, initializer, tuple(initargs)))
    # start the workers now with SIGINT blocked: they inherit the mask, so a Ctrl-C to the process
    # group while they still import torch cannot print their tracebacks; a SIGINT that reaches this
    # process meanwhile stays pending and is delivered when the mask is restored
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        for _ in range(workers):  # one worker spawned per submit (in this thread) until the pool is full
            pool.submit(int)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
    try:
        yield pool
    except BaseException:
        procs = list((getattr(pool, "_processes", None) or {}).values())  # no public handle on them
        manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets it
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(5)
            if p.is_alive():
                p.kill()
                p.join()
        # the pool's manager thread closes its wake-up pipe once it sees the dead workers; were it
        # still running at exit, the interpreter's wake-up call could race that close and print
        # "Exception ignored ... Bad file descriptor" (CPython 3.11): let it finish first
        if manager is not None:
            manager.join(10)
        raise
    pool.shutdown(wait=True)
