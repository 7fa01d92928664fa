"""Console entry points (``somtorch-run`` …): ``--help`` answers before torch or Hydra is imported."""

from __future__ import annotations

import importlib

from .help import maybe_print_help


def _go(module: str) -> None:
    maybe_print_help(module)
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
