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
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

__all__ = ["Interrupted", "checkpoint", "deferred", "install", "note", "requested", "reset"]


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


_state = _State()


def _handler(signum: int, frame: object) -> None:
    first = _state.signum is None
    _state.signum = signum
    if not first or _state.defer == 0:
        raise Interrupted(signum, _state.where)


def install(signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> bool:
    """Route ``signals`` through the flag (see the module docstring); False (and nothing done)
    outside the main thread, where Python cannot install handlers."""
    if threading.current_thread() is not threading.main_thread():
        return False
    for s in signals:
        signal.signal(s, _handler)
    _state.installed = True
    return True


def reset() -> None:
    """Forget a pending request and the progress note (a new job in the same process)."""
    _state.signum, _state.where, _state.defer = None, "", 0


def requested() -> int | None:
    """The pending signal's number, or None."""
    return _state.signum


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
