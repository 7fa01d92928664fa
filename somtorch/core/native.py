"""Fused native BMU search on the CPU (optional, built on first use).

:func:`native_bmu` computes, for every member e and sample n, the argmin over the K neurons of the
exact squared distance ``Σ_d (x_nd − w_ekd)²`` (summed left to right in the input precision; first
index on ties, as ``torch.argmin``), and optionally the second-best neuron, without ever holding the
``N × E × K`` score matrix. :func:`native_accumulate` fuses that search with the batch-map sums and
counts. The kernel (``csrc/bmu.cpp``) is vectorised over samples and split over blocks of samples
(over members for the sums) with OpenMP; every (e, n) is computed by the same operations whatever
the thread count, the chunking or the ensemble size, so member e equals a solo map with that
member's weights.

The kernel is plain C++ with a C ABI (no torch headers, so it compiles in about 3 s), loaded
with :mod:`ctypes`. It is compiled on the first call with the system C++ compiler (``$CXX`` or
``c++``) into ``$SOMTORCH_CACHE_DIR`` (default ``$XDG_CACHE_HOME/somtorch/native`` or
``~/.cache/somtorch/native``) under a name that hashes the source, the compiler and the flags; an
``fcntl`` file lock keeps concurrent processes (pytest-xdist workers) from compiling twice, and the
library is moved into place atomically. ``-mavx2 -mfma`` are used only when the CPU reports both,
``-mavx512f`` (16 float32 lanes in the search kernels) when it also reports AVX-512 and
``SOMTORCH_NATIVE_AVX512`` is not ``0``.

:mod:`somtorch.core.label_stats` calls the same library's one pass over a label map (the object
step's segment statistics).

``native_bmu`` returns ``None`` whenever the kernel cannot serve the call — ``SOMTORCH_NATIVE=0``,
no compiler or a failed build (logged once as a warning), non-CPU tensors, dtypes other than
float32/float64, mixed dtypes, NaN weights (where ``torch.argmin`` would pick the NaN) — and callers
then use the torch path.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import torch

from .threads import kernel_threads

try:
    import fcntl
except ImportError:  # Windows: no lock; the atomic rename alone keeps concurrent builds correct
    fcntl = None

logger = logging.getLogger(__name__)

ENV_SWITCH = "SOMTORCH_NATIVE"  # "0" disables the native kernel
ENV_CACHE = "SOMTORCH_CACHE_DIR"
ENV_WIDE = "SOMTORCH_NATIVE_AVX512"  # "0": AVX2 vectors even where the CPU has AVX-512
SOURCE = Path(__file__).resolve().parent / "csrc" / "bmu.cpp"
ABI = 7  # must equal somtorch_bmu_abi() in csrc/bmu.cpp
BASE_FLAGS = ("-O3", "-std=c++17", "-shared", "-fPIC", "-ffp-contract=off")
BUILD_TIMEOUT_S = 300

_lock = threading.Lock()
_lib: ctypes.CDLL | None = None
_failed: str | None = None  # why the library is unavailable (set once)
_noted: set[str] = set()


def _note(reason: str, level: int = logging.DEBUG) -> None:
    """Log each distinct reason for not using the kernel once."""
    if reason not in _noted:
        _noted.add(reason)
        logger.log(level, "native BMU kernel not used: %s; using the torch path", reason)


def cache_dir() -> Path:
    """Where compiled kernels are kept."""
    if os.environ.get(ENV_CACHE):
        return Path(os.environ[ENV_CACHE])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "somtorch" / "native"


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _compiler() -> str | None:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _compile(cxx: str, flags: list[str], target: Path) -> str | None:
    """Compile SOURCE into ``target`` atomically; the compiler's message on failure, else None."""
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=target.stem + ".", suffix=".tmp.so")
    os.close(fd)
    try:
        proc = subprocess.run([cxx, *flags, str(SOURCE), "-o", tmp], capture_output=True, text=True,
                              timeout=BUILD_TIMEOUT_S)
        if proc.returncode != 0:
            return (proc.stderr or proc.stdout).strip()[-2000:] or f"exit status {proc.returncode}"
        os.replace(tmp, target)
        return None
    except (OSError, subprocess.SubprocessError) as exc:
        return str(exc)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _build() -> Path:
    """Path of the compiled library for this source, compiler and CPU, building it if needed."""
    cxx = _compiler()
    if cxx is None:
        raise RuntimeError("no C++ compiler found (set $CXX or install g++)")
    try:
        version = subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        raise RuntimeError(f"cannot run the C++ compiler {cxx}: {exc}") from exc
    flags = _cpu_flags()
    isa = ["-mavx2", "-mfma"] if {"avx2", "fma"} <= flags else []
    if isa and "avx512f" in flags and os.environ.get(ENV_WIDE, "1").strip() != "0":
        isa.append("-mavx512f")  # 16 float32 lanes for the search kernels (csrc/bmu.cpp kSearchBytes)
    variants = [[*BASE_FLAGS, *isa, "-fopenmp"], [*BASE_FLAGS, *isa]]  # without OpenMP: one thread
    src = SOURCE.read_bytes()
    folder = cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK):
            raise PermissionError(f"{folder} is not writable")
    except OSError:  # e.g. a read-only home: a per-user folder in the temporary directory
        user = os.getuid() if hasattr(os, "getuid") else os.getpid()
        folder = Path(tempfile.gettempdir()) / f"somtorch-native-{user}"
        folder.mkdir(parents=True, exist_ok=True)
    errors = []
    for flags in variants:
        key = hashlib.sha256(b"\0".join([src, cxx.encode(), version.encode(), " ".join(flags).encode(),
                                         sys.platform.encode()])).hexdigest()[:16]
        target = folder / f"bmu-{key}.so"
        if target.exists():
            return target
        with open(folder / f"bmu-{key}.lock", "w") as lock:
            if fcntl is not None:
                fcntl.flock(lock, fcntl.LOCK_EX)  # another process may be compiling this one
            if target.exists():
                return target
            err = _compile(cxx, flags, target)
        if err is None:
            if "-fopenmp" not in flags:
                logger.warning("native BMU kernel built without OpenMP (single-threaded): %s",
                               errors[-1][:300] if errors else "")
            return target
        errors.append(f"{cxx} {' '.join(flags)}: {err}")
    raise RuntimeError("building csrc/bmu.cpp failed:\n" + "\n".join(errors))


