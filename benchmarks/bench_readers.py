"""Hostile and large disparity files: peak memory and time of ``read_disparity`` (issue 34).

Each case is read in a fresh subprocess; the peak is the growth of its ``VmHWM`` during the read
(after the imports and a warm-up read), the time its wall clock. The bombs are the issue's
reproducers, built at their sizes by ``tests/fuzz/bombs.py``; the large legitimate files give the
peak as a multiple of the arrays returned (target: ≤ 2×). ``--tree DIR`` reads with the somtorch
package under ``DIR`` (e.g. ``git archive <commit> somtorch | tar -x -C DIR``), for a before/after.

    python benchmarks/bench_readers.py                 # the issue's sizes (~1 min to build)
    python benchmarks/bench_readers.py --quick         # small sizes, seconds
    python benchmarks/bench_readers.py --ratios        # compression ratios of the real maps (headers.MAX_RATIO)
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
_spec = importlib.util.spec_from_file_location("bombs", ROOT / "tests" / "fuzz" / "bombs.py")
assert _spec is not None and _spec.loader is not None
bombs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bombs)

PROBE = r"""
import json, resource, sys, time
from somtorch.disparity.io import read_disparity


def hwm():  # this process's peak RSS, kB (not ru_maxrss: it also holds the parent's peak before exec)
    return int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1])


warm, path = sys.argv[1:3]
read_disparity(warm)
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # the peak RSS restarts from the current RSS (Linux >= 4.0)
base = hwm()
t0 = time.perf_counter()
try:
    d, v = read_disparity(path)
    out, returned = f"read {tuple(d.shape)}", d.numel() * 5
except Exception as e:
    out, returned = f"{type(e).__name__}: {str(e).split(': ', 1)[-1][:90]}", 0
dt = time.perf_counter() - t0
peak = (hwm() - base) * 1024
print(json.dumps({"outcome": out, "seconds": dt, "peak": peak, "returned": returned}))
"""


def build(folder: Path, quick: bool) -> dict[str, Path]:
    """The reproducers and large legitimate files, at the issue's sizes (small with ``quick``)."""
    s = 10 if quick else 1  # quick: a tenth of each side
    rng = np.random.default_rng(0)
    cases = {
        "npz bomb: zeros 10000x10000 float64": bombs.npz_zeros(folder / "zeros64.npz", 10000 // s, 10000 // s),
        "npz bomb: zeros 10000x10000 float32": bombs.npz_zeros(folder / "zeros32.npz", 10000 // s, 10000 // s, "<f4"),
        "png bomb: 14000x14000 16-bit": bombs.png16(folder / "bomb.png", 14000 // s, 14000 // s),
        "tiff bomb: 14000x14000 float32 strips": bombs.tiff_striped(folder / "bomb.tif", 14000 // s, 14000 // s),
        "png overrun: 1000x1000, stream of 2 GB": bombs.png16(folder / "overrun.png", 1000 // s, 1000 // s,
                                                              inflated=2_000_000_000 // s**2),
    }
    n = 4000 // s
    noise = rng.uniform(0, 200, (n, n))
    np.savez_compressed(folder / "noise64.npz", disparity=noise)
    np.save(folder / "noise64.npy", noise)
    sys.path.insert(0, str(ROOT))
    from somtorch.disparity.pfm import write_pfm

    write_pfm(folder / "noise.pfm", noise.astype(np.float32))
    import cv2

    cv2.imwrite(str(folder / "noise16.png"), (noise * 256).astype(np.uint16))
    cv2.imwrite(str(folder / "noise32.tif"), noise.astype(np.float32))
    for name, f in (("npz float64", "noise64.npz"), ("npy float64", "noise64.npy"), ("pfm float32", "noise.pfm"),
                    ("png 16-bit", "noise16.png"), ("tiff float32", "noise32.tif")):
        cases[f"legit {name} {n}x{n}"] = folder / f
    return cases


def ratios() -> None:
    """Decoded / file bytes of every real disparity map of ../shared/data, as stored and re-encoded."""
    import cv2
    import tifffile

    sys.path.insert(0, str(ROOT))
    from somtorch.disparity.io import read_disparity
    from somtorch.disparity.pfm import read_pfm

    rows: dict[str, list[tuple[float, str]]] = {}
    tmp = Path(tempfile.mkdtemp()) / "t.tif"
    for f in sorted(DATA.glob("**/disp*.p*")):
        raw = read_pfm(f)[0] if f.suffix == ".pfm" else cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        name = str(f.relative_to(DATA))
        if f.suffix == ".png":
            rows.setdefault("its own PNG", []).append((raw.nbytes / f.stat().st_size, name))
        d = read_disparity(f, scale=1.0 if raw.dtype == np.uint8 else None)[0].numpy()
        for kind, a in (("stored dtype", raw), ("float32", d), ("float64", d.astype(np.float64))):
            b = io.BytesIO()
            np.savez_compressed(b, disparity=a)
            rows.setdefault(f"npz, {kind}", []).append((a.nbytes / len(b.getvalue()), name))
            tifffile.imwrite(tmp, a, compression="zlib")
            rows.setdefault(f"deflate TIFF, {kind}", []).append((a.nbytes / tmp.stat().st_size, name))
    print(f"{len(rows['npz, float32'])} real disparity maps under {DATA}")
    print(f"{'stored as':28s} {'max':>7s} {'median':>7s}  most compressible")
    for kind, v in rows.items():
        v.sort()
        print(f"{kind:28s} {v[-1][0]:6.1f}:1 {v[len(v) // 2][0]:6.1f}:1  {v[-1][1]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--ratios", action="store_true")
    ap.add_argument("--tree", type=Path, help="read with the somtorch package under this folder")
    ap.add_argument("--timeout", type=float, default=600)
    args = ap.parse_args()
    if args.ratios:
        ratios()
        return
    env = dict(os.environ, PYTHONPATH=str(args.tree or ROOT))
    print(f"command: {' '.join([Path(sys.executable).name] + sys.argv)}; load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        warm = bombs.png16(folder / "warm.png", 8, 8)
        cases = build(folder, args.quick)
        print(f"{'case':44s} {'file':>10s} {'peak MB':>8s} {'x out':>6s} {'s':>7s}  outcome")
        for name, f in cases.items():
            try:
                p = subprocess.run([sys.executable, "-c", PROBE, str(warm), str(f)], env=env, capture_output=True,
                                   text=True, timeout=args.timeout, cwd=tmp)
                r = json.loads(p.stdout.strip().splitlines()[-1]) if p.returncode == 0 else {
                    "outcome": f"exit {p.returncode}: {p.stderr.strip().splitlines()[-1:]}", "seconds": float("nan"),
                    "peak": 0, "returned": 0}
            except subprocess.TimeoutExpired:
                r = {"outcome": f"killed after {args.timeout:.0f} s", "seconds": args.timeout, "peak": 0, "returned": 0}
            x = f"{r['peak'] / r['returned']:.2f}" if r["returned"] else "-"
            print(f"{name:44s} {f.stat().st_size / 1e6:9.2f}M {r['peak'] / 2**20:8.0f} {x:>6s} {r['seconds']:7.2f}  "
                  f"{r['outcome']}", flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
