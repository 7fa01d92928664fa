"""Shared helpers of the benchmark scripts: timing, machine description, tables, JSON output.

Not part of the library (``somtorch`` never imports ``benchmarks``). The scripts print to stdout on
purpose: a benchmark's output *is* its result.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shlex
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch

REPO_ROOT = Path(__file__).resolve().parent.parent


# ----------------------------------------------------------------------------------------- timing
@dataclass
class Timing:
    """Wall-clock seconds of the timed repeats (warm-up excluded)."""

    times_s: list[float]

    @property
    def median(self) -> float:
        return statistics.median(self.times_s)

    @property
    def min(self) -> float:
        return min(self.times_s)

    def as_dict(self) -> dict[str, Any]:
        return {"median_s": self.median, "min_s": self.min, "repeats": len(self.times_s),
                "times_s": list(self.times_s)}


def measure(fn: Callable[[Any], Any], *, repeats: int, warmup: int = 1,
            setup: Callable[[], Any] | None = None,
            warmup_fn: Callable[[Any], Any] | None = None) -> Timing:
    """Median-ready timings of ``fn(setup())``; ``setup`` (untimed) prepares a fresh state per call.

    ``warmup`` untimed calls run first, with ``warmup_fn`` when given (a shorter call that touches the
    same code paths, for rows whose single run takes seconds).
    """
    for _ in range(warmup):
        (warmup_fn or fn)(setup() if setup else None)
    times = []
    for _ in range(repeats):
        arg = setup() if setup else None
        t0 = time.perf_counter()
        fn(arg)
        times.append(time.perf_counter() - t0)
    return Timing(times)


# ------------------------------------------------------------------------------------ machine info
def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def package_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def loadavg() -> tuple[float, float, float] | None:
    try:
        return os.getloadavg()
    except OSError:
        return None


def machine_info() -> dict[str, Any]:
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    return {
        "cpu_model": cpu_model(),
        "logical_cpus": os.cpu_count(),
        "cpus_usable": affinity,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "torch_interop_threads": torch.get_num_interop_threads(),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "env": {k: os.environ[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
                if k in os.environ},
        "loadavg_start": loadavg(),
    }


def command_line() -> str:
    """The command that reproduces this run (as typed, relative to the repository root)."""
    args = list(sys.argv)
    script = Path(args[0]).resolve()
    try:
        args[0] = str(script.relative_to(REPO_ROOT))
    except ValueError:
        args[0] = str(script)
    return shlex.join(["python", *args])


def header(title: str, info: dict[str, Any], extra: Sequence[str] = ()) -> str:
    la = info["loadavg_start"]
    load = (f"{la[0]:.2f} {la[1]:.2f} {la[2]:.2f} (1/5/15 min) on {info['cpus_usable']} usable CPUs"
            if la else "unavailable")
    lines = [
        f"$ {command_line()}",
        f"# {title}",
        f"# cwd: {REPO_ROOT}",
        f"# date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}",
        f"# CPU: {info['cpu_model']} | {info['logical_cpus']} logical CPUs, {info['cpus_usable']} usable",
        f"# torch {info['torch']} | intra-op threads {info['torch_threads']}, "
        f"inter-op {info['torch_interop_threads']} | numpy {info['numpy']} | Python {info['python']}",
        f"# thread env: {info['env'] or 'none set'}",
        f"# load average at start: {load}",
        *[f"# {e}" for e in extra],
    ]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ tables
def table(headers: Sequence[str], rows: Sequence[Sequence[Any]], align: str | None = None) -> str:
    """A plain-text table; ``align`` holds one of ``l``/``r`` per column (default: first left)."""
    cells = [[str(h) for h in headers]] + [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    align = align or "l" + "r" * (len(headers) - 1)

    def line(r: list[str]) -> str:
        return "  ".join(c.ljust(w) if a == "l" else c.rjust(w) for c, w, a in zip(r, widths, align))

    sep = "  ".join("-" * w for w in widths)
    return "\n".join([line(cells[0]), sep, *[line(r) for r in cells[1:]]])


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        return f"{v:.3g}" if abs(v) < 1e-3 or abs(v) >= 1e5 else f"{v:.4g}"
    return str(v)


def ms(seconds: float | None) -> str:
    return "-" if seconds is None else f"{seconds * 1e3:,.1f} ms"


def secs(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    return f"{seconds * 1e3:,.1f} ms" if seconds < 1.0 else f"{seconds:,.3f} s"


# ------------------------------------------------------------------------------------------ output
@dataclass
class Report:
    """Everything a script writes with ``--json``."""

    benchmark: str
    command: str
    quick: bool
    machine: dict[str, Any]
    settings: dict[str, Any]
    results: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    wall_s: float | None = None

    def write(self, path: str | os.PathLike) -> Path:
        path = Path(path).expanduser()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=2, default=_json_default) + "\n")
        tmp.replace(path)
        return path


def _json_default(o: Any) -> Any:
    if isinstance(o, Timing):
        return o.as_dict()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, (Path, torch.dtype)):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def verdict(ok: bool | None) -> str:
    return "n/a" if ok is None else ("PASS" if ok else "FAIL")
