"""Core SOM benchmark: a 4×7 SOM on the 3-D (y, x, d) vectors of a 1264×720 disparity map.

Run from the repository root::

    python benchmarks/bench_core.py                 # full run (~40 s on 2 idle cores)
    python benchmarks/bench_core.py --quick         # smoke run on a 316×180 map (seconds)
    python benchmarks/bench_core.py --json out.json # also write every timing as JSON

Every row times ``somtorch`` against a peer measured in the same process, on the same data and from
the same initial weights, and prints the ratio and a PASS/FAIL against the target of the issue
"4×7 SOM, 3-D data". See ``benchmarks/README.md`` for what each row measures.

Data: a deterministic synthetic disparity map (ground-plane gradient below a horizon, a far
background plane above it, four fronto-parallel boxes standing on the ground, Gaussian sub-pixel
noise from a fixed seed), every pixel valid; features (y, x, d) min-max scaled to [0, 1] with
:func:`somtorch.disparity.features.make_features`. NOR = all 910,080 pixels, OR = stride 10
(127·72 = 9,144 pixels).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

try:  # python -m benchmarks.bench_core
    from . import common
except ImportError:  # python benchmarks/bench_core.py
    import common

from somtorch import SOM
from somtorch.disparity.features import make_features

Timing = common.Timing
measure = common.measure


# ------------------------------------------------------------------------------------------ settings
@dataclass(frozen=True)
class Settings:
    height: int = 720
    width: int = 1264
    stride: int = 10  # OR subsample
    rows: int = 4
    cols: int = 7
    repeats_fast: int = 11  # rows that take under a second per call
    repeats_slow: int = 5  # rows that take seconds per call
    online_epochs: int = 10
    ensemble: int = 100
    ensemble_online_epochs: int = 1
    ensemble_batch_epochs: int = 10
    paper_height: int = 497  # the every-pixel paper job: every pixel of a 741x497 map (Middlebury's size)
    paper_width: int = 741
    minibatch_epochs: int = 10
    batch_size: int = 256
    ref_chunk_rows: int = 65_536
    xpysom_tuned_n_parallel: int = 65_536
    lr: float = 0.5
    seed: int = 0

    @property
    def sigma(self) -> float:  # somtorch's default radius, given explicitly to every library
        return max(self.rows, self.cols) / 2.0


FULL = Settings()
QUICK = Settings(height=180, width=316, repeats_fast=2, repeats_slow=1, paper_height=99, paper_width=148)

TARGETS = {
    "bmu": "ours/ref <= 1.5",
    "bmu_read": "ours/read <= 3.0",
    "bmu_kmeans": "ours/sklearn <= 1.0",
    "batch": "speed-up >= 2.0",
    "online": "speed-up >= 20",
    "ensemble_online": "per-member thr. ratio >= 20",
    "ensemble_online_paper": "per-member thr. ratio >= 450",
    "ensemble_batch": "t(E)/t(1) <= 5.0",
    "ensemble_large": "t(E)/E / t(1) <= 0.05",
    "minibatch": "none (reference)",
}
BUSY_TARGET = 2.5  # slowdown with one core busy, against idle, same run


# -------------------------------------------------------------------------------------------- data
def synthetic_disparity(height: int, width: int, seed: int = 0) -> np.ndarray:
    """A road-scene-like disparity map (px): ground plane, far background, four boxes, noise.

    Disparities are given for the 1264-px-wide map and scaled with ``width`` so that a smaller map
    is the same scene at a lower resolution. Deterministic (numpy PCG64 with ``seed``).

    Shape:
        returns ``(height, width)`` float32, every value finite and > 0.
    """
    s = width / 1264.0
    y = np.arange(height, dtype=np.float64)[:, None]
    horizon = 0.30 * height
    d_far, d_bottom = 6.0 * s, 140.0 * s

    def ground(row: float) -> float:
        return d_far + (d_bottom - d_far) * max(row - horizon, 0.0) / (height - 1 - horizon)

    d = np.where(y > horizon, d_far + (d_bottom - d_far) * (y - horizon) / (height - 1 - horizon), d_far)
    d = np.broadcast_to(d, (height, width)).copy()
    # boxes: (centre x, width, height as fractions of the image, base row fraction); each stands on
    # the ground, so its disparity is the ground's at its base row; nearer boxes are painted last
    boxes = [(0.62, 0.10, 0.16, 0.52), (0.78, 0.08, 0.22, 0.62), (0.20, 0.13, 0.26, 0.76),
             (0.48, 0.20, 0.32, 0.92)]
    for cx, bw, bh, base in sorted(boxes, key=lambda b: b[3]):
        y1 = int(round(base * height))
        y0 = int(round((base - bh) * height))
        x0 = int(round((cx - bw / 2) * width))
        x1 = int(round((cx + bw / 2) * width))
        d[y0:y1, x0:x1] = ground(y1 - 1)
    rng = np.random.default_rng(seed)
    d += rng.normal(0.0, 0.25 * s, size=d.shape)
    return np.clip(d, 0.1 * s, None).astype(np.float32)


def build_features(st: Settings) -> tuple[torch.Tensor, torch.Tensor]:
    """NOR (all pixels) and OR (stride ``st.stride``) feature vectors ``(N, 3)`` float32 in [0, 1]."""
    disp = torch.from_numpy(synthetic_disparity(st.height, st.width, st.seed))
    valid = torch.ones_like(disp, dtype=torch.bool)
    feats = make_features(disp, valid, normalize="minmax")
    return feats.x.contiguous(), feats.subsample(st.stride).x.contiguous()


# -------------------------------------------------------------------------------------------- peers
def import_peers() -> dict[str, Any]:
    """The peer libraries that import and work here, with versions; reasons for those that do not."""
    peers: dict[str, Any] = {"available": {}, "missing": {}}
    try:
        from minisom import MiniSom
        peers["MiniSom"] = MiniSom
        peers["available"]["minisom"] = common.package_version("MiniSom")
    except ImportError as e:
        peers["missing"]["minisom"] = f"not importable ({e}); pip install minisom"
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # xpysom prints a CuPy warning on import
            from xpysom import XPySom
        peers["XPySom"] = XPySom
        peers["available"]["xpysom"] = common.package_version("XPySom")
    except ImportError as e:
        peers["missing"]["xpysom"] = f"not importable ({e}); pip install xpysom"
    try:
        import somoclu
        import somoclu.train as somoclu_train
    except ImportError as e:
        peers["missing"]["somoclu"] = f"not importable ({e}); see benchmarks/README.md to install it"
    else:
        if hasattr(somoclu_train, "wrap_train"):
            peers["Somoclu"] = somoclu.Somoclu
            peers["available"]["somoclu"] = common.package_version("somoclu")
        else:
            peers["missing"]["somoclu"] = ("installed, but its C++ extension _somoclu_wrap is missing (pip "
                                           "built a pure-Python wheel); see benchmarks/README.md")
    try:
        import fastersom
        peers["fastersom"] = fastersom
        peers["available"]["fastersom"] = common.package_version("fastersom")
    except ImportError as e:
        peers["missing"]["fastersom"] = (f"not importable ({e}); pip install --no-deps "
                                         "--ignore-requires-python fastersom==0.6.0")
    try:
        from sklearn.cluster import KMeans
        peers["KMeans"] = KMeans
        peers["available"]["scikit-learn"] = common.package_version("scikit-learn")
    except ImportError as e:
        peers["missing"]["scikit-learn"] = f"not importable ({e}); pip install scikit-learn"
    return peers


def fastersom_model(peers: dict[str, Any], rows: int, cols: int, w0: torch.Tensor, epochs: int,
                    sigma0: float | None = None, sigma1: float | None = None) -> Any:
    """A fastersom map on the CPU starting from ``w0`` ``(K, D)`` (its default schedule unless given)."""
    return peers["fastersom"].SOM(rows, cols, n_epochs=epochs, init=w0.numpy().copy(), random_state=0,
                                  device="cpu", sigma_initial=sigma0, sigma_final=sigma1)


def quantization_error(x: torch.Tensor, w: Any) -> float:
    """Mean distance of each sample to its nearest reference vector (the same formula for every library)."""
    w = torch.as_tensor(np.asarray(w, dtype=np.float32)).reshape(-1, x.shape[1])
    return float(torch.cdist(x, w).min(1).values.double().mean())


def reference_bmu(x: torch.Tensor, w: torch.Tensor, chunk_rows: int) -> torch.Tensor:
    """Plain chunked BMU search: one ``addmm`` (‖w‖² − 2 x·w) and one ``argmin`` per chunk.

    Shape:
        ``x`` ``(N, D)``, ``w`` ``(K, D)`` → ``(N,)`` long.
    """
    wsq = w.square().sum(1)  # (K,)
    out = torch.empty(x.shape[0], dtype=torch.long)
    wt = w.T.contiguous()  # (D, K)
    for s in range(0, x.shape[0], chunk_rows):
        out[s:s + chunk_rows] = torch.addmm(wsq, x[s:s + chunk_rows], wt, alpha=-2.0).argmin(1)
    return out


def bmu_backend() -> str:
    """Which BMU search ``somtorch.core.distance.bmu_search`` uses here (the native kernel is optional)."""
    try:
        from somtorch.core import native
    except ImportError:
        return "torch (chunked addmm + argmin)"
    if native.available():
        return "native fused kernel (somtorch.core.native; SOMTORCH_NATIVE=0 selects the torch path)"
    return "torch (chunked addmm + argmin; native kernel disabled or unavailable)"


@contextlib.contextmanager
def torch_bmu_path() -> Iterator[None]:
    """Force somtorch's torch BMU path (``SOMTORCH_NATIVE=0``, read at every call) inside the block."""
    old = os.environ.get("SOMTORCH_NATIVE")
    os.environ["SOMTORCH_NATIVE"] = "0"
    try:
        yield
    finally:
        if old is None:
            del os.environ["SOMTORCH_NATIVE"]
        else:
            os.environ["SOMTORCH_NATIVE"] = old


