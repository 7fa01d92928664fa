"""Tiles benchmark: divide and conquer (2 x 2 tiles) against the whole map, quality and time.

Run from the repository root::

    python benchmarks/bench_tiles.py            # the real dev scenes x 10 seeds + a 3840x2160 map (~3 min)
    python benchmarks/bench_tiles.py --quick    # two scenes, 3 seeds, no 4K map

Rows, measured in the same run on the same seeds: the whole map (``run_pipeline``), tiles run one
after the other in this process (``workers=0``) and tiles in 2 worker processes (``workers=2``;
their start-up, about a second per worker for Python + torch, is included). Quality: useful hits
of the main object per scene (``../shared/data`` needed; skipped without). Time: median seconds per
map. The 3840 x 2160 map is the shared Motorcycle_Q resampled (or the embedded one).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

try:  # python -m benchmarks.bench_tiles
    from . import common
except ImportError:  # python benchmarks/bench_tiles.py
    import common

from somtorch.config import PipelineConfig, with_overrides
from somtorch.pipeline import run_pipeline
from somtorch.tiles import run_tiled


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    a = p.parse_args(argv)
    print(common.header("bench_tiles: 2x2 tiles against the whole map", common.machine_info()), flush=True)
    data = common.REPO_ROOT.parent / "shared" / "data"
    runs = 3 if a.quick else 10
    cfg = with_overrides(PipelineConfig(), {"ensemble": runs})
    if data.is_dir():
        sys.path.insert(0, str(common.REPO_ROOT))
        from experiments.datasets import frames, load_frame

        specs = [s for s in frames(real=True) if not s.computed][: 2 if a.quick else None]
        tot = [0, 0]
        print(f"| scene | whole: useful of {runs} | s | tiles: useful | s |\n|---|---|---|---|---|")
        for spec in specs:
            sc = load_frame(spec, data)
            t0 = time.perf_counter()
            whole = run_pipeline(sc, cfg, metrics=False)
            t1 = time.perf_counter()
            tiled = run_tiled(sc, cfg, tiles=(2, 2))
            t2 = time.perf_counter()
            uw = sum(m.score.useful_hit for m in whole.members)
            ut = sum(m.score.useful_hit for m in tiled.members)
            tot[0] += uw
            tot[1] += ut
            print(f"| {spec.name} | {uw} | {t1 - t0:.2f} | {ut} | {t2 - t1:.2f} |", flush=True)
        print(f"| **total** | **{tot[0]}** | | **{tot[1]}** | |")
    if not a.quick:
        from somtorch.disparity.resize import resize_scene
        from somtorch.disparity import load_scene

        src = data / "middlebury2014" / "Motorcycle_Q"
        big = resize_scene(load_scene(src if src.is_dir() else "motorcycle"), 3840, 2160)
        one = with_overrides(PipelineConfig(), {"ensemble": 1})
        rows = {"whole map": lambda: run_pipeline(big, one, metrics=False),
                "tiles, workers=0": lambda: run_tiled(big, one, tiles=(2, 2), workers=0),
                "tiles, workers=2": lambda: run_tiled(big, one, tiles=(2, 2), workers=2)}
        print(f"\n3840x2160 ({big.name}), ensemble 1, median of 3 after one warm-up:")
        print("| row | s | useful |\n|---|---|---|")
        for name, fn in rows.items():
            fn()
            times, res = [], None
            for _ in range(3):
                t0 = time.perf_counter()
                res = fn()
                times.append(time.perf_counter() - t0)
            s = res.members[0].score
            print(f"| {name} | {statistics.median(times):.2f} | {'-' if s is None else s.useful_hit} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
