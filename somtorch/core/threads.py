"""How many CPU threads a somtorch process should use.

torch starts one intra-op thread per core it sees, ignoring a container's or a SLURM job's CPU
quota and any sibling jobs the same launcher started. On a shared node that over-subscription is
what turns a 4 ms BMU search into a 60 ms one: a parallel region waits for its slowest thread,
and a thread that shares its core with another process is descheduled for whole time slices.
:func:`configure` sets torch's thread count (which the native kernels follow) from the cores that
are actually this process's:

1. an explicit count: ``SOMTORCH_THREADS``, else ``OMP_NUM_THREADS`` (its first entry);
2. else the CPUs of the process's affinity mask (``taskset``, SLURM's ``--cpus-per-task``,
   ``docker --cpuset-cpus``), capped by the cgroup CPU quota (``docker --cpus``, Kubernetes
   limits; cgroup v2 ``cpu.max`` or v1 ``cpu.cfs_quota_us``), rounded up;
3. divided by the number of jobs a launcher runs side by side on the machine (``jobs``), at least 1.

The experiment entry points call it once at start-up (a joblib / Ray sweep passes its number of
parallel jobs); library code never changes torch's thread count on its own, so a caller's
``torch.set_num_threads`` is honoured.

The native kernels go one step further (:func:`kernel_threads`): at most torch's count, and no
more than the cores that *other* processes left free over the last fraction of a second —
measured, on Linux, as the busy time of the CPUs in the affinity mask (``/proc/stat``) minus this
process's own CPU time. With another job busy on one of two cores a kernel then runs one thread
instead of two, and does not wait a scheduler time slice at every barrier for a thread that shares
its core. ``SOMTORCH_THREADS`` fixes the count and turns this off.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ENV_THREADS = "SOMTORCH_THREADS"
CGROUP_ROOT = Path("/sys/fs/cgroup")
logger = logging.getLogger(__name__)
_warned: set[tuple[str, str]] = set()


def _positive_int(text: str | None) -> int | None:
    if not text:
        return None
    head = text.split(",")[0].strip()  # OMP_NUM_THREADS may list one count per nesting level
    try:
        value = int(head)
    except ValueError:
        return None
    return value if value > 0 else None


def env_threads() -> int | None:
    """The thread count the environment asks for (``SOMTORCH_THREADS``, then ``OMP_NUM_THREADS``);
    a value that is not a positive integer is ignored with one warning naming the variable."""
    for name in (ENV_THREADS, "OMP_NUM_THREADS"):
        raw = os.environ.get(name)
        value = _positive_int(raw)
        if value is not None:
            return value
        if raw and raw.strip() and (name, raw) not in _warned:
            _warned.add((name, raw))
            logger.warning("%s=%r is not a positive number of threads; ignored", name, raw)
    return None


def affinity_cores() -> int:
    """CPUs this process may run on (its affinity mask; ``os.cpu_count()`` where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _own_cgroup_dirs(root: Path) -> list[Path]:
    """The process's cgroup folders, innermost first, then the root (v2 and v1 ``cpu`` controller)."""
    dirs: list[Path] = []
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        lines = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, rel = parts
        rel = rel.lstrip("/")
        if controllers == "":  # cgroup v2
            base = root
        elif "cpu" in controllers.split(","):
            base = root / controllers if (root / controllers).is_dir() else root / "cpu"
        else:
            continue
        path = base / rel if rel else base
        while True:
            dirs.append(path)
            if path == base or path.parent == path:
                break
            path = path.parent
    dirs += [root, root / "cpu", root / "cpu,cpuacct"]
    return dirs


def cgroup_cpu_limit(root: Path = CGROUP_ROOT) -> float | None:
    """The CPU quota of the process's cgroup in cores (e.g. 1.5), or None when there is none."""
    limits = []
    for folder in _own_cgroup_dirs(root):
        try:
            text = (folder / "cpu.max").read_text().split()
            if len(text) == 2 and text[0] != "max":
                limits.append(int(text[0]) / int(text[1]))
            continue
        except (OSError, ValueError, ZeroDivisionError):
            pass
        try:
            quota = int((folder / "cpu.cfs_quota_us").read_text())
            period = int((folder / "cpu.cfs_period_us").read_text())
            if quota > 0 and period > 0:
                limits.append(quota / period)
        except (OSError, ValueError):
            pass
    return min(limits) if limits else None


def available_cores(root: Path = CGROUP_ROOT) -> int:
    """Cores this process can actually use: its affinity mask capped by the cgroup quota."""
    cores = affinity_cores()
    limit = cgroup_cpu_limit(root)
    if limit is not None:
        cores = min(cores, max(1, math.ceil(limit - 1e-9)))
    return cores


def auto_threads(jobs: int = 1) -> int:
    """The thread count for one of ``jobs`` processes sharing this machine (see the module doc)."""
    explicit = env_threads()
    if explicit is not None:
        return explicit
    jobs = max(1, int(jobs))
    return max(1, available_cores() // jobs)


def configure(threads: int | None = None, jobs: int = 1) -> int:
    """Set torch's intra-op threads to ``threads`` (None = :func:`auto_threads`) and return it."""
    import torch

    n = auto_threads(jobs) if threads is None else max(1, int(threads))
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


class FreeCoreMonitor:
    """Cores of the affinity mask that other processes left idle, estimated over a sliding window.

    :meth:`free` re-samples when the last sample is at least ``window_s`` old (a read of
    ``/proc/stat`` and ``os.times()``, about 30 µs) and otherwise returns the last estimate, so a
    kernel call pays nothing measurable. None where ``/proc/stat`` is unavailable.
    """

    def __init__(self, window_s: float = 0.2) -> None:
        self.window_s = window_s
        self._lock = threading.Lock()
        self._last: tuple[float, float, float] | None = None
        self._free: int | None = None
        try:
            self._tick = float(os.sysconf("SC_CLK_TCK"))
        except (AttributeError, ValueError, OSError):
            self._tick = 100.0

    def _sample(self) -> tuple[float, float, float] | None:
        """(monotonic seconds, busy CPU-seconds of the mask's CPUs, this process's CPU-seconds)."""
        try:
            mask = os.sched_getaffinity(0)
            busy = 0
            with open("/proc/stat", encoding="ascii") as f:
                for line in f:
                    if not line.startswith("cpu"):
                        break
                    name, *vals = line.split()
                    if name == "cpu" or int(name[3:]) not in mask:
                        continue
                    v = [int(x) for x in vals[:8]]  # user nice system idle iowait irq softirq steal
                    busy += v[0] + v[1] + v[2] + v[5] + v[6] + v[7]
        except (AttributeError, OSError, ValueError, IndexError):
            return None
        t = os.times()
        return time.monotonic(), busy / self._tick, t.user + t.system

    def free(self, cores: int) -> int | None:
        """Estimated free cores (1 … ``cores``), or None before the first full window / off Linux."""
        now = time.monotonic()
        with self._lock:
            if self._last is not None and now - self._last[0] < self.window_s:
                return self._free
            sample = self._sample()
            if sample is None:
                return None
            if self._last is not None:
                wall = sample[0] - self._last[0]
                others = ((sample[1] - self._last[1]) - (sample[2] - self._last[2])) / wall
                self._free = int(min(cores, max(1, math.floor(cores - max(0.0, others) + 0.5))))
            self._last = sample
            return self._free


_monitor = FreeCoreMonitor()
_cores: int | None = None  # available_cores(), read once per process


def _after_fork() -> None:
    """A forked child has its own CPU time and may have another affinity: start over."""
    global _monitor, _cores
    _monitor, _cores = FreeCoreMonitor(), None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)


def kernel_threads() -> int:
    """Threads for one native-kernel call: torch's count, capped by the cores other processes left free.

    ``SOMTORCH_THREADS`` (explicit) is used as it is.
    """
    import torch

    n = torch.get_num_threads()
    explicit = _positive_int(os.environ.get(ENV_THREADS))
    if explicit is not None or n <= 1:
        return n
    global _cores
    if _cores is None:
        _cores = available_cores()
    free = _monitor.free(_cores)
    return n if free is None else max(1, min(n, free))


@contextmanager
def contended() -> Iterator[int]:
    """Inside the block torch runs at most :func:`kernel_threads` threads (restored on exit).

    Used around SOM training and labelling, whose torch operations (element-wise maps, batched
    products of one member each) give the same bits for any thread count (tests/core check it),
    so a busy machine changes the speed, never the result.
    """
    import torch

    before = torch.get_num_threads()
    n = kernel_threads()
    if n < before:
        torch.set_num_threads(n)
    try:
        yield n
    finally:
        if n < before:
            torch.set_num_threads(before)
