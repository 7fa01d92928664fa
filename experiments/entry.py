"""Console entry points (``somtorch-run`` …): signals answered from the first instruction, and
``--help`` before torch or Hydra is imported.

:func:`answer_signals_at_startup` runs first: until the command has loaded somtorch and installed
its own handler (:mod:`somtorch.interrupt`, in :func:`experiments.cli.run_checked`), SIGINT and
SIGTERM end the process with one line (``interrupted (SIGINT) during start-up``) and 130 / 143:
nothing has been written yet, so there is nothing to clean, and an import cut half-way must not
print its traceback.
"""

from __future__ import annotations

import os
import signal

STARTUP = "during start-up"


def _startup_handler(signum: int, frame: object) -> None:
    name = signal.Signals(signum).name
    try:
        os.write(2, f"interrupted ({name}) {STARTUP}\n".encode())
    finally:
        os._exit(128 + signum)


def answer_signals_at_startup() -> None:
    """Until the command installs its own handler: SIGINT / SIGTERM print one line and exit."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, _startup_handler)


def start(module: str) -> None:
    """The first thing a command does: answer signals, then ``--help`` (which exits) if asked."""
    answer_signals_at_startup()
    from .help import maybe_print_help

    maybe_print_help(module)


def _go(module: str) -> None:
    import importlib

    start(module)
    importlib.import_module(f".{module}", __package__).cli()


def run() -> None:
    _go("run")


def study() -> None:
    _go("study")


def validate() -> None:
    _go("validate")


def scenes() -> None:
    _go("real_scenes")


def video() -> None:
    _go("video")


def synth() -> None:
    _go("synth")


def train_baseline() -> None:
    _go("train_baseline")