def _load() -> ctypes.CDLL:
    lib = ctypes.CDLL(str(_build()))
    lib.somtorch_bmu_abi.restype = ctypes.c_int
    if lib.somtorch_bmu_abi() != ABI:
        raise RuntimeError(f"library reports ABI {lib.somtorch_bmu_abi()}, expected {ABI}")
    p, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    for fn in (lib.somtorch_bmu_f32, lib.somtorch_bmu_f64):
        # x, x_stride, w, E, N, K, D, top, out, nthreads
        fn.argtypes = [p, i64, p, i64, i64, i64, i64, i32, p, i32]
        fn.restype = ctypes.c_int
    for fn in (lib.somtorch_accumulate_f32, lib.somtorch_accumulate_f64):
        # x, x_stride, w, E, N, K, D, sums, counts, nthreads
        fn.argtypes = [p, i64, p, i64, i64, i64, i64, p, p, i32]
        fn.restype = ctypes.c_int
    for fn in (lib.somtorch_bounded_f32, lib.somtorch_bounded_f64):
        # x, x_stride, w, E, N, K, D, c, u, l, drift, dmax, rho, alpha, grow, fresh, sums, counts, searched, nthreads
        fn.argtypes = [p, i64, p, i64, i64, i64, i64, p, p, p, p, p, ctypes.c_double, ctypes.c_double,
                       ctypes.c_double, i32, p, p, p, i32]
        fn.restype = ctypes.c_int
    for fn in (lib.somtorch_online_f32, lib.somtorch_online_f64):
        # w, x, x_stride, idx, idx_stride, coef, log_lr, grid_d2, E, S, K, D, nthreads
        fn.argtypes = [p, p, i64, p, i64, p, p, p, i64, i64, i64, i64, i32]
        fn.restype = ctypes.c_int
    # lab, H, W, K, wts, M, cont, groups, G, do_pairs, count, sums, box, pairs, cpairs, gcount
    lib.somtorch_label_stats.argtypes = [p, i64, i64, i64, p, i64, p, p, i64, i32, p, p, p, p, p, p]
    lib.somtorch_label_stats.restype = ctypes.c_int
    lib.somtorch_plane_counts.argtypes = [p, i64, p, p, p, i64, ctypes.c_float, p, p, p]
    lib.somtorch_plane_counts.restype = ctypes.c_int
    lib.somtorch_plane_band.argtypes = [p, p, p, i64, i64, ctypes.c_double, p, p, ctypes.c_int]
    lib.somtorch_plane_band.restype = ctypes.c_int
    return lib


def library() -> ctypes.CDLL | None:
    """The loaded kernel library, building it on the first call; None if that is impossible."""
    global _lib, _failed
    if _lib is not None or _failed is not None:
        return _lib
    with _lock:
        if _lib is None and _failed is None:
            try:
                _lib = _load()
            except Exception as exc:  # any failure here only means "use the torch path"
                _failed = f"{type(exc).__name__}: {exc}"
                _note(f"the kernel is unavailable ({_failed})", logging.WARNING)
    return _lib


def enabled() -> bool:
    """False when the environment variable ``SOMTORCH_NATIVE`` is ``0``."""
    return os.environ.get(ENV_SWITCH, "1").strip() != "0"


