"""Scale benchmark: train + segment maps from 9,072 px to 100 M px in a bounded memory budget.

Run from the repository root::

    python benchmarks/bench_scale.py                     # 9,072 px, 8.3 M px, 100 M px (~3 min, ~1 GB disk)
    python benchmarks/bench_scale.py --quick             # 9,072 px and 1 M px (seconds)
    python benchmarks/bench_scale.py --budget 1e9 --json out.json

Each size runs in a fresh subprocess: the Middlebury Motorcycle (embedded) is resampled
(nearest, disparities scaled) to ``W × H`` block by block into a memory-mapped ``.npy``, then
:func:`somtorch.large.train_segment_large` computes the OR training features (stride 10) into a
memory map, trains an 8×8 SOM with the chunked batch map (10 epochs) and labels every pixel into an
``int16`` memory map. Reported per size: seconds per stage, **peak resident memory** of the
process (``VmHWM``, which includes the ~0.3–0.4 GB of the Python + torch runtime) against the
budget, and the fitted exponent of time against pixels (1 = linear).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

try:  # python -m benchmarks.bench_scale
    from . import common
except ImportError:  # python benchmarks/bench_scale.py
    import common

SIZES = [(126, 72), (3840, 2160), (13334, 7500)]
QUICK = [(126, 72), (1333, 750)]


def make_map(path: Path, w: int, h: int, rows: int = 512):
    import numpy as np
    from skimage import data

    _l, _r, disp = data.stereo_motorcycle()
    disp = disp.astype(np.float32)
    h0, w0 = disp.shape
    cols = (np.arange(w) * w0 // w).astype(np.int64)
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(h, w))
    for r in range(0, h, rows):
        src = (np.arange(r, min(h, r + rows)) * h0 // h).astype(np.int64)
        out[r:r + len(src)] = disp[src][:, cols] * (w / w0)
    out.flush()
    return np.load(path, mmap_mode="r")


def one(w: int, h: int, budget: int) -> dict:
    from somtorch.large import train_segment_large

    with tempfile.TemporaryDirectory(prefix="somtorch-scale-") as d:
        t0 = time.perf_counter()
        disp = make_map(Path(d) / "disp.npy", w, h)
        t_make = time.perf_counter() - t0
        res = train_segment_large(disp, d, memory_budget=budget)
        labelled = int((res.labels >= 0).sum())
    # VmHWM, not ru_maxrss: a child's ru_maxrss keeps its parent's size before exec (Linux)
    peak = int(next(ln for ln in open("/proc/self/status") if ln.startswith("VmHWM")).split()[1]) * 1024
    return {"width": w, "height": h, "pixels": w * h, "valid": res.n_valid, "train": res.n_train,
            "labelled": labelled, "block_rows": res.block_rows, "make_s": t_make, "timings_s": res.timings,
            "total_s": sum(res.timings.values()), "peak_rss_bytes": peak, "budget_bytes": budget}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--budget", type=float, default=2 * 2 ** 30, help="memory budget in bytes (default 2 GiB)")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--one", nargs=2, type=int, metavar=("W", "H"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    budget = int(a.budget)
    if a.one:
        print(json.dumps(one(a.one[0], a.one[1], budget)))
        return 0
    print(common.header("bench_scale: train + segment in a memory budget", common.machine_info()), flush=True)
    rows = []
    for w, h in (QUICK if a.quick else SIZES):
        proc = subprocess.run([sys.executable, __file__, "--one", str(w), str(h), "--budget", str(budget)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            print(proc.stderr[-3000:], file=sys.stderr)
            return 1
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"{w}x{h} = {r['pixels']:,} px: {r['total_s']:.2f} s "
              f"({', '.join(f'{k} {v:.2f}' for k, v in r['timings_s'].items())}), peak RSS "
              f"{r['peak_rss_bytes'] / 2**30:.2f} GiB of {budget / 2**30:.2f}", flush=True)
    print("| map | pixels | valid | train | scan s | features s | train s | segment s | total s | peak RSS GiB | within budget |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        t = r["timings_s"]
        print(f"| {r['width']}x{r['height']} | {r['pixels']:,} | {r['valid']:,} | {r['train']:,} | {t['scan']:.2f} | "
              f"{t['features']:.2f} | {t['train']:.2f} | {t['segment']:.2f} | {r['total_s']:.2f} | "
              f"{r['peak_rss_bytes'] / 2**30:.2f} | {'yes' if r['peak_rss_bytes'] <= budget else 'NO'} |")
    if len(rows) >= 2:
        xs = [math.log(r["pixels"]) for r in rows]
        ys = [math.log(r["total_s"]) for r in rows]
        n = len(xs)
        mx, my = sum(xs) / n, sum(ys) / n
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
        big = rows[-2:]
        pair = math.log(big[1]["total_s"] / big[0]["total_s"]) / math.log(big[1]["pixels"] / big[0]["pixels"])
        print(f"time ~ pixels^{slope:.2f} over all sizes; ^{pair:.2f} between the two largest (1 = linear)")
    if a.json:
        report = common.Report("bench_scale", common.command_line(), a.quick, common.machine_info(),
                               {"budget_bytes": budget, "sizes": [[r["width"], r["height"]] for r in rows]},
                               {"rows": rows})
        print(f"# JSON written to {report.write(a.json)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
