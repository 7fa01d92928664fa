"""The study sections of ``experiments.aggregate`` that fit, plot and compare: runtime (log-log
power law per stage), stability (box plots with outliers), grid size, and ensemble vs separate
executions. Each reads only ``metrics.json`` content and writes its PNG next to its Markdown.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

from .metrics_schema import config_hash

STAGES = ("ground", "features", "train", "segment", "objects", "reduction")


def _fmt(v: Any, nd: int = 1) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def _config_name(m: dict) -> str:
    name = m["method"] if m["method"] != "som" else m["label"]
    return name + (" (separate runs)" if m.get("execution") == "separate" else "")


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
    """Lay out (unless the figure has its own layout engine), write atomically as PNG and close it."""
    from somtorch.atomic import atomic_path

    if fig.get_layout_engine() is None:
        fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    _pyplot().close(fig)


def _panel_grid(plt, n: int, title: str, ncols: int = 3):
    """A figure of ``n`` panels, ``ncols`` a row (about 1650 px wide at the PNG's 110 dpi), the
    rest hidden; shared y axis. Returns the figure and the first ``n`` axes."""
    ncols = min(ncols, n)
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.0 * ncols, 2.8 * nrows + 1.0), sharey=True, squeeze=False,
                             layout="constrained")
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    fig.suptitle(title)
    return fig, list(axes.flat[:n])


def _tick(config: object) -> str:
    """A configuration's name as a tick label: a long snake_case name on two lines."""
    name = str(config)
    return name.replace("_", "\n", 1) if len(name) > 10 else name


def _by_scene(scored: list[dict]) -> dict[str, list[dict]]:
    """The rows of each scene: the SOM's modes first (NOR, OR), then the task baselines ("all px")."""
    out: dict[str, list[dict]] = {}
    for r in scored:
        out.setdefault(r["scene"], []).append(r)
    order = {"NOR": 0, "OR": 1}
    return {s: sorted(rs, key=lambda r: (order.get(r["mode"], 2), str(r["config"]))) for s, rs in out.items()}


def tables_plot(rows: list[dict], out: Path, paper1: list[tuple], paper2: list[tuple]) -> list[str]:
    """``table1.png`` (runs identifying 100 % / ≥ 95 % of the object and useful hits, as a share
    of the runs, beside the paper's Table 1) and ``table2.png`` (reduction x_min … x_max with the
    mean, and x_opt, beside the paper's Table 2): one panel per scene (its configurations side by
    side: mode and preset) and one for the paper, three panels a row. Returns the names written."""
    import numpy as np

    scored = [r for r in rows if "identified_95" in r]
    if not scored:
        return []
    plt = _pyplot()
    scenes = _by_scene(scored)
    names = []
    keys = [("identified_100", "100 % identified"), ("identified_95", "≥ 95 % identified"),
            ("useful_hits", "useful hits")]
    fig, axes = _panel_grid(plt, len(scenes) + bool(paper1),
                            "Table 1: runs identifying the object [% of the runs] (ours: this sweep; paper: its "
                            "synthetic scenes)")
    for ax, (scene, rs) in zip(axes, scenes.items()):
        x = np.arange(len(rs))
        for j, (key, name) in enumerate(keys):
            ax.bar(x + (j - 1) * 0.27, [100.0 * r[key] / r["runs"] for r in rs], 0.27, color=f"C{j}", label=name)
        ax.set_xticks(x, [f"{r['mode']}\n{_tick(r['config'])}\n{r['runs']} runs" for r in rs], fontsize=7)
        ax.set_title(scene, fontsize=10)
    if paper1:
        ax = axes[-1]
        xp = np.arange(len(paper1))
        ax.bar(xp - 0.135, [a for _, a, _ in paper1], 0.27, color="0.55", label="paper: 100 %")
        ax.bar(xp + 0.135, [b for _, _, b in paper1], 0.27, color="0.8", label="paper: ≥ 95 %")
        ax.set_xticks(xp, [n.replace(" ", "\n", 1) for n, _, _ in paper1], fontsize=8)
        ax.set_title("paper (Table 1)", fontsize=10)
    for ax in axes:
        ax.set_ylim(0, 105)
        ax.grid(axis="y", alpha=0.3)
    for ax in axes[::3]:
        ax.set_ylabel("% of the runs")
    handles = {lab: h for ax in axes for h, lab in zip(*ax.get_legend_handles_labels())}
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=5, fontsize=9, frameon=False)
    _finish(fig, out / "table1.png")
    names.append("table1.png")

    fig, axes = _panel_grid(plt, len(scenes) + bool(paper2),
                            "Table 2: data reduction [%] of the completely identified runs")
    for ax, (scene, rs) in zip(axes, scenes.items()):
        for i, r in enumerate(rs):
            if r.get("x_min") is not None:
                ax.plot([i, i], [r["x_min"], r["x_max"]], color="C0", lw=2)
                ax.plot(i, r["x_mean"], "o", color="C0", label="ours: x_min … x_max, mean")
            ax.plot(i, r["x_opt"], "k_", ms=18, mew=2, label="x_opt (exactly the object's box)")
        ax.set_xticks(range(len(rs)), [f"{r['mode']}\n{_tick(r['config'])}" for r in rs], fontsize=7)
        ax.set_xlim(-0.6, len(rs) - 0.4)
        ax.set_title(scene, fontsize=10)
    if paper2:
        ax = axes[-1]
        for j, (n, lo, mean, hi, opt) in enumerate(paper2):
            ax.plot([j, j], [lo, hi], color="0.5", lw=2)
            ax.plot(j, mean, "o", color="0.5", label="paper: x_min … x_max, mean")
            ax.plot(j, opt, "_", color="0.3", ms=18, mew=2)
        ax.set_xticks(range(len(paper2)), [n.replace(" ", "\n", 1) for n, *_ in paper2], fontsize=8)
        ax.set_xlim(-0.6, len(paper2) - 0.4)
        ax.set_title("paper (Table 2)", fontsize=10)
    for ax in axes:
        ax.grid(axis="y", alpha=0.3)
    for ax in axes[::3]:
        ax.set_ylabel("reduction [%]")
    handles = {lab: h for ax in axes for h, lab in zip(*ax.get_legend_handles_labels())}
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=3, fontsize=9, frameon=False)
    _finish(fig, out / "table2.png")
    names.append("table2.png")
    return names