def native_in_use() -> bool:
    return bmu_backend().startswith("native")


# -------------------------------------------------------------------------------------------- rows
@dataclass
class Row:
    key: str
    name: str
    work: str
    ours: Timing
    peer: str | None = None
    peer_timing: Timing | None = None
    ratio: float | None = None
    ratio_label: str = ""
    target: str = ""
    ok: bool | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    peers_extra: list[tuple[str, Timing, float, str]] = field(default_factory=list)  # more peers, info only

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ours"] = self.ours.as_dict()
        d["peer_timing"] = self.peer_timing.as_dict() if self.peer_timing else None
        d["peers_extra"] = [{"peer": p, "timing": t.as_dict(), "ratio": r, "ratio_label": lab}
                            for p, t, r, lab in self.peers_extra]
        d["status"] = common.verdict(self.ok)
        return d


def new_som(st: Settings, w0: torch.Tensor, ensemble: int = 1) -> SOM:
    """A fresh map (fresh generators) holding the initial weights ``w0`` ``(K, D)``."""
    return SOM(st.rows, st.cols, 3, ensemble=ensemble, seed=st.seed).set_weight(w0)


def row_bmu(st: Settings, x_all: torch.Tensor, w_trained: torch.Tensor) -> Row:
    som = new_som(st, w_trained)
    ours = measure(lambda _: som.bmu(x_all), repeats=st.repeats_fast)
    ref = measure(lambda _: reference_bmu(x_all, w_trained, st.ref_chunk_rows), repeats=st.repeats_fast)
    agree = float((som.bmu(x_all)[0] == reference_bmu(x_all, w_trained, st.ref_chunk_rows)).double().mean())
    ratio = ours.median / ref.median
    n, k = x_all.shape[0], st.rows * st.cols
    row = Row("bmu", "BMU assignment", f"{n:,} vectors x {k} neurons", ours,
              f"reference addmm+argmin, {st.ref_chunk_rows:,}-row chunks", ref, ratio, "ours/ref",
              TARGETS["bmu"], ratio <= 1.5,
              extra={"agreement_with_reference": agree, "ours_vectors_per_s": n / ours.median})
    if native_in_use():
        with torch_bmu_path():
            tp = measure(lambda _: som.bmu(x_all), repeats=st.repeats_fast)
        row.peers_extra.append(("somtorch torch path (SOMTORCH_NATIVE=0) vs reference", tp,
                                tp.median / ref.median, "ours/ref time"))
    return row


