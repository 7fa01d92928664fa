"""Pipeline benchmark: the whole paper pipeline on a 1264×720 disparity map with a 4×7 SOM.

Run from the repository root::

    python benchmarks/bench_pipeline.py                  # full run (~10 s on 2 idle cores)
    python benchmarks/bench_pipeline.py --quick          # smoke run on small maps (seconds)
    python benchmarks/bench_pipeline.py --json out.json  # also write every timing as JSON

Map: the embedded Middlebury Motorcycle (``skimage.data.stereo_motorcycle()``, 741×500) resized with
``cv2.INTER_NEAREST`` — disparity and valid mask alike, disparities multiplied by the horizontal
scale factor — and wrapped with :func:`somtorch.disparity.scene.scene_from_arrays`.

Table 1: ``run_pipeline`` with the default :class:`~somtorch.pipeline.PipelineConfig` except
``som=SOMConfig(rows=4, cols=7)`` and ``ensemble=1`` (OR mode: ``features.train_stride=10``), median
and min over ≥ 20 runs (seed = run index) after one warm-up, every stage of ``result.timings``
(point clouds are not part of ``run_pipeline``); target: median total < 100 ms.

Table 2: runtime against pixel count in NOR mode (``features.train_stride=1``): the map resized to
6 sizes from 126×72 = 9,072 px to 1264×720 = 910,080 px, 3 runs each, with a least-squares fit of
time against pixels (slope per 100k px) and the log-log exponent, for the total and every stage.
The paper claims at most linear growth and an almost constant object-area time.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

try:  # python -m benchmarks.bench_pipeline
    from . import common
except ImportError:  # python benchmarks/bench_pipeline.py
    import common

from somtorch.disparity.scene import Scene, scene_from_arrays
from somtorch.pipeline import PipelineConfig, SOMConfig, run_pipeline, train_stride

STAGE_ORDER = ("ground", "features", "train", "segment", "objects", "reduction")
CORE_STAGES = ("train", "segment", "objects", "reduction")
TARGET_S = 0.100
LINEAR_EXPONENT_MAX = 1.10  # "at most linear", with room for timing noise
CONSTANT_EXPONENT_MAX = 0.25  # "almost constant"


@dataclass(frozen=True)
class Settings:
    width: int = 1264
    height: int = 720
    runs: int = 20
    scale_factors: tuple[float, ...] = tuple(float(f) for f in np.geomspace(0.1, 1.0, 6))
    scale_repeats: int = 3
    online_runs: int = 3  # context table: the paper's online rule instead of the default
    rows: int = 4
    cols: int = 7


FULL = Settings()
QUICK = Settings(width=316, height=180, runs=3, scale_factors=(0.1, 0.16, 0.25, 0.4), scale_repeats=1,
                 online_runs=1)


# -------------------------------------------------------------------------------------------- data
def motorcycle_arrays() -> tuple[np.ndarray, np.ndarray]:
    """The embedded Motorcycle ground truth: disparity (0 where invalid) and valid mask, 500×741."""
    from skimage import data

    _left, _right, disp = data.stereo_motorcycle()
    disp = np.asarray(disp, dtype=np.float32)
    valid = np.isfinite(disp)
    return np.where(valid, disp, 0.0).astype(np.float32), valid


def resized_scene(disp: np.ndarray, valid: np.ndarray, width: int, height: int) -> Scene:
    """The map resized to ``width × height`` by nearest neighbour (disparity values scaled with width)."""
    import cv2

    d = cv2.resize(disp, (width, height), interpolation=cv2.INTER_NEAREST) * (width / disp.shape[1])
    v = cv2.resize(valid.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)
    return scene_from_arrays(d.astype(np.float32), v, name=f"motorcycle_{width}x{height}",
                             source={"disparity": "skimage.data.stereo_motorcycle() resized (nearest)"})


def base_config(st: Settings) -> PipelineConfig:
    return PipelineConfig(som=SOMConfig(rows=st.rows, cols=st.cols), ensemble=1)


# ------------------------------------------------------------------------------------------ timing
def time_runs(scene: Scene, cfg: PipelineConfig, runs: int, warmup: int = 1) -> list[dict[str, float]]:
    """``result.timings`` of ``runs`` calls (seed = ``cfg.seed`` + run index) plus ``"wall"``, the whole
    call, ``"total"`` (sum of the stages) and ``"core"`` (train + segment + objects + reduction)."""
    for _ in range(warmup):
        run_pipeline(scene, cfg, progress=False, metrics=False)
    out = []
    for i in range(runs):
        c = replace(cfg, seed=cfg.seed + i)
        t0 = time.perf_counter()
        res = run_pipeline(scene, c, progress=False, metrics=False)
        wall = time.perf_counter() - t0
        t = dict(res.timings)
        t["total"] = sum(res.timings.values())
        t["core"] = sum(res.timings.get(k, 0.0) for k in CORE_STAGES)
        t["wall"] = wall
        t["kept_areas"] = float(len(res.members[0].kept))
        out.append(t)
    return out


def stages_present(runs: list[dict[str, float]]) -> list[str]:
    keys = [k for k in runs[0] if k not in ("total", "core", "wall", "kept_areas")]
    return [k for k in STAGE_ORDER if k in keys] + [k for k in keys if k not in STAGE_ORDER]


def med(runs: list[dict[str, float]], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def fit_linear(px: np.ndarray, t: np.ndarray) -> dict[str, float]:
    """Least squares ``t = a + b·px`` (R² included) and ``log t = c + p·log px``."""
    A = np.stack([np.ones_like(px), px], axis=1)
    (a, b), *_ = np.linalg.lstsq(A, t, rcond=None)
    resid = t - (a + b * px)
    ss_tot = float(((t - t.mean()) ** 2).sum())
    r2 = 1.0 - float((resid ** 2).sum()) / ss_tot if ss_tot > 0 else float("nan")
    pos = t > 0
    if pos.sum() >= 2:
        p = np.polyfit(np.log(px[pos]), np.log(t[pos]), 1)[0]
    else:
        p = float("nan")
    return {"intercept_ms": float(a) * 1e3, "slope_ms_per_100k_px": float(b) * 1e3 * 1e5, "r2": r2,
            "loglog_exponent": float(p)}


# -------------------------------------------------------------------------------------------- main
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 316x180 map, 3 runs, 4 small sizes x 1 run for the scaling table")
    p.add_argument("--json", metavar="PATH", help="write settings, machine info and all timings here")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t_start = time.perf_counter()
    st = QUICK if args.quick else FULL
    info = common.machine_info()
    disp, valid = motorcycle_arrays()
    cfg = base_config(st)
    tc, fc = cfg.train, cfg.features
    scene = resized_scene(disp, valid, st.width, st.height)
    n_px = st.width * st.height
    n_valid = int(scene.valid.sum())
    extra = [
        f"map: skimage Motorcycle GT {disp.shape[1]}x{disp.shape[0]} resized (nearest) to "
        f"{st.width}x{st.height}"
        f" = {n_px:,} px, {n_valid:,} valid ({n_valid / n_px:.1%})",
        f"config: PipelineConfig() except som=SOMConfig(rows={st.rows}, cols={st.cols}), ensemble=1 -> "
        f"train mode={tc.mode}, epochs={tc.epochs}, features stride={fc.train_stride}, "
        f"d_weight={fc.d_weight}, ground rule={cfg.ground.rule}, objects rule={cfg.objects.rule}",
        "timing: result.timings per stage (point cloud not included); run_pipeline(progress=False, "
        "metrics=False); seed = run index; 1 untimed warm-up",
    ]
    if args.quick:
        extra.append("QUICK smoke run: small maps and few runs; PASS/FAIL below is NOT a verdict")
    print(common.header("bench_pipeline: paper pipeline, 4x7 SOM, Motorcycle", info, extra), flush=True)
    report = common.Report("bench_pipeline", common.command_line(), args.quick, info,
                           {**asdict(st), "pipeline_config": cfg.as_dict()})

    # ---------------------------------------------------------------- table 1: OR mode, >= 20 runs
    runs = time_runs(scene, cfg, st.runs)
    stages = stages_present(runs)
    meds = {k: med(runs, k) for k in stages}
    sum_meds = sum(meds.values())
    rows = [[k, common.ms(meds[k]), common.ms(min(r[k] for r in runs)), common.ms(max(r[k] for r in runs)),
             f"{100 * meds[k] / sum_meds:.1f} %" if sum_meds > 0 else "-"] for k in stages]
    total_med, core_med = med(runs, "total"), med(runs, "core")
    rows += [
        ["TOTAL (all stages)", common.ms(total_med), common.ms(min(r["total"] for r in runs)),
         common.ms(max(r["total"] for r in runs)), ""],
        [" + ".join(k for k in CORE_STAGES if k in stages), common.ms(core_med),
         common.ms(min(r["core"] for r in runs)), common.ms(max(r["core"] for r in runs)), ""],
        ["run_pipeline wall (all of it)", common.ms(med(runs, "wall")),
         common.ms(min(r["wall"] for r in runs)),
         common.ms(max(r["wall"] for r in runs)), ""],
    ]
    ts = train_stride(scene, cfg)  # features.train_stride counted on 640 x 480, scaled to this size
    n_train = len(range(0, st.height, ts)) * len(range(0, st.width, ts))
    print(f"\nTable 1: {st.width}x{st.height}, OR mode (train stride {ts}, "
          f"<= {n_train:,} train px; "
          f"all {n_valid:,} valid px segmented), {st.runs} runs")
    print(common.table(["stage", "median", "min", "max", "share of summed medians"], rows, align="lrrrr"))
    ok = total_med < TARGET_S
    print(f"target: median total of all stages < {TARGET_S * 1e3:.0f} ms: {total_med * 1e3:.1f} ms -> "
          f"{common.verdict(ok)} (train+segment+objects+reduction only: {core_med * 1e3:.1f} ms -> "
          f"{common.verdict(core_med < TARGET_S)})")
    kept = [r["kept_areas"] for r in runs]
    print(f"kept object areas per run: median {statistics.median(kept):.0f}, min {min(kept):.0f}, "
          f"max {max(kept):.0f}")
    report.results["table1"] = {"runs": runs, "stages": stages, "median_s": meds, "total_median_s": total_med,
                                "core_median_s": core_med, "target_s": TARGET_S, "status": common.verdict(ok)}

    # ---------------------------------------------------------------- context: the paper's online rule
    if st.online_runs:
        cfg_on = replace(cfg, train=replace(cfg.train, mode="online"))
        on = time_runs(scene, cfg_on, st.online_runs)
        print(f"\nContext (not a target): same map and config with train.mode='online' (the paper's rule, "
              f"{cfg_on.train.epochs} epochs), {st.online_runs} runs: median total "
              f"{common.secs(med(on, 'total'))}, of which train {common.secs(med(on, 'train'))}")
        report.results["online_context"] = {"runs": on}

    # ---------------------------------------------------------------- table 2: scaling, NOR mode
    cfg_nor = replace(cfg, features=replace(cfg.features, train_stride=1))
    sizes = [(max(2, round(st.width * f)), max(2, round(st.height * f))) for f in st.scale_factors]
    scenes = [resized_scene(disp, valid, w, h) for w, h in sizes]
    run_pipeline(scenes[0], cfg_nor, progress=False, metrics=False)  # warm-up
    per_size = [{"width": w, "height": h, "pixels": w * h, "valid": int(sc.valid.sum()), "runs": []}
                for (w, h), sc in zip(sizes, scenes)]
    for rep in range(st.scale_repeats):  # sizes interleaved, so a burst of load does not hit one size only
        for s, sc in zip(per_size, scenes):
            s["runs"] += time_runs(sc, replace(cfg_nor, seed=rep), 1, warmup=0)
    stages2 = stages_present(per_size[0]["runs"])
    hdr = ["size", "pixels", "valid px", "total median", "total min", *[f"{k}" for k in stages2],
           "total ms/100k px"]
    rows2 = []
    for s in per_size:
        tm = med(s["runs"], "total")
        rows2.append([f"{s['width']}x{s['height']}", f"{s['pixels']:,}", f"{s['valid']:,}", common.ms(tm),
                      common.ms(min(r["total"] for r in s["runs"])),
                      *[f"{med(s['runs'], k) * 1e3:.1f}" for k in stages2],
                      f"{tm * 1e3 / s['pixels'] * 1e5:.1f}"])
    print("\nTable 2: runtime vs pixel count, NOR mode (train stride 1), "
          f"median of {st.scale_repeats} run(s) "
          "per size, sizes interleaved, seed = repeat index (stage columns: medians in ms)")
    print(common.table(hdr, rows2, align="l" + "r" * (len(hdr) - 1)))

    px = np.array([s["pixels"] for s in per_size], dtype=np.float64)
    fits = {}
    for key in ["total", *stages2]:
        t = np.array([med(s["runs"], key) for s in per_size], dtype=np.float64)
        fits[key] = fit_linear(px, t)
    print("\nLeast-squares fits over the sizes above (t = a + b*pixels; log t = c + p*log pixels):")
    print(common.table(["quantity", "slope ms/100k px", "intercept ms", "R^2", "log-log exponent p"],
                       [[k, f"{f['slope_ms_per_100k_px']:.2f}", f"{f['intercept_ms']:.2f}", f"{f['r2']:.3f}",
                         f"{f['loglog_exponent']:.3f}"] for k, f in fits.items()], align="lrrrr"))
    p_tot = fits["total"]["loglog_exponent"]
    lin_ok = p_tot <= LINEAR_EXPONENT_MAX
    print(f"paper claim 'runtime grows at most linearly': exponent p = {p_tot:.2f} "
          f"(<= {LINEAR_EXPONENT_MAX} counts as consistent) -> "
          f"{'consistent' if lin_ok else 'NOT consistent'}")
    if "objects" in fits:
        p_obj = fits["objects"]["loglog_exponent"]
        obj_ok = p_obj <= CONSTANT_EXPONENT_MAX
        print(f"paper claim 'object-area time almost constant': exponent p = {p_obj:.2f} "
              f"(<= {CONSTANT_EXPONENT_MAX} counts as consistent) -> "
              f"{'consistent' if obj_ok else 'NOT consistent'}")
    report.results["table2"] = {"sizes": per_size, "fits": fits, "stages": stages2}

    wall = time.perf_counter() - t_start
    la = common.loadavg()
    print(f"\n# wall time {wall:.1f} s (after imports); load average at end: "
          + (f"{la[0]:.2f} {la[1]:.2f} {la[2]:.2f}" if la else "unavailable"))
    if args.json:
        info["loadavg_end"] = la
        report.wall_s = wall
        print(f"# JSON written to {report.write(args.json)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
