"""Bound-accelerated BMU search (somtorch.core.bounds): skip shares and speed-ups on the motorcycle.

Run from the repository root::

    python benchmarks/bench_bounds.py            # ~1 min on a quiet machine
    python benchmarks/bench_bounds.py --json out.json

Reported, all on the embedded Middlebury motorcycle, in one process so the ratios share the load:

1. the share of BMU searches the bounds *would* skip per epoch if they ran from the first epoch
   (forced on), for the default job's training pixels (OR, stride 10), every pixel, 10 and 30
   epochs, and the mini-batch rule (bounds carried from one epoch's visit of a sample to the next);
2. the cost of one bounded epoch against the fused kernel at several skip shares (the break-even
   behind ``bounds.START_SHARE``) and of a fresh start;
3. end-to-end seconds of ``run_pipeline`` (what ``somtorch-run`` runs) for the default job and the
   every-pixel job (``features.train_stride=1``), with the bounds as shipped (probe rule) and off:
   the ratio off / on.
"""

from __future__ import annotations

import argparse
import json
import time

import torch


def _best(f, n=3):
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def potential(x, epochs, mode="batch"):
    """Skip share per epoch with the bounds forced on from the start (the weights' trajectory of a
    plain run, the bounds carried from epoch to epoch)."""
    from somtorch import SOM
    from somtorch.core.bounds import BmuBounds

    seen = []
    som = SOM(8, 8, 3, seed=0)
    som.initialize(x)
    seen.append(som.weight.detach().clone())
    som.fit(x, mode=mode, epochs=epochs, progress=False, callback=lambda i: seen.append(i.weight.clone()))
    b, out = BmuBounds(), []
    for w in seen[:-1]:
        b.accumulate(x, w)
        out.append(round(b.skipped, 3))
    return out[1:]


def epoch_costs(x):
    from somtorch import SOM
    from somtorch.core.bounds import BmuBounds
    from somtorch.core.native import native_accumulate

    w = SOM(8, 8, 3, seed=0).fit(x, mode="batch", progress=False).weight.detach().clone()
    dirs = torch.randn(w.shape, generator=torch.Generator().manual_seed(1))
    dirs /= dirs.norm(dim=-1, keepdim=True)
    fused = _best(lambda: native_accumulate(x, w), 5)
    rows = []
    for step in (0.0, 0.001, 0.002, 0.004, 0.008):
        def bounded():
            b = BmuBounds()
            b.accumulate(x, w)
            t = time.perf_counter()
            b.accumulate(x, w + step * dirs)
            return time.perf_counter() - t, b.skipped
        runs = [bounded() for _ in range(3)]
        sec = min(r[0] for r in runs)
        rows.append({"drift": step, "skipped": round(runs[-1][1], 3), "ms": round(1e3 * sec, 2),
                     "fused_over_bounded": round(fused / sec, 2)})
    fresh = _best(lambda: BmuBounds().accumulate(x, w))
    return {"fused_ms": round(1e3 * fused, 2), "fresh_ms": round(1e3 * fresh, 2), "rows": rows}


def end_to_end(scene, stride, reps=7):
    """Seconds (best and median of ``reps``, alternating) of run_pipeline and of its SOM.fit alone,
    bounds as shipped vs off."""
    from statistics import median

    from somtorch import SOM
    from somtorch.config import PipelineConfig, with_overrides
    from somtorch.core import training
    from somtorch.disparity.features import make_features
    from somtorch.pipeline import run_pipeline

    cfg = with_overrides(PipelineConfig(), {"features.train_stride": stride})
    x = make_features(scene.disparity, scene.valid, d_weight=cfg.features.d_weight).subsample(stride).x
    out: dict = {}
    for _ in range(reps):
        for use in (False, True):
            training.USE_BOUNDS = use
            out.setdefault(("pipeline", use), []).append(_best(lambda: run_pipeline(scene, cfg), 1))
            fit = _best(lambda: SOM(8, 8, 3, seed=0).fit(x, progress=False), 1)
            out.setdefault(("fit", use), []).append(fit)
    training.USE_BOUNDS = True
    row = {"train_stride": stride, "pixels": len(x)}
    for what in ("pipeline", "fit"):
        off, on = min(out[(what, False)]), min(out[(what, True)])
        med = median(out[(what, False)]) / median(out[(what, True)])
        row[what] = {"off_s": round(off, 4), "on_s": round(on, 4), "off_over_on": round(off / on, 3),
                     "median_off_over_on": round(med, 3)}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args()
    from somtorch.disparity import load_scene
    from somtorch.disparity.features import make_features

    scene = load_scene("motorcycle")
    feats = make_features(scene.disparity, scene.valid, d_weight=2.0)
    every, orx = feats.x, feats.subsample(10).x
    res = {"command": "python benchmarks/bench_bounds.py", "threads": torch.get_num_threads()}
    res["potential"] = {
        "OR 10 epochs": potential(orx, 10), "every pixel 10 epochs": potential(every, 10),
        "every pixel 30 epochs": potential(every, 30),
        "every pixel minibatch 10 epochs": potential(every, 10, "minibatch"),
    }
    for k, v in res["potential"].items():
        print(f"skip share per epoch, bounds forced on, {k}: {v}")
    res["epoch_costs"] = epoch_costs(every)
    c = res["epoch_costs"]
    print(f"one epoch, every pixel: fused kernel {c['fused_ms']} ms, fresh bounded start {c['fresh_ms']} ms")
    for r in c["rows"]:
        print(f"  bounded epoch, {100 * r['skipped']:.0f} % skipped: {r['ms']} ms "
              f"(fused / bounded {r['fused_over_bounded']}x)")
    res["end_to_end"] = [end_to_end(scene, 10), end_to_end(scene, 1)]
    for r in res["end_to_end"]:
        for what in ("pipeline", "fit"):
            m = r[what]
            print(f"{what}, features.train_stride={r['train_stride']} ({r['pixels']} px): bounds off "
                  f"{m['off_s']} s, as shipped {m['on_s']} s (best of 7), off / on {m['off_over_on']}x "
                  f"(medians: {m['median_off_over_on']}x)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