def row_bmu_read(st: Settings, x_all: torch.Tensor, w_trained: torch.Tensor) -> Row:
    """The BMU search against the time to read its input once from memory (a vectorised sum).

    Both from a cold cache: before every timed call a 64 MiB buffer is written (untimed), so the
    array comes from DRAM, not from the last-level cache it would fit in.
    """
    junk = torch.empty(64 * 2 ** 20 // 4)

    def evict() -> None:
        junk.add_(1.0)

    som = new_som(st, w_trained)
    ours = measure(lambda _: som.bmu(x_all), repeats=st.repeats_fast, setup=evict)
    read = measure(lambda _: torch.sum(x_all), repeats=st.repeats_fast, setup=evict)
    ratio = ours.median / read.median
    mb = x_all.numel() * x_all.element_size() / 2 ** 20
    return Row("bmu_read", "BMU vs one read of the data (cold cache)",
               f"{x_all.shape[0]:,} x 3 float32 = {mb:.1f} MiB", ours,
               "torch.sum(x): one pass over the same array", read, ratio, "ours/read",
               TARGETS["bmu_read"], ratio <= 3.0, extra={"read_gib_per_s": mb / 1024 / read.median})


def row_bmu_kmeans(st: Settings, x_all: torch.Tensor, w_trained: torch.Tensor, bmu: Row,
                   peers: dict[str, Any]) -> Row:
    """The BMU assignment against scikit-learn's ``KMeans.predict`` with the same centres."""
    row = Row("bmu_kmeans", "BMU vs KMeans.predict", f"{x_all.shape[0]:,} vectors x {w_trained.shape[0]} centres",
              bmu.ours, target=TARGETS["bmu_kmeans"], ratio_label="ours/sklearn")
    x_np = x_all.numpy()
    if "KMeans" in peers:
        w_np = w_trained.numpy().astype(np.float32)
        km = peers["KMeans"](n_clusters=w_np.shape[0], init=w_np, n_init=1, max_iter=1).fit(w_np)
        km.cluster_centers_ = w_np.copy()  # exactly our centres (fit on them only sets the attributes)
        sk = measure(lambda _: km.predict(x_np), repeats=st.repeats_fast)
        som = new_som(st, w_trained)
        row.extra["agreement_with_sklearn"] = float((torch.from_numpy(km.predict(x_np)).long()
                                                     == som.bmu(x_all)[0]).double().mean())
        row.peer, row.peer_timing = "sklearn KMeans.predict (same centres)", sk
        row.ratio = bmu.ours.median / sk.median
        row.ok = row.ratio <= 1.0
    if "fastersom" in peers:
        try:
            fs = peers["fastersom"].SOM.from_weights(w_trained.numpy().copy(), st.rows, st.cols, device="cpu")
            t = measure(lambda _: fs.predict(x_np), repeats=st.repeats_fast)
            row.peers_extra.append(("fastersom SOM.predict (same weights)", t,
                                    t.median / bmu.ours.median, "peer/ours time"))
        except Exception as exc:  # a peer's API drift must not stop the benchmark
            row.extra["fastersom_predict_error"] = f"{type(exc).__name__}: {exc}"
    return row


def row_batch(st: Settings, x_all: torch.Tensor, w0: torch.Tensor, peers: dict[str, Any]) -> Row:
    def ours_fn(som: SOM) -> None:
        som.fit(x_all, mode="batch", epochs=1, sigma=st.sigma, progress=False)

    ours = measure(ours_fn, repeats=st.repeats_fast, setup=lambda: new_som(st, w0))
    som = new_som(st, w0)
    ours_fn(som)
    w_ours = som.weight.detach()[0].numpy()
    torch_path = None
    if native_in_use():
        with torch_bmu_path():
            torch_path = measure(ours_fn, repeats=st.repeats_fast, setup=lambda: new_som(st, w0))
    x_np = x_all.numpy()
    w0_grid = w0.numpy().reshape(st.rows, st.cols, 3)
    row = Row("batch", "Batch map, 1 epoch", f"{x_all.shape[0]:,} px, 1 batch epoch", ours,
              target=TARGETS["batch"], ratio_label="peer/ours (speed-up)")
    if "XPySom" in peers:
        XPySom = peers["XPySom"]

        def xp_setup(n_parallel: int = 0) -> Any:
            # std_coeff=1 makes xpysom's gaussian exp(-d²/2σ²), the same as ours; one epoch at
            # iteration 0 uses σ0 in both; the learning rate cancels in the batch map
            m = XPySom(st.rows, st.cols, 3, sigma=st.sigma, learning_rate=st.lr, std_coeff=1.0,
                       neighborhood_function="gaussian", random_seed=st.seed, xp=np, n_parallel=n_parallel)
            m._weights = w0_grid.astype(np.float64).copy()
            return m

        def xp_fn(m: Any) -> None:
            m.train(x_np, 1)  # num_epochs=1: one pass accumulating numerator/denominator, one merge

        xp_default = measure(xp_fn, repeats=st.repeats_slow, setup=xp_setup)
        m = xp_setup()
        xp_fn(m)
        row.extra["xpysom_default_n_parallel"] = m._n_parallel
        row.extra["max_abs_weight_diff_vs_xpysom"] = float(np.abs(np.asarray(m._weights).reshape(-1, 3)
                                                                  - w_ours).max())
        tuned = st.xpysom_tuned_n_parallel
        xp_tuned = measure(xp_fn, repeats=st.repeats_slow, setup=lambda: xp_setup(tuned))
        # the target is judged against the faster xpysom configuration (the stricter comparison)
        configs = sorted([(f"xpysom {m._n_parallel:,}-row chunks (default)", xp_default),
                          (f"xpysom {tuned:,}-row chunks", xp_tuned)], key=lambda c: c[1].median)
        (best_label, best), (other_label, other) = configs
        row.peer, row.peer_timing = best_label + " [faster of two]", best
        row.ratio = best.median / ours.median
        row.ok = row.ratio >= 2.0
        row.peers_extra.append((other_label, other, other.median / ours.median, "peer/ours time"))
    if "Somoclu" in peers:
        Somoclu = peers["Somoclu"]
        x32 = np.ascontiguousarray(x_np, dtype=np.float32)

        def so_setup() -> Any:
            m = Somoclu(st.cols, st.rows, initialcodebook=w0.numpy().astype(np.float32).copy(),
                        compactsupport=False, std_coeff=1.0)
            m.update_data(x32)  # untimed: somoclu keeps a reference to the float32 data
            return m

        def so_fn(m: Any) -> None:
            # one batch epoch at radius σ0 (std_coeff=1: exp(-d²/2σ²) as ours), scale 1 (it cancels in
            # the batch map); "exponential" cooling because somoclu's linear cooling divides by
            # epochs − 1 (NaN codebook for one epoch); train() also computes the final BMUs and U-matrix
            m.train(epochs=1, radius0=st.sigma, radiusN=st.sigma, radiuscooling="exponential",
                    scale0=1.0, scaleN=1.0, scalecooling="exponential")

        so = measure(so_fn, repeats=st.repeats_slow, setup=so_setup)
        m = so_setup()
        so_fn(m)
        row.extra["max_abs_weight_diff_vs_somoclu"] = float(np.abs(m.codebook.reshape(-1, 3) - w_ours).max())
        row.peers_extra.append(("somoclu (C++/OpenMP, includes final BMUs + U-matrix)", so,
                                so.median / ours.median, "peer/ours time"))
    if "fastersom" in peers:
        # one batch epoch at sigma0: sigma_initial = sigma_final, the same gaussian exp(-d²/2σ²)
        fs_fn = lambda m: m.fit(x_np)  # noqa: E731
        fs_t = measure(fs_fn, repeats=st.repeats_slow,
                       setup=lambda: fastersom_model(peers, st.rows, st.cols, w0, 1, st.sigma, st.sigma))
        m = fastersom_model(peers, st.rows, st.cols, w0, 1, st.sigma, st.sigma)
        m.fit(x_np)
        row.extra["max_abs_weight_diff_vs_fastersom"] = float(np.abs(m.weights_.reshape(-1, 3) - w_ours).max())
        row.peers_extra.append(("fastersom 0.6 (PyTorch batch SOM, CPU)", fs_t, fs_t.median / ours.median,
                                "peer/ours time"))
    if torch_path is not None:
        row.peers_extra.append(("somtorch torch BMU path (SOMTORCH_NATIVE=0)", torch_path,
                                torch_path.median / ours.median, "it/ours time"))
    return row


def row_online(st: Settings, x_or: torch.Tensor, w0: torch.Tensor, peers: dict[str, Any]) -> Row:
    n = x_or.shape[0]
    steps = st.online_epochs * n
    warm = max(1, n // 10)

    def ours_fn(som: SOM, iterations: int = steps) -> None:
        som.fit(x_or, mode="online", iterations=iterations, order="random", lr=st.lr, sigma=st.sigma,
                progress=False)

    ours = measure(ours_fn, repeats=st.repeats_slow, setup=lambda: new_som(st, w0),
                   warmup_fn=lambda som: ours_fn(som, warm))
    row = Row("online", "Online rule, 1 SOM", f"{st.online_epochs} epochs x {n:,} px = {steps:,} steps", ours,
              target=TARGETS["online"], ratio_label="peer/ours (speed-up)",
              extra={"ours_steps_per_s": steps / ours.median, "steps": steps})
    if "MiniSom" in peers:
        MiniSom = peers["MiniSom"]
        x64 = x_or.numpy().astype(np.float64)

        def ms_setup() -> Any:
            # same grid, σ0, α0, gaussian neighbourhood and asymptotic decays as somtorch's defaults
            m = MiniSom(st.rows, st.cols, 3, sigma=st.sigma, learning_rate=st.lr, random_seed=st.seed,
                        neighborhood_function="gaussian", decay_function="asymptotic_decay",
                        sigma_decay_function="asymptotic_decay")
            m._weights = w0.numpy().astype(np.float64).reshape(st.rows, st.cols, 3).copy()
            return m

        mini = measure(lambda m: m.train(x64, steps, random_order=True), repeats=st.repeats_slow,
                       setup=ms_setup, warmup_fn=lambda m: m.train(x64, warm, random_order=True))
        row.peer, row.peer_timing = f"MiniSom.train(data, {steps:,}, random_order=True)", mini
        row.ratio = mini.median / ours.median
        row.ok = row.ratio >= 20.0
        row.extra["minisom_steps_per_s"] = steps / mini.median
    return row


def vs_minisom(row: Row, member_steps_per_s: float, online: Row, target: float) -> Row:
    """Judge an ensemble row by its member-steps/s against MiniSom's steps/s of the online row."""
    if "minisom_steps_per_s" in online.extra:
        ms_thr = online.extra["minisom_steps_per_s"]
        row.peer = f"MiniSom steps/s from the online row ({ms_thr:,.0f}/s)"
        row.peer_timing = online.peer_timing
        row.ratio = member_steps_per_s / ms_thr
        row.ok = row.ratio >= target
    return row


def row_ensemble_online(st: Settings, x_or: torch.Tensor, w0: torch.Tensor, online: Row) -> Row:
    n = x_or.shape[0]
    steps = st.ensemble_online_epochs * n
    e = st.ensemble
    warm = max(1, n // 20)

    def fn(som: SOM, iterations: int = steps) -> None:
        som.fit(x_or, mode="online", iterations=iterations, order="random", lr=st.lr, sigma=st.sigma,
                progress=False)

    ours = measure(fn, repeats=st.repeats_slow, setup=lambda: new_som(st, w0, e),
                   warmup_fn=lambda som: fn(som, warm))
    thr = e * steps / ours.median  # member-steps per second
    row = Row("ensemble_online", f"Online rule, ensemble of {e}",
              f"{e} members x {st.ensemble_online_epochs} epoch x {n:,} px = {e * steps:,} member-steps",
              ours, target=TARGETS["ensemble_online"],
              ratio_label="member-steps/s / MiniSom steps/s",
              extra={"member_steps_per_s": thr, "solo_steps_per_s": online.extra["ours_steps_per_s"],
                     "vs_solo_somtorch": thr / online.extra["ours_steps_per_s"]})
    return vs_minisom(row, thr, online, 20.0)


def cpu_mhz() -> float | None:
    """The clock the kernel reports in ``/proc/cpuinfo`` (first ``cpu MHz`` line), or None."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("cpu MHz"):
                    return float(line.split(":", 1)[1])
    except (OSError, ValueError):
        pass
    return None


def online_limit(k: int, d: int, mhz: float | None) -> dict[str, Any]:
    """The arithmetic of the online kernel's limit on one core (``docs/scaling.md`` §8).

    Lane operations per member-step (float32, no fused multiply-add so that every lane rounds like
    MiniSom's formula): distances ``K (D sub + D mul + (D−1) add)``, the running argmin ``K (compare +
    2 blends)``, the update ``K·D (sub + mul + add)``. Peak: 2 vector FP units × 8 float32 lanes
    (AVX2) per cycle at the clock of ``/proc/cpuinfo``.
    """
    ops = k * (3 * d - 1) + 3 * k + 3 * k * d
    out: dict[str, Any] = {"lane_ops_per_member_step": ops}
    if mhz:
        out["peak_lane_ops_per_s"] = 2 * 8 * mhz * 1e6
        out["limit_member_steps_per_s_per_core"] = out["peak_lane_ops_per_s"] / ops
    return out


def row_ensemble_online_paper(st: Settings, online: Row) -> Row:
    """Issue 27 item 1: the paper's online job on every pixel of a 741x497 map, 100 members, 1 epoch."""
    disp = torch.from_numpy(synthetic_disparity(st.paper_height, st.paper_width, st.seed))
    x = make_features(disp, torch.ones_like(disp, dtype=torch.bool), normalize="minmax").x.contiguous()
    n, e = x.shape[0], st.ensemble
    gen = torch.Generator().manual_seed(st.seed)
    w0 = x[torch.randperm(n, generator=gen)[:st.rows * st.cols]].clone()

    def fn(som: SOM, iterations: int = n) -> None:
        som.fit(x, mode="online", iterations=iterations, order="random", lr=st.lr, sigma=st.sigma,
                progress=False)

    ours = measure(fn, repeats=max(1, st.repeats_slow // 2), setup=lambda: new_som(st, w0, e),
                   warmup_fn=lambda som: fn(som, max(1, n // 50)))
    thr = e * n / ours.median
    limit = online_limit(st.rows * st.cols, 3, cpu_mhz())
    extra = {"member_steps_per_s": thr, "pixels": n, **limit,
             "vs_solo_somtorch": thr / online.extra["ours_steps_per_s"]}
    if "limit_member_steps_per_s_per_core" in limit:
        extra["share_of_limit_per_core"] = thr / torch.get_num_threads() / limit["limit_member_steps_per_s_per_core"]
    row = Row("ensemble_online_paper", f"Online rule, ensemble of {e}, every pixel",
              f"{e} members x 1 epoch x {n:,} px ({st.paper_width}x{st.paper_height}) = {e * n:,} member-steps",
              ours, target=TARGETS["ensemble_online_paper"], ratio_label="member-steps/s / MiniSom steps/s",
              extra=extra)
    return vs_minisom(row, thr, online, 450.0)


def row_ensemble_batch(st: Settings, x_or: torch.Tensor, w0: torch.Tensor) -> Row:
    e, ep = st.ensemble, st.ensemble_batch_epochs

    def fn(som: SOM) -> None:
        som.fit(x_or, mode="batch", epochs=ep, sigma=st.sigma, progress=False)

    big = measure(fn, repeats=st.repeats_slow, setup=lambda: new_som(st, w0, e))
    one = measure(fn, repeats=st.repeats_fast, setup=lambda: new_som(st, w0, 1))
    ratio = big.median / one.median
    return Row("ensemble_batch", f"Batch map, ensemble of {e}",
               f"{e} members x {ep} batch epochs x {x_or.shape[0]:,} px", big,
               "somtorch E=1, same settings", one, ratio, "t(E)/t(E=1)", TARGETS["ensemble_batch"],
               ratio <= 5.0, extra={"speed_up_vs_E_solo_runs": e * one.median / big.median})


def row_ensemble_large(st: Settings, x_or: torch.Tensor, rows: int = 16, cols: int = 16) -> Row:
    """A large grid: does an ensemble still cost less per member than a solo map?"""
    e, ep = st.ensemble, st.ensemble_batch_epochs
    gen = torch.Generator().manual_seed(st.seed)
    w0 = x_or[torch.randperm(x_or.shape[0], generator=gen)[:rows * cols]].clone()

    def fn(som: SOM) -> None:
        som.fit(x_or, mode="batch", epochs=ep, progress=False)

    big = measure(fn, repeats=max(1, st.repeats_slow // 2),
                  setup=lambda: SOM(rows, cols, 3, ensemble=e, seed=st.seed).set_weight(w0))
    one = measure(fn, repeats=st.repeats_fast, setup=lambda: SOM(rows, cols, 3, seed=st.seed).set_weight(w0))
    per = big.median / e
    return Row("ensemble_large", f"Batch map {rows}x{cols}, ensemble of {e}",
               f"{e} members x {ep} batch epochs x {x_or.shape[0]:,} px", big,
               f"somtorch {rows}x{cols} E=1", one, per / one.median, "t(E)/E / t(1)",
               TARGETS["ensemble_large"], per <= 0.05 * one.median,
               extra={"ms_per_member": per * 1e3, "ms_solo": one.median * 1e3,
                      "speed_up_vs_E_solo_runs": one.median / per})


def quality_table(st: Settings, x_or: torch.Tensor, peers: dict[str, Any]) -> list[dict[str, Any]]:
    """Quantization error and time of 10 batch epochs per library and schedule (4x7 and 16x16).

    Every library starts from the same initial weights and keeps its own default radius schedule;
    somtorch is run with its default (asymptotic: sigma ends at sigma0/3, the pipeline's choice, see
    docs/scaling.md) and with an exponential decay to min(0.1·sigma0, 1) (fastersom's end radius).
    """
    out = []
    x_np = x_or.numpy()
    epochs = st.ensemble_batch_epochs
    for rows, cols in ((st.rows, st.cols), (16, 16)):
        k = rows * cols
        sigma = max(rows, cols) / 2.0
        gen = torch.Generator().manual_seed(st.seed)
        w0 = x_or[torch.randperm(x_or.shape[0], generator=gen)[:k]].clone()
        entries: list[tuple[str, Callable[[], Any], Callable[[Any], Any], Callable[[Any], Any], bool]] = []

        def ours(decay: str, final: float | None):
            return (lambda: SOM(rows, cols, 3, seed=st.seed).set_weight(w0),
                    lambda m: m.fit(x_or, mode="batch", epochs=epochs, sigma_decay=decay, sigma_final=final,
                                    progress=False),
                    lambda m: m.weight.detach()[0])

        def ours_sigma(sigma0: float, decay: str, final: float):
            return (lambda: SOM(rows, cols, 3, seed=st.seed).set_weight(w0),
                    lambda m: m.fit(x_or, mode="batch", epochs=epochs, sigma=sigma0, sigma_decay=decay,
                                    sigma_final=final, progress=False),
                    lambda m: m.weight.detach()[0])

        entries.append(("somtorch default (asymptotic)", *ours("asymptotic", None), True))
        entries.append((f"somtorch exponential to {min(0.1 * sigma, 1.0):g}",
                         *ours("exponential", min(0.1 * sigma, 1.0)), True))
        fs0 = math.ceil(min(rows, cols) / 2) / 2  # fastersom's default radius schedule, given to somtorch
        entries.append((f"somtorch exponential {fs0:g} to {min(0.1 * fs0, 1.0):g} (fastersom's schedule)",
                         *ours_sigma(fs0, "exponential", min(0.1 * fs0, 1.0)), True))
        if "fastersom" in peers:
            entries.append(("fastersom (default schedule)",
                            lambda: fastersom_model(peers, rows, cols, w0, epochs),
                            lambda m: m.fit(x_np), lambda m: m.weights_, False))
        if "XPySom" in peers:
            def xp_setup():
                m = peers["XPySom"](rows, cols, 3, sigma=sigma, learning_rate=st.lr, random_seed=st.seed, xp=np)
                m._weights = w0.numpy().reshape(rows, cols, 3).astype(np.float64).copy()
                return m
            entries.append(("xpysom (default schedule)", xp_setup, lambda m: m.train(x_np, epochs),
                            lambda m: m._weights, False))
        if "Somoclu" in peers:
            x32 = np.ascontiguousarray(x_np, dtype=np.float32)

            def so_setup():
                m = peers["Somoclu"](cols, rows, initialcodebook=w0.numpy().astype(np.float32).copy(),
                                     compactsupport=False)
                m.update_data(x32)
                return m
            entries.append(("somoclu (default schedule)", so_setup, lambda m: m.train(epochs=epochs),
                            lambda m: m.codebook, False))
        for name, setup, fit, weights, is_ours in entries:
            t = measure(fit, repeats=st.repeats_slow, setup=setup)
            m = setup()
            fit(m)
            out.append({"grid": f"{rows}x{cols}", "library": name, "ours": is_ours, "timing": t,
                        "qe": quantization_error(x_or, weights(m))})
    return out


def matched_quality(table: list[dict[str, Any]], tol: float = 0.05) -> list[list[str]]:
    """Per grid: the best peer QE, and the fastest somtorch entry within ``tol`` of it (speed at matched quality)."""
    lines = []
    for grid in dict.fromkeys(r["grid"] for r in table):
        peers_ = [r for r in table if r["grid"] == grid and not r["ours"]]
        ours = [r for r in table if r["grid"] == grid and r["ours"]]
        if not peers_:
            continue
        best = min(peers_, key=lambda r: r["qe"])
        fastest_peer = min((r for r in peers_ if r["qe"] <= best["qe"] * (1 + tol)), key=lambda r: r["timing"].median)
        ok = [r for r in ours if r["qe"] <= best["qe"] * (1 + tol)]
        if ok:
            o = min(ok, key=lambda r: r["timing"].median)
            lines.append([grid, f"{best['qe']:.4f} ({best['library']})", o["library"], f"{o['qe']:.4f}",
                          common.secs(o["timing"].median), fastest_peer["library"],
                          common.secs(fastest_peer["timing"].median),
                          f"{fastest_peer['timing'].median / o['timing'].median:.2f}x"])
        else:
            lines.append([grid, f"{best['qe']:.4f} ({best['library']})", "none within 5 %", "-", "-",
                          fastest_peer["library"], common.secs(fastest_peer["timing"].median), "-"])
    return lines


def busy_rows(st: Settings, x_all: torch.Tensor, x_or: torch.Tensor, w0: torch.Tensor,
              w_trained: torch.Tensor, peers: dict[str, Any]) -> list[list[str]]:
    """The contended machine: each row idle, then with a competing busy process, in this run."""
    import subprocess

    som = new_som(st, w_trained)
    n = x_or.shape[0]
    jobs: list[tuple[str, Callable[[Any], Any], Callable[[], Any] | None, int, bool]] = [
        (f"BMU, {x_all.shape[0]:,} vectors", lambda _: som.bmu(x_all), None, st.repeats_fast, True),
        (f"batch map E={st.ensemble}, {st.ensemble_batch_epochs} epochs",
         lambda m: m.fit(x_or, mode="batch", epochs=st.ensemble_batch_epochs, sigma=st.sigma, progress=False),
         lambda: new_som(st, w0, st.ensemble), st.repeats_slow, True),
        (f"online rule, {st.online_epochs} epochs",
         lambda m: m.fit(x_or, mode="online", iterations=st.online_epochs * n, lr=st.lr, sigma=st.sigma,
                         progress=False), lambda: new_som(st, w0), st.repeats_slow, True),
    ]
    if "MiniSom" in peers:
        x64 = x_or.numpy().astype(np.float64)

        def ms_setup():
            m = peers["MiniSom"](st.rows, st.cols, 3, sigma=st.sigma, learning_rate=st.lr, random_seed=st.seed)
            m._weights = w0.numpy().astype(np.float64).reshape(st.rows, st.cols, 3).copy()
            return m
        jobs.append((f"MiniSom.train, {n:,} steps (peer)", lambda m: m.train(x64, n, random_order=True),
                     ms_setup, max(1, st.repeats_slow // 2), False))
    idle = [measure(fn, repeats=r, setup=setup) for _, fn, setup, r, _ in jobs]
    hog = subprocess.Popen([sys.executable, "-c", "while True:\n    pass"])
    try:
        time.sleep(0.5)  # the competitor is running before the first timed call
        busy = [measure(fn, repeats=r, setup=setup) for _, fn, setup, r, _ in jobs]
    finally:
        hog.kill()
        hog.wait()
    lines = []
    for (name, _, _, _, is_ours), a, b in zip(jobs, idle, busy):
        slow = b.median / a.median
        verdict = common.verdict(slow <= BUSY_TARGET) if is_ours else "-"
        lines.append([name, common.secs(a.median), common.secs(b.median), f"{slow:.2f}x",
                      f"<= {BUSY_TARGET}" if is_ours else "-", verdict])
    return lines


def row_minibatch(st: Settings, x_or: torch.Tensor, w0: torch.Tensor) -> Row:
    n = x_or.shape[0]
    steps = max(1, st.minibatch_epochs * n // st.batch_size)

    def fn(som: SOM) -> None:
        som.fit(x_or, mode="minibatch", epochs=st.minibatch_epochs, batch_size=st.batch_size, lr=st.lr,
                sigma=st.sigma, progress=False)

    ours = measure(fn, repeats=st.repeats_slow, setup=lambda: new_som(st, w0))
    return Row("minibatch", "Mini-batch, 1 SOM",
               f"{st.minibatch_epochs} epochs x {n:,} px, batch {st.batch_size} ({steps:,} steps)", ours,
               "none installed (torchsom, quicksom)", None, None, "", TARGETS["minibatch"], None,
               extra={"samples_per_s": steps * st.batch_size / ours.median, "steps": steps,
                      "ms_per_step": ours.median / steps * 1e3})


# -------------------------------------------------------------------------------------------- main
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="smoke run: 316x180 map, 1-2 repeats")
    p.add_argument("--json", metavar="PATH", help="write settings, machine info and all timings here")
    p.add_argument("--busy", action="store_true",
                   help="also time the main rows with one core busy (a competing process this script starts)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t_start = time.perf_counter()
    st = QUICK if args.quick else FULL
    info = common.machine_info()
    peers = import_peers()
    x_all, x_or = build_features(st)
    k = st.rows * st.cols
    extra = [f"data: synthetic {st.width}x{st.height} disparity map (ground plane + 4 boxes + noise, seed "
             f"{st.seed}), (y, x, d) min-max scaled to [0, 1]; NOR = {x_all.shape[0]:,} px, OR = stride "
             f"{st.stride} = {x_or.shape[0]:,} px",
             f"SOM {st.rows}x{st.cols} (K={k}), D=3, float32; sigma0={st.sigma}, lr0={st.lr}, gaussian, "
             "asymptotic decays; every library starts from the same initial weights",
             f"timing: median and min of {st.repeats_fast} (fast rows) / {st.repeats_slow} (slow rows) "
             "repeats "
             "after 1 untimed warm-up; construction and weight set-up are not timed",
             f"somtorch BMU search: {bmu_backend()}",
             "peers: " + ", ".join(f"{k_} {v}" for k_, v in peers["available"].items())]
    extra += [f"peer unavailable: {k_}: {v}" for k_, v in peers["missing"].items()]
    if args.quick:
        extra.append("QUICK smoke run: reduced sizes and repeats; PASS/FAIL below is NOT a verdict")
    print(common.header("bench_core: 4x7 SOM, 3-D (y, x, d) data", info, extra), flush=True)

    gen = torch.Generator().manual_seed(st.seed)
    w0 = x_or[torch.randperm(x_or.shape[0], generator=gen)[:k]].clone()  # (K, 3) shared initial weights
    w_trained = new_som(st, w0).fit(x_or, mode="batch", epochs=10, sigma=st.sigma,
                                    progress=False).weight.detach()[0].clone()

    rows: list[Row] = []
    steps: list[tuple[str, Callable[[], Row]]] = [
        ("bmu", lambda: row_bmu(st, x_all, w_trained)),
        ("bmu_read", lambda: row_bmu_read(st, x_all, w_trained)),
        ("bmu_kmeans", lambda: row_bmu_kmeans(st, x_all, w_trained, rows[0], peers)),
        ("batch", lambda: row_batch(st, x_all, w0, peers)),
        ("online", lambda: row_online(st, x_or, w0, peers)),
        ("ensemble_online", lambda: row_ensemble_online(st, x_or, w0, rows[4])),
        ("ensemble_online_paper", lambda: row_ensemble_online_paper(st, rows[4])),
        ("ensemble_batch", lambda: row_ensemble_batch(st, x_or, w0)),
        ("ensemble_large", lambda: row_ensemble_large(st, x_or)),
        ("minibatch", lambda: row_minibatch(st, x_or, w0)),
    ]
    for key, make in steps:
        t0 = time.perf_counter()
        rows.append(make())
        print(f"# ... {key} done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)

    print()
    print(common.table(
        ["row", "work", "ours median", "ours min", "peer", "peer median", "peer min", "ratio (of medians)",
         "target", "status"],
        [[r.name, r.work, common.secs(r.ours.median), common.secs(r.ours.min), r.peer or "-",
          common.secs(r.peer_timing.median) if r.peer_timing else "-",
          common.secs(r.peer_timing.min) if r.peer_timing else "-",
          f"{r.ratio:.2f}x {r.ratio_label}" if r.ratio is not None else "-", r.target,
          common.verdict(r.ok)] for r in rows],
        align="llrrlrrlll"))

    more = [(r.name, p, t, rat, lab) for r in rows for p, t, rat, lab in r.peers_extra]
    if more:
        print("\nFurther peers (information, not targets):")
        print(common.table(["row", "peer", "median", "min", "ratio", "ratio is"],
                           [[n, p, common.secs(t.median), common.secs(t.min), f"{rat:.2f}x", lab]
                            for n, p, t, rat, lab in more], align="llrrrl"))

    by = {r.key: r for r in rows}
    print("\nThroughput and checks:")
    lines = [
        f"BMU: {by['bmu'].extra['ours_vectors_per_s'] / 1e6:,.1f} M vectors/s; agreement with the reference "
        f"argmin: {by['bmu'].extra['agreement_with_reference']:.6f}",
        f"online: somtorch {by['online'].extra['ours_steps_per_s']:,.0f} steps/s"
        + (f", MiniSom {by['online'].extra['minisom_steps_per_s']:,.0f} steps/s"
           if "minisom_steps_per_s" in by["online"].extra else ""),
        f"online ensemble: {by['ensemble_online'].extra['member_steps_per_s']:,.0f} member-steps/s = "
        f"{by['ensemble_online'].extra['vs_solo_somtorch']:.1f}x somtorch's solo steps/s",
        f"online ensemble, every pixel: {by['ensemble_online_paper'].extra['member_steps_per_s']:,.0f} "
        f"member-steps/s = {by['ensemble_online_paper'].extra['vs_solo_somtorch']:.1f}x somtorch's solo steps/s"
        + (f" = {by['ensemble_online_paper'].ratio:.0f}x MiniSom" if by['ensemble_online_paper'].ratio else ""),
        f"batch ensemble: {by['ensemble_batch'].extra['speed_up_vs_E_solo_runs']:.1f}x faster than "
        f"{st.ensemble} solo runs in a row",
        f"mini-batch: {by['minibatch'].extra['samples_per_s']:,.0f} samples/s, "
        f"{by['minibatch'].extra['ms_per_step']:.2f} ms per step of {st.batch_size}",
    ]
    lines.append(f"memory read: {by['bmu_read'].extra['read_gib_per_s']:.1f} GiB/s (torch.sum over the NOR array, cold cache)")
    if "agreement_with_sklearn" in by["bmu_kmeans"].extra:
        lines.append(f"BMU vs KMeans.predict: agreement {by['bmu_kmeans'].extra['agreement_with_sklearn']:.6f}")
    lines.append(f"16x16 ensemble: {by['ensemble_large'].extra['ms_per_member']:.2f} ms per member vs "
                 f"{by['ensemble_large'].extra['ms_solo']:.2f} ms solo = "
                 f"{by['ensemble_large'].extra['speed_up_vs_E_solo_runs']:.1f}x faster than {st.ensemble} solo runs")
    lim = by["ensemble_online_paper"].extra
    if "limit_member_steps_per_s_per_core" in lim:
        lines.append(f"online limit: {lim['lane_ops_per_member_step']} lane-ops per member-step (K={st.rows * st.cols}, "
                     f"D=3) against 2 FP units x 8 float32 lanes x {cpu_mhz():,.0f} MHz = "
                     f"{lim['limit_member_steps_per_s_per_core'] / 1e6:,.0f} M member-steps/s per core; measured "
                     f"{100 * lim['share_of_limit_per_core']:.0f} % of it per thread (whole fit: permutations, "
                     "schedule and call overhead included)")
    for key in ("max_abs_weight_diff_vs_xpysom", "max_abs_weight_diff_vs_somoclu", "max_abs_weight_diff_vs_fastersom"):
        if key in by["batch"].extra:
            lines.append(f"batch epoch, same initial weights: {key.replace('_', ' ')} = "
                         f"{by['batch'].extra[key]:.2e}")
    for line in lines:
        print("  " + line)

    t0 = time.perf_counter()
    quality = quality_table(st, x_or, peers)
    print(f"# ... quality table done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    print(f"\nQuality at equal epochs ({st.ensemble_batch_epochs} batch epochs on the OR pixels, same initial "
          "weights, each library's own radius schedule; QE = mean distance to the nearest unit):")
    print(common.table(["grid", "library / schedule", "QE", "median", "min"],
                       [[r["grid"], r["library"], f"{r['qe']:.4f}", common.secs(r["timing"].median),
                         common.secs(r["timing"].min)] for r in quality], align="llrrr"))
    matched = matched_quality(quality)
    if not matched:
        print("\nSpeed at matched quality: no peer SOM library installed here (bash scripts/setup.sh bench)")
    else:
        print("\nSpeed at matched quality (the fastest somtorch setting within 5 % of the best peer's QE, "
              "against the fastest peer within 5 %):")
        print(common.table(["grid", "best peer QE", "somtorch setting", "its QE", "its time", "fastest peer",
                            "peer time", "peer/ours"], matched, align="lllrrlrr"))
    busy = None
    if args.busy:
        t0 = time.perf_counter()
        busy = busy_rows(st, x_all, x_or, w0, w_trained, peers)
        print(f"# ... busy rows done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        print("\nOne core busy (a competing `while True: pass` process started by this script; idle and "
              "busy timed in this run):")
        print(common.table(["row", "idle median", "busy median", "slowdown", "target", "status"], busy,
                           align="lrrrll"))

    wall = time.perf_counter() - t_start
    la = common.loadavg()
    print(f"\n# wall time {wall:.1f} s (after imports); load average at end: "
          + (f"{la[0]:.2f} {la[1]:.2f} {la[2]:.2f}" if la else "unavailable"))
    if args.json:
        info["loadavg_end"] = la
        report = common.Report("bench_core", common.command_line(), args.quick, info, asdict(st),
                               {"rows": [r.as_dict() for r in rows], "peers": peers["available"],
                                "quality": [{**r, "timing": r["timing"].as_dict()} for r in quality],
                                "busy": busy,
                                "peers_missing": peers["missing"],
                                "n_nor": int(x_all.shape[0]), "n_or": int(x_or.shape[0])},
                               wall_s=wall)
        print(f"# JSON written to {report.write(args.json)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