def available() -> bool:
    """Whether the kernel is enabled and builds/loads on this machine."""
    return enabled() and library() is not None


def _unsupported(x: torch.Tensor, weight: torch.Tensor, k: int) -> str | None:
    if x.device.type != "cpu" or weight.device.type != "cpu":
        return f"tensors on {x.device}/{weight.device}, the kernel runs on the CPU only"
    if x.dtype != weight.dtype or x.dtype not in (torch.float32, torch.float64):
        return f"dtypes {x.dtype}/{weight.dtype}; the kernel needs both float32 or both float64"
    if weight.ndim != 3 or x.ndim not in (2, 3) or x.shape[-1] != weight.shape[-1] \
            or (x.ndim == 3 and x.shape[0] != weight.shape[0]):
        return f"shapes x {tuple(x.shape)}, weight {tuple(weight.shape)}"
    if k not in (1, 2) or weight.shape[1] < k or weight.shape[0] == 0 or weight.shape[2] == 0:
        return f"k={k} with weight {tuple(weight.shape)}"
    return None


def _refusal(rc: int, e: int, n: int, k: int, d: int) -> str:
    if rc == 2:  # torch.argmin picks a NaN distance, the kernel never would
        return "NaN weights"
    return f"the kernel refused E={e}, N={n}, K={k}, D={d} (e.g. K beyond int32 in float32)"


def _prepare(x: torch.Tensor, weight: torch.Tensor, k: int):
    """``(library, x, weight contiguous, (E, K, D, N))`` for a kernel call, or None (reason logged once)."""
    if not enabled():
        _note(f"{ENV_SWITCH}=0", logging.INFO)
        return None
    reason = _unsupported(x, weight, k)
    if reason is not None:
        _note(reason)
        return None
    lib = library()
    if lib is None:
        return None
    e, kk, d = weight.shape
    return lib, x.detach().contiguous(), weight.detach().contiguous(), (e, kk, d, x.shape[-2])


@torch.no_grad()
def native_bmu(x: torch.Tensor, weight: torch.Tensor, k: int = 1) -> torch.Tensor | None:
    """Nearest (k = 1) or two nearest (k = 2) neurons by exact squared distance; None if unsupported.

    Args:
        x: samples, shared ``(N, D)`` or per member ``(E, N, D)``; float32 or float64 on the CPU.
        weight: reference vectors ``(E, K, D)``, same dtype as ``x``.
        k: 1 or 2 (``k ≤ K``).

    Shape:
        returns ``(E, N)`` for k = 1, else ``(E, N, 2)`` (best first; ties by index); dtype long.
    """
    call = _prepare(x, weight, k)
    if call is None:
        return None
    lib, xc, wc, (e, kk, d, n) = call
    out = torch.empty((e, n) if k == 1 else (e, n, 2), dtype=torch.long)
    fn = lib.somtorch_bmu_f32 if x.dtype == torch.float32 else lib.somtorch_bmu_f64
    rc = fn(xc.data_ptr(), 0 if x.ndim == 2 else n * d, wc.data_ptr(), e, n, kk, d, k, out.data_ptr(),
            kernel_threads())
    if rc != 0:
        _note(_refusal(rc, e, n, kk, d))
        return None
    return out


