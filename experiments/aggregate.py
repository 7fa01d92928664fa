"""``python -m experiments.aggregate DIR [DIR ...] [--out OUT]``: tables and plots of study sweeps.

Reads only the ``metrics.json`` files (schema ``somtorch.study/1``) below the given folders — any
Hydra multirun or single-run folder of ``python -m experiments.study`` — and writes into ``OUT``
(default: the first folder):

* ``results.csv`` — one row per job, quality only (deterministic: identical for identical configs
  and seeds whatever the launcher); ``timings.csv`` — wall and per-stage times;
* ``table1.md/.csv`` — runs identifying 100 % / ≥ 95 % of the object, useful hits (paper Table 1);
* ``table2.md/.csv`` — reduction x_min / mean / x_max over the completely identified runs, x_opt,
  union mask and separate crops (paper Table 2); ``per_object.md``;
* ``runtime.md/.png`` — time per stage against training pixels with the fitted growth exponent;
* ``stability.md/.png`` — distributions (box plots, outliers marked) of area, reduction, runtime;
* ``grid.md/.png`` — segmentation precision and runtime against the SOM size;
* ``executions.md`` — the same configuration as one ensemble vs separate runs (time, identical?).

The paper's own numbers (../shared/PAPER.md) are printed next to ours in the Markdown tables.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import logging
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from experiments.metrics_schema import SCHEMA, config_hash

log = logging.getLogger("somtorch.aggregate")

PAPER_TABLE1 = [("NOR stair", 91, 91), ("OR stair", 84, 86), ("NOR garden", 79, 91), ("OR garden", 70, 87)]
PAPER_TABLE2 = [("NOR stair", 12.56, 79.13, 86.35, 90.04), ("OR stair", 16.98, 75.91, 88.11, 90.04),
                ("NOR garden", -6.94, 39.42, 47.81, 56.55), ("OR garden", 7.11, 31.26, 47.54, 56.55)]
STAGES = ("clean", "ground", "features", "train", "segment", "objects", "reduction")


def find_metrics(folders: list[Path]) -> list[tuple[Path, dict]]:
    """Every complete study ``metrics.json`` below ``folders`` (staging folders ignored), sorted by path."""
    found = []
    for folder in folders:
        if not folder.exists():
            raise FileNotFoundError(f"{folder}: no such folder")
        files = [folder] if folder.is_file() else sorted(folder.rglob("metrics.json"))
        for f in files:
            if any(part.startswith(".partial-") for part in f.parts):
                continue
            try:
                m = json.loads(f.read_text())
            except (OSError, ValueError) as err:
                log.warning("skipping %s: unreadable (%s)", f, err)
                continue
            if isinstance(m, dict) and m.get("schema") == SCHEMA:
                found.append((f.parent, m))
    return found


def _fmt(v: Any, nd: int = 1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def _config_name(m: dict) -> str:
    name = m["method"] if m["method"] != "som" else m["label"]
    return name + (" (separate runs)" if m.get("execution") == "separate" else "")


def result_row(path: Path, m: dict, root: Path | None = None) -> dict[str, Any]:
    """The quality columns of one job (no times)."""
    s = m["summary"]
    cfg = m.get("config", {})
    row: dict[str, Any] = {
        "job": str(path.relative_to(root)) if root is not None and path.is_relative_to(root) else str(path),
        "study": m["study"], "scene": m["scene"]["name"], "mode": m["mode"], "config": _config_name(m),
        "label": m["label"], "method": m["method"], "grid": m["grid"], "segments": m["segments"],
        "train_order": cfg.get("train", {}).get("order"), "init": cfg.get("som", {}).get("init"),
        "train_px": m["pixels"]["train"], "runs": s["runs"], "config_hash": m["config_hash"],
        "reduction_all_mean": s["reduction_all"]["mean"], "area_frac_mean": s["area_frac"]["mean"],
        "_runtime_ms": 1e3 * s["runtime_s"]["mean"],  # "_": not in results.csv (times vary between runs)
    }
    if "identified_95" in s:
        rc, cc, r95 = s["reduction_complete"], s["reduction_crops_complete"], s["reduction_95"]
        row.update({
            "identified_100": s["identified_100"], "identified_95": s["identified_95"],
            "useful_hits": s["useful_hits"], "mean_identified_fraction": s["mean_identified_fraction"],
            "x_min": rc["min"], "x_mean": rc["mean"], "x_max": rc["max"], "x_opt": s["x_opt"],
            "crops_x_min": cc["min"], "crops_x_mean": cc["mean"], "crops_x_max": cc["max"],
            "reduction_95_mean": r95["mean"], "tradeoff": s["tradeoff"],
            "segment_f1_mean": s["segment_f1"]["mean"], "area_precision_mean": s["area_precision"]["mean"],
        })
    return row


def timing_row(path: Path, m: dict, root: Path | None = None) -> dict[str, Any]:
    reps = m.get("timings_repeats_s") or [m["timings_s"]]
    row: dict[str, Any] = {"job": result_row(path, m, root)["job"], "execution": m["execution"],
                           "runs": m["summary"]["runs"], "train_px": m["pixels"]["train"], "repeats": len(reps),
                           "job_wall_s": m.get("wall_s")}
    for k in (*STAGES, "wall"):
        vals = [r[k] for r in reps if k in r]
        if vals:
            row[f"{k}_s_median"] = _median(vals)
    row["runtime_per_run_s_mean"] = m["summary"]["runtime_s"]["mean"]
    return row


def _csv(rows: list[dict[str, Any]]) -> str:
    if not rows:
        return ""
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys and not k.startswith("_")]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else (repr(r[k]) if isinstance(r[k], float) else r[k])) for k in keys})
    return buf.getvalue()


def _sort_key(r: dict) -> tuple:
    return (r["study"], r["scene"], r["mode"] != "NOR", r["config"], r["segments"], r["grid"], str(r["train_order"]),
            str(r["init"]), r["train_px"], r["job"])


def table1_md(rows: list[dict]) -> str:
    scored = [r for r in rows if "identified_95" in r]
    # training order / initialisation become a column where they vary (e.g. the stability study)
    vary = len({(r["train_order"], r["init"]) for r in scored}) > 1
    extra = " order, init |" if vary else ""
    out = ["| mode | scene | config | grid |" + extra + " runs | 100 % | ≥ 95 % | useful hits | mean identified | "
           "ms per run |", "|---" * (10 + vary) + "|"]
    for r in scored:
        cell = f" {r['train_order']}, {r['init']} |" if vary else ""
        out.append(f"| {r['mode']} | {r['scene']} | {r['config']} | {r['grid']} |{cell} {r['runs']} | "
                   f"{r['identified_100']} | {r['identified_95']} | {r['useful_hits']} | "
                   f"{_fmt(r['mean_identified_fraction'], 2)} | {_fmt(r['_runtime_ms'], 1)} |")
    out += ["", "The paper (Table 1; synthetic scenes, 100 runs each):", "",
            "| | 100 % | 95 % |", "|---|---|---|"]
    out += [f"| {n} | {a} | {b} |" for n, a, b in PAPER_TABLE1]
    return "\n".join(out) + "\n"


def table2_md(rows: list[dict]) -> str:
    scored = [r for r in rows if "identified_95" in r]
    out = ["Reduction in % over the runs with complete (100 %) identification; union = one mask of all kept "
           "areas, crops = each kept area's box stored separately (overlaps counted twice).", "",
           "| mode | scene | config | n complete | x_min | mean | x_max | x_opt | crops: x_min | mean | x_max | "
           "mean over ≥ 95 % runs |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in scored:
        out.append(f"| {r['mode']} | {r['scene']} | {r['config']} | {r['identified_100']} | {_fmt(r['x_min'], 2)} | "
                   f"{_fmt(r['x_mean'], 2)} | {_fmt(r['x_max'], 2)} | {_fmt(r['x_opt'], 2)} | "
                   f"{_fmt(r['crops_x_min'], 2)} | {_fmt(r['crops_x_mean'], 2)} | {_fmt(r['crops_x_max'], 2)} | "
                   f"{_fmt(r['reduction_95_mean'], 2)} |")
    out += ["", "The paper (Table 2):", "", "| | x_min | mean | x_max | x_opt |", "|---|---|---|---|---|"]
    out += [f"| {n} | {a} | {b} | {c} | {d} |" for n, a, b, c, d in PAPER_TABLE2]
    return "\n".join(out) + "\n"


def per_object_md(jobs: list[tuple[Path, dict]]) -> str:
    out = ["| mode | scene | config | object | ≥ 95 % identified | mean identified | x_opt |",
           "|---|---|---|---|---|---|---|"]
    n = 0
    for _, m in jobs:
        for oid, o in m.get("per_object", {}).items():
            n += 1
            out.append(f"| {m['mode']} | {m['scene']['name']} | {_config_name(m)} | {oid}: {o['name']} | "
                       f"{o['identified_95']}/{m['summary']['runs']} | {o['mean_identified_fraction']:.2f} | "
                       f"{o['x_opt']:.1f} |")
    return "\n".join(out) + "\n" if n else ""


def fit_power(px: list[float], secs: list[float]) -> tuple[float, float]:
    """Least-squares fit of log t = a + b log n; returns (b, exp(a)). Needs ≥ 2 distinct n."""
    import numpy as np

    x, y = np.log(np.asarray(px, float)), np.log(np.maximum(np.asarray(secs, float), 1e-9))
    b, a = np.polyfit(x, y, 1)
    return float(b), float(math.exp(a))


def runtime_section(jobs: list[tuple[Path, dict]], out: Path) -> str | None:
    """Runtime per stage vs training pixels, per configuration; every repeat is one point of the fit."""
    groups: dict[str, list[dict]] = defaultdict(list)
    for _, m in jobs:
        if m["study"] == "runtime" or len(m.get("timings_repeats_s", [])) > 1:
            groups[f"{m['scene']['name']} {_config_name(m)} {m['grid']} E={m['summary']['runs']}"].append(m)
    groups = {k: v for k, v in groups.items() if len({m["pixels"]["train"] for m in v}) >= 2}
    if not groups:
        return None
    plt = _pyplot()

    lines = ["Time per stage against training pixels (median of the repeats); exponent b of the least-squares "
             "fit log t = a + b log n over every repeat (b = 1: linear growth).", ""]
    fig, axes = plt.subplots(1, len(groups), figsize=(6.5 * len(groups), 4.5), squeeze=False)
    for ax, (name, ms) in zip(axes[0], sorted(groups.items())):
        ms = sorted(ms, key=lambda m: m["pixels"]["train"])
        stages = [s for s in (*STAGES, "wall") if all(s in r for m in ms for r in m["timings_repeats_s"])]
        lines += [f"**{name}**", "", "| train px | " + " | ".join(f"{s} ms" for s in stages) + " |",
                  "|---" * (len(stages) + 1) + "|"]
        for m in ms:
            med = {s: _median([r[s] for r in m["timings_repeats_s"]]) for s in stages}
            lines.append(f"| {m['pixels']['train']} | " + " | ".join(f"{1e3 * med[s]:.1f}" for s in stages) + " |")
        fits = []
        for s in stages:
            px = [m["pixels"]["train"] for m in ms for _ in m["timings_repeats_s"]]
            ts = [r[s] for m in ms for r in m["timings_repeats_s"]]
            b, c = fit_power(px, ts)
            fits.append(f"{s} b = {b:.2f}")
            xs = sorted({m["pixels"]["train"] for m in ms})
            ax.loglog(xs, [1e3 * _median([r[s] for r in m["timings_repeats_s"]]) for m in ms],
                      "o-" if s == "wall" else ".-", lw=2.5 if s == "wall" else 1, label=f"{s} (b={b:.2f})")
        lines += ["", "Fitted exponents: " + ", ".join(fits) + ".", ""]
        ax.set_xlabel("training pixels")
        ax.set_ylabel("time per job [ms]")
        ax.set_title(name, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    _finish(fig, out / "runtime.png")
    return "\n".join(lines) + "\n"


def _median(v: list[float]) -> float:
    v = sorted(v)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def _box_stats(v: list[float]) -> dict[str, float | int]:
    import numpy as np

    a = np.asarray(v, float)
    q1, med, q3 = np.percentile(a, [25, 50, 75])
    iqr = q3 - q1
    return {"median": float(med), "q1": float(q1), "q3": float(q3),
            "low_outliers": int((a < q1 - 1.5 * iqr).sum()), "high_outliers": int((a > q3 + 1.5 * iqr).sum())}


def stability_section(jobs: list[tuple[Path, dict]], out: Path) -> str | None:
    sel = [m for _, m in jobs if m["study"] == "stability"]
    if not sel:
        return None
    plt = _pyplot()

    def name(m: dict) -> str:
        c = m["config"]
        return f"{m['scene']['name']} {_config_name(m)}\norder={c['train']['order']} init={c['som']['init']}"

    sel = sorted(sel, key=name)
    keys = [("area_frac", "detected area (share of valid px)", 1.0), ("reduction_union", "reduction [%]", 1.0),
            ("runtime_s", "runtime per run [ms]", 1e3)]
    fig, axes = plt.subplots(1, len(keys), figsize=(5.5 * len(keys), 4.8))
    lines = ["Distributions over the runs (median [Q1, Q3]; outliers beyond 1.5 IQR, low / high):", "",
             "| configuration | runs | " + " | ".join(k[1] for k in keys) + " | ≥ 95 % identified |",
             "|---" * (len(keys) + 3) + "|"]
    for m in sel:
        cells = []
        for key, _, scale in keys:
            b = _box_stats([scale * v for v in m["runs"][key]])
            cells.append(f"{b['median']:.3g} [{b['q1']:.3g}, {b['q3']:.3g}] ({b['low_outliers']}/{b['high_outliers']})")
        id95 = m["summary"].get("identified_95")
        lines.append(f"| {name(m).replace(chr(10), ' ')} | {m['summary']['runs']} | " + " | ".join(cells)
                     + f" | {_fmt(id95)} |")
    for ax, (key, label, scale) in zip(axes, keys):
        ax.boxplot([[scale * v for v in m["runs"][key]] for m in sel], showfliers=True,
                   flierprops={"marker": "x", "markeredgecolor": "crimson"})
        ax.set_xticks(range(1, len(sel) + 1), [name(m) for m in sel], rotation=30, ha="right", fontsize=7)
        ax.set_title(label)
        ax.grid(True, axis="y", alpha=0.3)
    _finish(fig, out / "stability.png")
    return "\n".join(lines) + "\n"


def grid_section(jobs: list[tuple[Path, dict]], out: Path) -> str | None:
    sel = [m for _, m in jobs if m["study"] == "grid"]
    if not sel:
        return None
    plt = _pyplot()

    by_scene: dict[str, list[dict]] = defaultdict(list)
    for m in sel:
        by_scene[f"{m['scene']['name']} {m['mode']} {_config_name(m)}"].append(m)
    lines = ["Segmentation precision (segments that are mostly object vs the object mask: precision / recall / F1), "
             "identification and runtime (train + segment, per run) against the SOM size.", "",
             "| scene | grid | K | QE | segment precision | recall | F1 | kept-area precision | ≥ 95 % | useful | "
             "train + segment ms per run |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.3))
    for scene, ms in sorted(by_scene.items()):
        ms = sorted(ms, key=lambda m: m["segments"])
        ks, f1s, ts = [], [], []
        for m in ms:
            r, s = m["runs"], m["summary"]
            n = s["runs"]
            t = 1e3 * (m["timings_s"].get("train", 0) + m["timings_s"].get("segment", 0)) / n
            qe = [q for q in r["quantization_error"] if q is not None]
            f1 = s.get("segment_f1", {}).get("mean")
            lines.append(f"| {scene} | {m['grid']} | {m['segments']} | {_fmt(sum(qe) / len(qe) if qe else None, 4)} | "
                         f"{_fmt(_mean(r.get('segment_precision')), 3)} | {_fmt(_mean(r.get('segment_recall')), 3)} | "
                         f"{_fmt(f1, 3)} | {_fmt(s.get('area_precision', {}).get('mean'), 3)} | "
                         f"{_fmt(s.get('identified_95'))}/{n} | {_fmt(s.get('useful_hits'))}/{n} | {t:.2f} |")
            ks.append(m["segments"])
            f1s.append(f1 if f1 is not None else float("nan"))
            ts.append(t)
        axes[0].plot(ks, f1s, "o-", label=scene)
        axes[1].loglog(ks, ts, "o-", label=scene)
    axes[0].set_xscale("log")
    axes[0].set_xlabel("neurons K")
    axes[0].set_ylabel("segmentation F1 vs object mask")
    axes[1].set_xlabel("neurons K")
    axes[1].set_ylabel("train + segment per run [ms]")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    _finish(fig, out / "grid.png")
    return "\n".join(lines) + "\n"


def _mean(v: list | None) -> float | None:
    return sum(v) / len(v) if v else None


def executions_section(jobs: list[tuple[Path, dict]]) -> str | None:
    """Jobs whose configs differ only in ``execution``: time of one ensemble vs separate runs."""
    groups: dict[str, dict[str, dict]] = defaultdict(dict)
    for _, m in jobs:  # same rule as the skip logic: the hash of the config, here without `execution`
        cfg = {k: v for k, v in m.get("config", {}).items() if k != "execution"}
        groups[config_hash(cfg)][m["execution"]] = m
    pairs = [g for g in groups.values() if "ensemble" in g and "separate" in g]
    if not pairs:
        return None
    lines = ["| scene | mode | config | runs | one ensemble s | separate runs s | ratio | per-run results identical |",
             "|---|---|---|---|---|---|---|---|"]
    for g in pairs:
        e, s = g["ensemble"], g["separate"]
        keys = [k for k in e["runs"] if k != "runtime_s"]
        same = all(e["runs"][k] == s["runs"].get(k) for k in keys)
        te, ts = e["timings_s"]["wall"], s["timings_s"]["wall"]
        lines.append(f"| {e['scene']['name']} | {e['mode']} | {_config_name(e)} | {e['summary']['runs']} | {te:.2f} | "
                     f"{ts:.2f} | {ts / te:.1f}× | {'yes' if same else 'NO'} |")
    return "\n".join(lines) + "\n"


def _pyplot():
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _finish(fig, path: Path) -> None:
    """Lay out, write atomically as PNG and close a figure."""
    from somtorch.atomic import atomic_path

    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    _pyplot().close(fig)


def aggregate(folders: list[Path], out: Path) -> dict[str, Path]:
    """Write every table and plot for the jobs below ``folders`` into ``out``; returns the written files."""
    from somtorch.atomic import write_bytes

    jobs = find_metrics(folders)
    if not jobs:
        raise FileNotFoundError(f"no study metrics.json (schema {SCHEMA}) below {[str(f) for f in folders]}")
    root = folders[0] if folders[0].is_dir() else None
    ranked = sorted(((result_row(p, m, root), p, m) for p, m in jobs), key=lambda t: _sort_key(t[0]))
    rows = [r for r, _, _ in ranked]
    jobs = [(p, m) for _, p, m in ranked]
    timings = [timing_row(p, m, root) for p, m in jobs]
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}

    def put(name: str, text: str | None) -> None:
        if text:
            write_bytes(out / name, text.encode())
            written[name] = out / name

    put("results.csv", _csv(rows))
    put("timings.csv", _csv(timings))
    if any("identified_95" in r for r in rows):
        put("table1.md", table1_md(rows))
        put("table1.csv", _csv([{k: r.get(k) for k in ("mode", "scene", "config", "grid", "runs", "identified_100",
                                                        "identified_95", "useful_hits")} for r in rows
                                if "identified_95" in r]))
        put("table2.md", table2_md(rows))
        put("table2.csv", _csv([{k: r.get(k) for k in ("mode", "scene", "config", "identified_100", "x_min", "x_mean",
                                                        "x_max", "x_opt", "crops_x_min", "crops_x_mean",
                                                        "crops_x_max", "reduction_95_mean")} for r in rows
                                if "identified_95" in r]))
        put("per_object.md", per_object_md(jobs))
    for name, fn in (("runtime", runtime_section), ("stability", stability_section), ("grid", grid_section)):
        text = fn(jobs, out)
        put(f"{name}.md", text)
        if text:
            written[f"{name}.png"] = out / f"{name}.png"
    put("executions.md", executions_section(jobs))
    log.info("%d jobs aggregated into %s: %s", len(jobs), out, ", ".join(sorted(written)))
    return written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.aggregate", description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="+", type=Path, help="sweep / run folders holding metrics.json files")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: the first folder)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="[%(levelname)s] %(message)s")
    try:
        written = aggregate(args.folders, args.out or args.folders[0])
    except FileNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for name in ("table1.md", "table2.md", "runtime.md", "stability.md", "grid.md", "executions.md"):
        if name in written:
            print(f"\n## {name}\n\n{written[name].read_text()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
