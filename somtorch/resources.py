"""Memory and time a run will need, predicted from sizes alone, checked before any work.

:func:`estimate` is a pure function of the sizes of a job (image, valid and training pixels,
feature dimension D, neurons K, members E, epochs, training rule, object-step stride). It models the
big tensors each stage holds at its peak:

* training: the batch map's neighbourhood matrix ``(E, K, K)`` float32 (three of them: the
  neighbourhood function's temporaries), the weights and their sums
  ``(E, K, D + 1)`` (a few copies), and for the online / mini-batch rules the per-member sample order
  ``(E, N_train)`` int64 and one block of samples ``(E, S, D)``;
* labelling (BMU of every pixel): the label maps ``(E, H, W)`` int64 plus the BMU indices
  ``(E', N)`` int64 of one group of members, scattered into them;
* object step: the label maps (still held) plus two strided copies ``(E, H/s, W/s)`` int64 (measured:
  the sampled maps and one more copy of them) and the
  per-map work buffers (``~64 B`` per read pixel);
* the errors of the trained maps (their time counted with the labelling): the top-2 BMUs of the
  training pixels ``(E, N_train, 2)`` int64
  and their masks (the label maps still held);
* several maps per run (``maps``, ``PipelineConfig.consensus``): the sets of ``E`` maps run one
  after another, and each set done is held until the consensus — its label maps as int16 and one
  boolean reduced map per member — so every stage also holds the sets before it.

The peak is the largest stage plus what every stage holds (features, scene, chunk buffers). It
is the memory *added* to the process that calls it (the imported libraries are already resident),
so it is compared with the memory still available: ``MemAvailable`` of ``/proc/meminfo``, capped by
the cgroup limit (v2 ``memory.max − memory.current``, v1 ``memory.limit_in_bytes −
memory.usage_in_bytes``). Measured on small real runs (``tests/test_resources.py``) the estimate is
an upper bound of the measured peak RSS increase and at most 2.5× it for whole pipeline runs that
hold more than ~150 MB (labelling- and object-step-bound); the training term over-estimates the
current batch engine (a shared neighbourhood table) several-fold on large grids.

Times are typical, not bounds (per-element costs fitted on one thread of a 2-core CPU with the
native kernel; a study's jobs come out at 0.6-2x their measured time; without the kernel — no
compiler, ``SOMTORCH_NATIVE=0`` — the torch path's own costs, 50-100x higher, fitted on a loaded
machine): they refuse the absurd (``train.epochs=1000000000``), not the merely long, and give a
sweep its time estimate. Ground plane and features are not counted (0.1-0.2 s a scene, unloaded).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from .validation import SomtorchError

__all__ = ["Estimate", "ResourceError", "available_memory", "check", "combine", "estimate", "fmt_bytes", "fmt_seconds"]

GIB = 1 << 30
_FIXED = 192 << 20  # allocator slack, chunk buffers of the BMU search (16 MiB of scores, a few of them); the
# whole-suite runs that measured 739, 808 and 864 MB for ensemble 40 on every pixel (against 731-832 MB
# estimated) read ru_maxrss, which keeps the xdist parent's size across exec: its own memory is 370-380 MB
_CHUNK = 1 << 22  # somtorch.core.distance.DEFAULT_CHUNK_ELEMENTS
_BLOCK = 4096  # somtorch.core.training.BLOCK_STEPS
# seconds per unit of work: one thread of the 2-core development CPU with the native kernel, fitted
# to the stage timings of the 32 jobs of `somtorch-study +experiment=table1` (two jobs side by side,
# one thread each; estimate / measured per job: docs/scaling.md §11)
_T_BATCH = 7e-11  # per member x training pixel x neuron, one epoch of the batch map
_T_KK = 5e-10  # per member x neuron², one batch-map update (neighbourhood product)
_T_ONLINE = 1.5e-9  # per member x step x neuron, online rule (members in vector lanes)
_T_STEP = 3e-7  # per step, the schedule and the kernel's per-step work
# the online rule without the compiled loop (no C++ compiler, SOMTORCH_NATIVE=0, a neighbourhood
# other than the Gaussian, a GPU): a few torch calls per step from Python. Measured 2026-12-03
# under a load average of 9 on the 2 cores: 47-80 us a step for one member of 64 neurons,
# 132 us for 10 members of 256 (SOM.fit); the issue-34 trial: 57 s for 1000 epochs of 2,800 steps
_T_STEP_TORCH = 2e-5  # per step
_T_ONLINE_TORCH = 1e-8  # per member x step x neuron
# the batch map without the fused kernel (distances, argmin and sums in torch): 33 ms an epoch of
# 20 members x 2,800 pixels x 64 neurons, measured 2026-12-03 under a load average of 10
_T_BATCH_TORCH = 8e-9  # per member x training pixel x neuron, one epoch
_T_EPOCH = 2.5e-4  # per batch-map epoch: schedule, kernel launches, the update
_T_LABEL = 3e-10  # per member x pixel x neuron, BMU labelling
_T_ERRORS = 4.5e-8  # per member x training pixel, quantization and topographic errors (top-2 BMUs)
_T_OBJECT = 3e-8  # per member x pixel read by the object step
_T_MEMBER = 4e-3  # per member: object step bookkeeping, reduction
_T_MINISOM = 3e-5  # per member x step of the MiniSom (pure NumPy) baseline
_T_SUPERPIXEL = 2e-6  # per pixel of SLIC / Felzenszwalb


class ResourceError(SomtorchError, RuntimeError):
    """A job would need more memory or time than its budget; raised before any work."""


@dataclass(frozen=True)
class Estimate:
    """Predicted extra memory (bytes) per stage and the whole job's peak, and seconds per stage."""

    train_bytes: int
    label_bytes: int
    objects_bytes: int
    peak_bytes: int
    train_s: float
    label_s: float
    objects_s: float

    @property
    def seconds(self) -> float:
        """Expected seconds in all: training + labelling + object step."""
        return self.train_s + self.label_s + self.objects_s

    def times(self, n: int | float) -> Estimate:
        """The same job run ``n`` times one after another (same peak, ``n`` × the time)."""
        return Estimate(self.train_bytes, self.label_bytes, self.objects_bytes, self.peak_bytes,
                        self.train_s * n, self.label_s * n, self.objects_s * n)

    def describe(self) -> str:
        """The estimate in one line: peak memory by stage and the expected time."""
        return (f"~{fmt_bytes(self.peak_bytes)} peak (training {fmt_bytes(self.train_bytes)}, labelling "
                f"{fmt_bytes(self.label_bytes)}, objects {fmt_bytes(self.objects_bytes)}), ~{fmt_seconds(self.seconds)}")