@torch.no_grad()
def native_accumulate(x: torch.Tensor, weight: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Batch-map statistics in one pass: per-unit sums and counts of the samples each unit wins.

    The same result as :func:`somtorch.core.training.accumulate` (BMUs by :func:`native_bmu`, each
    member's sums added in sample order like ``index_add_``) without the ``E·N`` index and copy
    tensors. Threads split the members (a solo map runs on one thread). None if unsupported.

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)`` → sums ``(E, K, D)``, counts
        ``(E, K)``, both in the dtype of ``weight``.
    """
    call = _prepare(x, weight, 1)
    if call is None:
        return None
    lib, xc, wc, (e, kk, d, n) = call
    sums = torch.zeros(e, kk, d, dtype=weight.dtype)
    counts = torch.zeros(e, kk, dtype=torch.long)
    fn = lib.somtorch_accumulate_f32 if x.dtype == torch.float32 else lib.somtorch_accumulate_f64
    rc = fn(xc.data_ptr(), 0 if x.ndim == 2 else n * d, wc.data_ptr(), e, n, kk, d, sums.data_ptr(),
            counts.data_ptr(), kernel_threads())
    if rc != 0:
        _note(_refusal(rc, e, n, kk, d))
        return None
    return sums, counts.to(weight.dtype)


@torch.no_grad()
def native_bounded(x: torch.Tensor, weight: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
                   drift: torch.Tensor | None, slack: tuple[float, float, float]
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
    """:func:`native_accumulate` that searches only the samples whose bounds do not prove their
    BMU (see :mod:`somtorch.core.bounds`); None if unsupported.

    Args:
        state: per member and sample the BMU ``(E, N)`` int64 and the upper / lower distance
            bounds ``(E, N)`` float64, all contiguous, updated in place.
        drift: how far each unit moved since the state was valid ``(E, K)`` float64, rounded
            outwards; None searches every sample (a fresh state).
        slack: ``(rho, alpha, grow)``: the kernel's relative and absolute distance error, and the
            outward rounding of a computed distance.

    Shape:
        returns sums ``(E, K, D)``, counts ``(E, K)`` (the weights' dtype) and the number of
        samples each member searched ``(E,)`` int64.
    """
    call = _prepare(x, weight, 2)
    if call is None:
        return None
    lib, xc, wc, (e, kk, d, n) = call
    c, u, lo = state
    if drift is None:
        drift_c = torch.zeros(e, kk, dtype=torch.float64)
    else:
        drift_c = drift.detach().to(torch.float64).contiguous()
    dmax = drift_c.amax(1).contiguous()
    sums = torch.zeros(e, kk, d, dtype=weight.dtype)
    counts = torch.zeros(e, kk, dtype=torch.long)
    searched = torch.zeros(e, dtype=torch.long)
    fn = lib.somtorch_bounded_f32 if x.dtype == torch.float32 else lib.somtorch_bounded_f64
    rho, alpha, grow = slack
    rc = fn(xc.data_ptr(), 0 if x.ndim == 2 else n * d, wc.data_ptr(), e, n, kk, d, c.data_ptr(), u.data_ptr(),
            lo.data_ptr(), drift_c.data_ptr(), dmax.data_ptr(), rho, alpha, grow, int(drift is None),
            sums.data_ptr(), counts.data_ptr(), searched.data_ptr(), kernel_threads())
    if rc != 0:
        _note(_refusal(rc, e, n, kk, d))
        return None
    return sums, counts.to(weight.dtype), searched


@torch.no_grad()
def native_online(weight: torch.Tensor, xs: torch.Tensor, coef: torch.Tensor, log_lr: torch.Tensor,
                  grid_d2: torch.Tensor, idx: torch.Tensor | None = None) -> bool:
    """Gaussian online rule for S steps, in place on ``weight``; False (nothing done) if unsupported.

    The kernel runs :func:`somtorch.core.training.online_block`'s operations in the same precision
    and order; the exponential is the C library's, so the weights agree with the torch path to
    rounding. From 2 members on, 8 float32 (4 float64) members share each vector instruction, and
    a step whose members share α and σ computes one exponential per distinct grid distance for
    all of them; member e still equals its solo map bitwise.

    Args:
        weight: ``(E, K, D)`` contiguous, updated in place.
        xs: the samples of the S steps ``(1 | E, S, D)``; with ``idx``, the data ``(N, D)`` or
            ``(E, N, D)`` they are taken from (no ``(E, S, D)`` copy).
        coef: −1/(2σ²) per step and member ``(S, E)``.
        log_lr: log α ``(S, E)``.
        grid_d2: squared grid distances ``(K, K)``.
        idx: sample index of every step, ``(1 | E, S)`` in ``[0, N)`` (not checked here), or None.
    """
    if not enabled():
        _note(f"{ENV_SWITCH}=0", logging.INFO)
        return False
    if weight.device.type != "cpu" or weight.dtype not in (torch.float32, torch.float64) \
            or not weight.is_contiguous() or xs.dtype != weight.dtype or xs.device.type != "cpu":
        _note(f"online rule with weight {weight.dtype} on {weight.device}, samples {xs.dtype}")
        return False
    lib = library()
    if lib is None:
        return False
    e, k, d = weight.shape
    dt = weight.dtype
    if idx is None:  # the samples in step order: data = xs, index = 0 … S−1
        idx = torch.arange(xs.shape[1])[None]
    s = idx.shape[-1]
    data = xs.detach().contiguous()
    ic = idx.detach().to(device="cpu", dtype=torch.long).contiguous()
    cc = coef.detach().to(dt).reshape(s, e).contiguous()
    lc = log_lr.detach().to(dt).reshape(s, e).contiguous()
    gc = grid_d2.detach().to(device="cpu", dtype=dt).contiguous()
    x_stride = 0 if data.ndim == 2 or data.shape[0] == 1 else data.shape[1] * d
    fn = lib.somtorch_online_f32 if dt == torch.float32 else lib.somtorch_online_f64
    rc = fn(weight.data_ptr(), data.data_ptr(), x_stride, ic.data_ptr(), 0 if ic.shape[0] == 1 else s,
            cc.data_ptr(), lc.data_ptr(), gc.data_ptr(), e, s, k, d, kernel_threads())
    if rc != 0:
        _note(_refusal(rc, e, s, k, d))
        return False
    return True

