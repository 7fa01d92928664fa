"""Video benchmark: frames per second of the sequence runner, warm-started against cold.

Run from the repository root::

    python benchmarks/bench_video.py                 # 60 frames at 1264x720 (~1 min on 2 cores)
    python benchmarks/bench_video.py --quick         # 12 small frames (seconds)
    python benchmarks/bench_video.py --json out.json

Sequence: a synthetic camera pan (:func:`somtorch.video.pan_sequence`, 4 px per frame) over the
Middlebury Motorcycle resized to 1.25 x 1264 x 720, cut to 1264 x 720 windows; the shared
``Motorcycle_Q`` with its object mask when ``../shared/data`` is there (then every frame is scored),
else the embedded scikit-image map (timing only). OR mode, one SOM per frame (``ensemble=1``).

Rows, measured in the same run: **cold** (every frame trained from scratch: the configured
schedule, ground refitted — what ``run_pipeline`` does per frame) and **warm** (the previous
frame's weights, ``warm_epochs`` batch epochs at a small radius, the ground plane re-used while
it fits). Printed: median ms per frame and per stage, frames per second, the warm/cold ratio, and
on the masked scene the useful hits of each row (warm frames must keep the object as well as
cold ones).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

try:  # python -m benchmarks.bench_video
    from . import common
except ImportError:  # python benchmarks/bench_video.py
    import common

from somtorch.config import PipelineConfig, with_overrides
from somtorch.disparity.resize import resize_scene
from somtorch.video import SequenceRunner, pan_sequence


def base_scene(quick: bool):
    shared = common.REPO_ROOT.parent / "shared" / "data" / "middlebury2014" / "Motorcycle_Q"
    from somtorch.disparity import load_scene

    scene = load_scene(shared) if shared.is_dir() else load_scene("motorcycle")
    w, h = (316, 180) if quick else (1264, 720)
    return resize_scene(scene, round(1.25 * w), round(1.25 * h)), w, h


def run_row(name: str, frames: list, cfg: PipelineConfig, warm: bool) -> dict:
    runner = SequenceRunner(cfg, warm=warm)
    runner.step(frames[0])  # warm-up frame (cold either way), not counted
    res, wall = [], []
    for f in frames[1:]:
        t0 = time.perf_counter()
        res.append(runner.step(f))
        wall.append(time.perf_counter() - t0)  # end to end, checks and bookkeeping included
    per = [r.seconds for r in res]
    stages = sorted({k for r in res for k in r.timings})
    scored = [r.members[0].score for r in res if r.members[0].score is not None]
    return {"row": name, "frames": len(res), "median_ms": 1e3 * statistics.median(per),
            "fps": 1.0 / statistics.median(per), "wall_ms": 1e3 * statistics.median(wall),
            "stages_ms": {k: 1e3 * statistics.median(r.timings.get(k, 0.0) for r in res) for k in stages},
            "useful_hits": sum(s.useful_hit for s in scored) if scored else None,
            "ground_reused": sum(r.ground_reused for r in res)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args(argv)
    scene, w, h = base_scene(a.quick)
    n = a.frames or (12 if a.quick else 61)
    frames = list(pan_sequence(scene, w, h, n))
    cfg = with_overrides(PipelineConfig(), {"ensemble": 1})
    rows = [run_row("cold", frames, cfg, warm=False), run_row("warm", frames, cfg, warm=True)]
    # what a camera delivers: no object mask, so no scoring; the wall time is the whole frame
    bare = [replace(f, objects=None) for f in frames]
    rows.append(run_row("warm, no mask (end to end)", bare, cfg, warm=True))
    print(common.header("bench_video: warm-started frames against cold ones", common.machine_info()))
    print(f"sequence: {len(frames) - 1} timed frames of {w}x{h} (pan over {scene.name}), OR, ensemble 1")
    stages = sorted({k for r in rows for k in r["stages_ms"]})
    print("| row | ms / frame (stages) | fps | wall ms / frame (scoring incl.) | " + " | ".join(stages)
          + " | useful hits | ground re-used |")
    print("|---|---|---|---|" + "---|" * len(stages) + "---|---|")
    for r in rows:
        print(f"| {r['row']} | {r['median_ms']:.1f} | {r['fps']:.1f} | {r['wall_ms']:.1f} | "
              + " | ".join(f"{r['stages_ms'][k]:.1f}" for k in stages)
              + f" | {'-' if r['useful_hits'] is None else r['useful_hits']} | {r['ground_reused']} |")
    print(f"warm / cold time per frame: {rows[1]['median_ms'] / rows[0]['median_ms']:.2f}")
    e2e = rows[2]["wall_ms"]
    print(f"end to end (warm, no mask, wall): {e2e:.1f} ms/frame = {1e3 / e2e:.1f} fps; target >= 30 fps: "
          + ("PASS" if 1e3 / e2e >= 30 else "FAIL"))
    if a.json:
        report = common.Report("bench_video", common.command_line(), a.quick, common.machine_info(),
                               {"width": w, "height": h, "frames": n, "scene": scene.name}, {"rows": rows})
        print(f"# JSON written to {report.write(a.json)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
