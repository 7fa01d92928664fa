"""The per-run warnings of a command that runs the pipeline thousands of times, kept out of the console.

``somtorch-validate`` scores every candidate on every frame: a map whose kept areas cover it all,
a member without a convincing object, a stride too coarse for a small map each warn once per
pipeline call — 346 lines in 5 minutes, none of which a user acts on (the scores record them).
:func:`warnings_to_file` sends the WARNING records of the pipeline's loggers (in this process and,
through :func:`worker_start`, in the worker processes) to one file in the output folder, and
prints one line at the end: how many there were and where they are.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator
from pathlib import Path

NOISY = ("somtorch.pipeline", "somtorch.disparity", "somtorch.tasks", "somtorch.segmenters")
FORMAT = "[%(asctime)s][%(process)d][%(name)s][%(levelname)s] - %(message)s"


def _route(path: Path) -> list[tuple[logging.Logger, logging.Handler, bool]]:
    handler = logging.FileHandler(path, mode="a", encoding="utf-8", delay=True)
    handler.setFormatter(logging.Formatter(FORMAT))
    handler.setLevel(logging.WARNING)
    routed = []
    for name in NOISY:
        lg = logging.getLogger(name)
        routed.append((lg, handler, lg.propagate))
        lg.addHandler(handler)
        lg.propagate = False
    return routed


def worker_start(path: str) -> None:
    """In a worker process (a pool's initializer): its pipeline warnings go to ``path`` only."""
    _route(Path(path))


def _count(path: Path) -> int:
    try:
        with path.open(encoding="utf-8", errors="replace") as f:
            return sum(1 for line in f if "][WARNING] - " in line)
    except FileNotFoundError:
        return 0


@contextlib.contextmanager
def warnings_to_file(path: Path, what: str) -> Iterator[None]:
    """Inside the block, the pipeline's warnings go to ``path``; after it (if it ends normally), one
    line on stderr (``what: N warnings of the scored runs (...) in path``) if there were any."""
    path.parent.mkdir(parents=True, exist_ok=True)
    before = _count(path)
    routed = _route(path)
    try:
        yield
    finally:  # (an error or an interrupt says its own one line: no count then)
        for lg, handler, propagate in routed:
            lg.removeHandler(handler)
            lg.propagate = propagate
        routed[0][1].close()
    n = _count(path) - before
    if n:
        print(f"{what}: {n} warning(s) of the scored runs (maps kept whole, no object, maps that disagree, "
              f"strides adjusted) in {path}", file=sys.stderr, flush=True)