def estimate(*, height: int, width: int, valid: int, train: int, dim: int = 3, units: int = 64, members: int = 1,
             epochs: int = 10, mode: str = "batch", batch_size: int = 256, map_stride: int = 1,
             method: str = "som", iterations: int = 20, metrics: bool = True, native: bool = True,
             maps: int = 1) -> Estimate:
    """Predicted peak memory and time of one pipeline call (see the module docstring).

    Args:
        height, width: the map, px. valid: pixels segmented (≤ H·W). train: training pixels.
        dim: features per pixel D. units: neurons K (k-means centres). members: E.
        epochs, mode, batch_size: the SOM's training (``mode`` online / batch / minibatch).
        map_stride: the object step reads every ``map_stride``-th pixel in y and x.
        method: the segmenter (``som``, ``minisom``, ``kmeans``, ``slic``, ``felzenszwalb``).
        iterations: k-means iterations.
        metrics: the quantization and topographic errors are computed (``run_pipeline(metrics=True)``).
        native: the compiled kernels serve the training (``somtorch.core.native``: the online
            loop, the batch map's fused search and sums); False: the torch path, 50-100x slower.
        maps: maps per run (``PipelineConfig.consensus``): trained and read by the object step one
            set of E after another; each set done is held (int16 labels, its reduced maps) until
            the consensus is taken.

    >>> e = estimate(height=500, width=741, valid=343_274, train=1_979, members=400, map_stride=2)
    >>> 1.6 < e.peak_bytes / 2**30 < 2.5  # measured: 1.6 GiB
    True
    """
    hw, n, nt, e, k, d = height * width, valid, train, members, units, dim
    feats = n * (d * 4 + 16) + nt * d * 4 + hw * 12  # features, pixel coordinates, the scene's maps
    if method in ("slic", "felzenszwalb"):
        train_b, train_s = hw * 32, hw * _T_SUPERPIXEL
    elif method == "kmeans":
        train_b = e * nt * 8 + e * k * (d + 1) * 16 + min(e * nt * k, _CHUNK) * 4 * 3
        train_s = iterations * e * nt * k * _T_BATCH
    else:
        weights = e * k * (d + 1) * 4 * 4  # weights, sums, target, the product's input
        if mode == "batch":
            # the neighbourhood's (E, K, K) and its temporaries, or the BMU bounds' (E, K, K) float64
            # unit distances (somtorch.core.bounds): an upper bound, 5-30x the measured peak of the
            # shared-table engine on a 32 x 32 grid (tests/test_resources.py)
            train_b = weights + e * k * k * 4 * 3
            train_s = epochs * (e * nt * k * (_T_BATCH if native else _T_BATCH_TORCH) + e * k * k * _T_KK + _T_EPOCH)
        elif mode == "minibatch":
            steps = max(1, epochs * nt // batch_size)
            train_b = weights + e * k * k * 4 * 3 + e * nt * 8 + e * batch_size * d * 4
            train_s = epochs * e * nt * k * _T_BATCH + steps * (e * k * k * _T_KK + _T_STEP)
        else:  # online: one block of S steps' samples and schedule values per member
            s = min(_BLOCK, epochs * nt)
            train_b = weights + e * nt * 8 + e * s * (d + 2) * 4 + e * k * d * 4
            train_s = epochs * nt * ((_T_STEP + e * k * _T_ONLINE) if native else
                                     (_T_STEP_TORCH + e * k * _T_ONLINE_TORCH))
        if method == "minisom":
            train_s = e * epochs * nt * _T_MINISOM
        train_b += min(e * nt * k, _CHUNK) * 4 * 3  # one chunk of distances (and its argmin)
    per = min(e, max(1, (1 << 27) // max(1, n * k)))  # somtorch.tasks.segmentation.members_per_call
    # the sets of maps done, held for the consensus: int16 labels and a boolean reduced map per member
    # (5 bytes a pixel with the allocator's slack, measured: tests/test_resources.py)
    held = (maps - 1) * e * hw * 5
    label_b = held + e * hw * 8 + per * n * 8 + min(per * n * k, _CHUNK) * 4 * 3
    label_s = maps * e * n * k * _T_LABEL + (e * nt * _T_ERRORS if metrics and method in ("som", "minisom")
                                             else 0.0)
    read = math.ceil(height / map_stride) * math.ceil(width / map_stride)
    objects_b = held + e * hw * 8 + (e * read * 8 * 2 if map_stride > 1 else 0) + read * 64 + hw * 24
    objects_s = maps * e * (read * _T_OBJECT + _T_MEMBER)
    # quantization / topographic error of the trained maps: top-2 BMUs (E, N_train, 2) int64 and masks
    metrics_b = ((maps * e * hw * 5 if maps > 1 else 0) + e * hw * 8  # every set held, the kept copied
                 + (e * nt * 36 if metrics and method in ("som", "minisom") else 0))
    peak = feats + _FIXED + max(train_b + held, label_b, objects_b, metrics_b)
    return Estimate(int(train_b), int(label_b), int(objects_b), int(peak), float(maps * train_s), float(label_s),
                    float(objects_s))


def combine(estimates: list[Estimate]) -> Estimate:
    """Jobs run one after another in one process: the largest peak, the summed time."""
    return Estimate(max(e.train_bytes for e in estimates), max(e.label_bytes for e in estimates),
                    max(e.objects_bytes for e in estimates), max(e.peak_bytes for e in estimates),
                    sum(e.train_s for e in estimates), sum(e.label_s for e in estimates),
                    sum(e.objects_s for e in estimates))


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def available_memory(root: str | os.PathLike = "/") -> tuple[int, str]:
    """``(bytes, where from)``: the memory a new allocation can still get.

    ``MemAvailable`` of ``/proc/meminfo``, capped by the cgroup's limit minus its usage (v2
    ``memory.max`` / ``memory.current``, v1 ``memory.limit_in_bytes`` / ``memory.usage_in_bytes``);
    ``root`` prefixes the paths (tests give a fake tree).
    """
    base = Path(root)
    avail, source = None, "MemAvailable"
    try:
        for line in (base / "proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except OSError:
        pass
    cg = base / "sys/fs/cgroup"
    for limit_f, usage_f, name in ((cg / "memory.max", cg / "memory.current", "cgroup v2 memory.max"),
                                   (cg / "memory/memory.limit_in_bytes", cg / "memory/memory.usage_in_bytes",
                                    "cgroup v1 memory.limit_in_bytes")):
        limit, usage = _read_int(limit_f), _read_int(usage_f)
        if limit is not None and limit < 1 << 60:  # "max" or a near-2^63 value: no limit
            free = max(0, limit - (usage or 0))
            if avail is None or free < avail:
                avail, source = free, f"{name} - usage"
            break
    if avail is None:
        return 0, "unknown"
    return avail, source


def check(est: Estimate, *, max_memory_frac: float = 0.8, max_hours: float = 24.0, what: str = "this run",
          available: tuple[int, str] | None = None) -> None:
    """Raise :class:`ResourceError` (one line: the estimate, the budget and the overrides) when ``est``
    needs more than ``max_memory_frac`` of the available memory or more than ``max_hours``."""
    avail, source = available if available is not None else available_memory()
    budget = int(max_memory_frac * avail)
    if avail > 0 and est.peak_bytes > budget:
        raise ResourceError(
            f"{what} needs {est.describe()}; more than the memory budget {fmt_bytes(budget)} "
            f"({max_memory_frac:g} x {fmt_bytes(avail)} available, {source}): use fewer members or pixels, or "
            f"override with resources.max_memory_frac=... or resources.check=false")
    if est.seconds > max_hours * 3600:
        raise ResourceError(
            f"{what} needs {est.describe()}; more than the time budget of {max_hours:g} h: use fewer epochs, "
            f"members or pixels, or override with resources.max_hours=... or resources.check=false")


def fmt_bytes(b: float) -> str:
    """A byte count for people: GiB, MiB or bytes."""
    for unit, size in (("GiB", GIB), ("MiB", 1 << 20)):
        if b >= size:
            return f"{b / size:.1f} {unit}"
    return f"{b / 1024:.0f} KiB"


def fmt_seconds(s: float) -> str:
    """A duration for people: seconds up to years."""
    if s >= 86400 * 365:
        return f"{s / (86400 * 365):.2g} years"
    if s >= 86400:
        return f"{s / 86400:.1f} days"
    if s >= 3600:
        return f"{s / 3600:.1f} h"
    if s >= 60:
        return f"{s / 60:.1f} min"
    return f"{s:.1f} s"
