"""``python -m experiments.aggregate DIR [DIR ...] [--out OUT]``: tables and plots of study sweeps.

Reads only the ``metrics.json`` files (schema ``somtorch.study/1``) below the given folders — any
Hydra multirun or single-run folder of ``python -m experiments.study`` — and writes into ``OUT``
(default: the first folder):

* ``results.csv`` — one row per job, quality only (deterministic: identical for identical configs
  and seeds whatever the launcher); ``timings.csv`` — wall and per-stage times;
* ``table1.md/.csv/.png`` — runs identifying 100 % / ≥ 95 % of the object, useful hits (paper Table 1);
* ``table2.md/.csv/.png`` — reduction x_min / mean / x_max over the completely identified runs, x_opt,
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
import sys
from pathlib import Path
from typing import Any

from .metrics_schema import SCHEMA
from .study_sections import (STAGES, _config_name, _fmt, _median, executions_section,
                                        fit_power, grid_section, runtime_section, stability_section)

__all__ = ["aggregate", "find_metrics", "fit_power", "main", "result_row", "timing_row"]

log = logging.getLogger("somtorch.aggregate")

PAPER_TABLE1 = [("NOR stair", 91, 91), ("OR stair", 84, 86), ("NOR garden", 79, 91), ("OR garden", 70, 87)]
PAPER_TABLE2 = [("NOR stair", 12.56, 79.13, 86.35, 90.04), ("OR stair", 16.98, 75.91, 88.11, 90.04),
                ("NOR garden", -6.94, 39.42, 47.81, 56.55), ("OR garden", 7.11, 31.26, 47.54, 56.55)]


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
        "_side_by_side": m.get("env", {}).get("jobs_side_by_side", 1),  # the runtime's conditions
        "_threads": m.get("env", {}).get("threads"),
    }
    if "identified_95" in s:
        rc, cc, r95 = s["reduction_complete"], s["reduction_crops_complete"], s["reduction_95"]
        row.update({
            "identified_100": s["identified_100"], "identified_95": s["identified_95"],
            "useful_hits": s["useful_hits"], "all_objects_hits": s.get("all_objects_hits"),
            "no_object": s.get("no_object"), "mean_identified_fraction": s["mean_identified_fraction"],
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
    out = ["| mode | scene | config | grid |" + extra + " runs | 100 % | ≥ 95 % | useful hits | all-objects hits | "
           "no object | mean identified | ms per run |", "|---" * (12 + vary) + "|"]
    for r in scored:
        cell = f" {r['train_order']}, {r['init']} |" if vary else ""
        out.append(f"| {r['mode']} | {r['scene']} | {r['config']} | {r['grid']} |{cell} {r['runs']} | "
                   f"{r['identified_100']} | {r['identified_95']} | {r['useful_hits']} | "
                   f"{_fmt(r['all_objects_hits'])} | {_fmt(r['no_object'])} | "
                   f"{_fmt(r['mean_identified_fraction'], 2)} | {_fmt(r['_runtime_ms'], 1)} |")
    side = max((r["_side_by_side"] for r in scored), default=1)
    if side > 1:
        threads = sorted({r["_threads"] for r in scored if r["_side_by_side"] > 1 and r["_threads"]})
        out += ["", f"ms per run: measured with up to {side} jobs side by side on {'/'.join(map(str, threads))} "
                    "thread(s) each (the somtorch launcher); time jobs alone with hydra.launcher.n_jobs=1 or "
                    "+experiment=runtime."]
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
        from .study_sections import tables_plot

        for name in tables_plot(rows, out, PAPER_TABLE1, PAPER_TABLE2):
            written[name] = out / name
    for name, fn in (("runtime", runtime_section), ("stability", stability_section), ("grid", grid_section)):
        text = fn(jobs, out)
        put(f"{name}.md", text)
        if text:
            written[f"{name}.png"] = out / f"{name}.png"
    put("executions.md", executions_section(jobs))
    log.info("%d jobs aggregated into %s: %s", len(jobs), out, ", ".join(sorted(written)))
    return written


def main(argv: list[str] | None = None) -> int:
    from .help import prog

    p = argparse.ArgumentParser(prog=prog("aggregate"), description=__doc__.split("\n\n")[0])
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
