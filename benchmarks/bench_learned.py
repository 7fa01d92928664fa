"""Learned baseline vs SOM: per-frame CPU cost on the same frames, training time, parameters.

Run from the repository root::

    python benchmarks/bench_learned.py                   # needs the trained default model (somtorch-train-baseline)
    python benchmarks/bench_learned.py --quick           # smoke run: a tiny model trained in the run (seconds)
    python benchmarks/bench_learned.py --json out.json   # also write every timing as JSON

Frames: the embedded Middlebury Motorcycle (741x500, GT) and one generated frame per camera at
full size (``road``/kitti 1242x375, ``room``/oakd 640x480, ``tabletop``/middlebury 741x497; seed 0,
SGBM version, rendered into the corpus cache if missing). Methods, each on every frame:
``learned`` (the default model of the cache, the whole path: input preparation, the network,
resizing back, the mask's parts as boxes), ``som`` (``run_pipeline`` with the default
:class:`~somtorch.pipeline.PipelineConfig`, one member, no metrics), and the task baselines
``uv_disparity`` and ``plane_components`` as context. Wall time: median and min of the repeats
after one warm-up. Memory: the peak resident-set growth of one call, measured in a fresh process
per method (``/proc/self/clear_refs`` resets the peak before each frame). Training: the seconds
and thread count in the model's sidecar (measured when it was trained) beside its estimate.
Target: fewer than 1 M parameters (issue 32: "well under 1 M").
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path

try:  # python -m benchmarks.bench_learned
    from . import common
except ImportError:  # python benchmarks/bench_learned.py
    import common

FRAMES = (("road", "kitti"), ("room", "oakd"), ("tabletop", "middlebury"))
METHODS = ("learned", "som", "uv_disparity", "plane_components")
MAX_PARAMS = 1_000_000


def load_frames(quick: bool) -> list:
    from somtorch.disparity import load_scene
    from somtorch.synth import load_frame

    scale = 0.25 if quick else 1.0
    frames = [load_scene("motorcycle")]
    frames += [load_frame(f, 0, c, "sgbm", scale=scale) for f, c in FRAMES]
    return frames


def tiny_model_cfgs():
    from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig

    return (LearnedModelConfig(widths=[8, 16], height=32, width=48),
            LearnedDataConfig(families=["garden"], cameras=["oakd"], frames=2, held_out=1, scale=0.1),
            LearnedFitConfig(epochs=1))


def get_model(quick: bool):
    """``(model, sidecar)``: the cached default model, or with ``quick`` a tiny one trained now."""
    from somtorch.baselines.learned import checkpoint
    from somtorch.baselines.learned.store import model_path, train_or_load
    from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig

    if quick:
        model, meta, _ = train_or_load(*tiny_model_cfgs())
        return model, meta
    cfgs = LearnedModelConfig(), LearnedDataConfig(), LearnedFitConfig()
    path = model_path(*cfgs)
    if not path.is_file():
        sys.exit(f"error: no trained default model in {path.parent}: run somtorch-train-baseline first")
    return checkpoint.load(path, model_cfg=cfgs[0]), checkpoint.read_meta(path)


def method_fn(name: str, quick: bool):
    """``fn(scene)`` running ``name`` once on a scene."""
    if name == "som":
        from somtorch.pipeline import PipelineConfig, run_pipeline

        cfg = PipelineConfig(ensemble=1)
        return lambda s: run_pipeline(s, cfg, progress=False, metrics=False)
    from somtorch.tasks.baselines import get_task_baseline, learned_boxes

    if name == "learned":
        model, _ = get_model(quick)
        return lambda s: learned_boxes(s.disparity, s.valid, s.camera, model=model)
    fn = get_task_baseline(name)
    return lambda s: fn(s.disparity, s.valid, s.camera)


def _rss_kib(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return None


def _peak_worker(name: str, quick: bool, conn) -> None:
    """In a fresh process: the peak RSS growth (bytes) of one call of ``name`` on each frame."""
    import torch

    torch.set_num_threads(2)
    fn, frames = method_fn(name, quick), load_frames(quick)
    out = []
    for s in frames:
        try:
            Path("/proc/self/clear_refs").write_text("5")  # reset the peak (VmHWM) to the current RSS
            base = _rss_kib("VmRSS")
            fn(s)
            peak = _rss_kib("VmHWM")
            out.append(None if base is None or peak is None else 1024 * (peak - base))
        except OSError:
            out.append(None)
    conn.send(out)
    conn.close()


def peak_memory(name: str, quick: bool) -> list[int | None]:
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_peak_worker, args=(name, quick, child))
    p.start()
    got = parent.recv()
    p.join()
    return got


def mib(b: int | None) -> str:
    return "-" if b is None else f"{b / 2**20:,.1f} MiB"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="smoke run: quarter-size frames, a tiny model, 2 repeats")
    p.add_argument("--json", metavar="PATH", help="write settings, machine info and all timings here")
    p.add_argument("--repeats", type=int, default=None, help="timed calls per method and frame (default 7; --quick 2)")
    args = p.parse_args(argv)
    t_start = time.perf_counter()
    repeats = args.repeats or (2 if args.quick else 7)
    info = common.machine_info()
    frames = load_frames(args.quick)
    model, meta = get_model(args.quick)
    extra = [f"frames: {', '.join(f'{s.name} {s.width}x{s.height}' for s in frames)}",
             f"timing: median / min of {repeats} calls after 1 warm-up; memory: peak RSS growth of one call, "
             f"fresh process per method"]
    if args.quick:
        extra.append("QUICK smoke run: quarter-size frames and a tiny model; the figures are NOT a verdict")
    print(common.header("bench_learned: learned baseline vs SOM, per frame", info, extra), flush=True)
    report = common.Report("bench_learned", common.command_line(), args.quick, info,
                           {"repeats": repeats, "frames": [s.name for s in frames], "methods": list(METHODS)})
    timings = {}
    for name in METHODS:
        fn = method_fn(name, args.quick)
        timings[name] = [common.measure(lambda _, s=s: fn(s), repeats=repeats) for s in frames]
    peaks = {name: peak_memory(name, args.quick) for name in METHODS}
    rows = []
    for i, s in enumerate(frames):
        som_t, som_m = timings["som"][i].median, peaks["som"][i]
        for name in METHODS:
            t, m = timings[name][i], peaks[name][i]
            rows.append([s.name if name == METHODS[0] else "", name, common.secs(t.median), common.secs(t.min),
                         f"{t.median / som_t:.2f}x", mib(m),
                         "-" if m is None or not som_m else f"{m / som_m:.2f}x"])
    print("\nPer frame (ratios against the SOM pipeline on the same frame, same run):")
    print(common.table(["frame", "method", "median", "min", "/ SOM", "peak RSS growth", "/ SOM"], rows,
                       align="llrrrrr"))
    med = {n: statistics.median(t.median for t in timings[n]) for n in METHODS}
    print("\nMedian over the frames: " + ", ".join(f"{n} {common.secs(med[n])}" for n in METHODS)
          + f"; learned / SOM = {med['learned'] / med['som']:.2f}x")
    params = meta["parameters"]
    from somtorch.baselines.learned.train import estimate
    from somtorch.config.learned import LearnedFitConfig

    est = estimate(model.cfg, LearnedFitConfig(**meta["fit"]), train_frames=meta["train_frames"],
                   held_out_frames=meta["held_out_metrics"]["frames"])
    print(f"\nTraining (from the sidecar, measured when it was trained): {meta['train_s']} s training + "
          f"{meta['prepare_s']} s preparing {meta['train_frames']} frames on {meta['threads']} thread(s) "
          f"(estimate for 2 idle cores: {est.train_s:.0f} s); the SOM trains per frame, inside its time above")
    ok = params < MAX_PARAMS
    print(f"Parameters: {params:,} (target < {MAX_PARAMS:,}) -> {common.verdict(ok)}")
    report.results = {"timings": {n: [t.as_dict() for t in timings[n]] for n in METHODS}, "peak_bytes": peaks,
                      "median_s": med, "parameters": params, "train_s": meta["train_s"],
                      "prepare_s": meta["prepare_s"], "train_threads": meta["threads"],
                      "train_estimate_s": est.train_s, "held_out_metrics": meta["held_out_metrics"]}
    report.wall_s = time.perf_counter() - t_start
    la = common.loadavg()
    print(f"\nload average at end: {la[0]:.2f} {la[1]:.2f} {la[2]:.2f}" if la else "")
    if args.json:
        report.write(args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
