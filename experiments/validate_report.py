"""The reports of ``python -m experiments.validate``: each knob's verdict, the per-dataset summary
with the macro averages, and ``validate.md`` (split from :mod:`experiments.validate`, which runs
the protocol)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["gallery", "summarize", "to_markdown", "verdict"]


def verdict(key: str, entries: list[dict[str, Any]], in_sample: dict[str, Any], neutral: dict[str, Any]) -> str:
    """``adopt <value>`` (the in-sample choice changed it), ``remove`` (its neutral value is
    non-inferior on the real data and not shown to cost over every dataset:
    :attr:`~experiments.protocol.Decision.removable`), or ``keep``."""
    names = key.split("+")
    if any(n in in_sample for n in names):
        return "adopt " + ", ".join(f"{n}={in_sample[n]}" for n in names if n in in_sample)
    off = [e for e in entries if e["neutral"]]
    if key in neutral and (not off or off[0]["removable"]):
        return "remove"
    return "keep"


def summarize(t: Any, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per dataset: frames, runs, useful and all-objects rates (default / in-sample / left-out),
    saliency of the defaults; then the macro averages over the real datasets and over all."""
    out: dict[str, Any] = {"datasets": {}}
    arr = {(part, m): np.array([r[part][m] / r[part]["runs"] for r in rows])
           for part in ("default", "in_sample", "left_out") for m in ("useful_hits", "all_objects_hits")}
    per = {key: t.per_dataset(v) for key, v in arr.items()}
    for d in t.names:
        drows = [r for r in rows if r["dataset"] == d]
        sal = [r["default"]["saliency"] for r in drows if r["default"].get("saliency")]
        out["datasets"][d] = {
            "real": drows[0]["real"], "frames": len(drows), "runs": sum(r["default"]["runs"] for r in drows),
            "objects_per_frame": float(np.mean([r["default"]["n_objects"] for r in drows])),
            "valid_share": float(np.mean([r["default"]["valid_share"] for r in drows])),
            "x_opt": float(np.mean([r["default"]["x_opt"] for r in drows])),
            **{f"{part}_{m}": per[(part, m)][d] for part, m in per},
            **({k: float(np.mean([s[k] for s in sal])) for k in sal[0]} if sal else {})}
    for label, real_only in (("real", True), ("all", False)):
        out[f"macro_{label}"] = {f"{part}_{m}": t.macro(v, real_only)[0] for (part, m), v in arr.items()}
    # the defaults' ceilings
    for ceiling in ("best_map_hits", "first_place_hits", "best_area_hits", "best_grouping_hits"):
        if not all(ceiling in r["default"] for r in rows):
            continue
        best = np.array([r["default"][ceiling] / r["default"]["runs"] for r in rows])
        for d, v in t.per_dataset(best).items():
            out["datasets"][d][f"default_{ceiling}"] = v
        for label, real_only in (("real", True), ("all", False)):
            out[f"macro_{label}"][f"default_{ceiling}"] = t.macro(best, real_only)[0]
    for d in t.names:  # how the defaults' other runs missed, in runs (wrong object, partial, too much kept)
        got = [r["default"] for r in rows if r["dataset"] == d and "misses" in r["default"]]
        if got:
            out["datasets"][d]["default_misses"] = {
                "useful": sum(g["useful_hits"] for g in got), **{k: sum(g["misses"][k] for g in got)
                                                                for k in got[0]["misses"]}}
    missed = {d: r["default_misses"] for d, r in out["datasets"].items() if "default_misses" in r}
    for label, real_only in (("real", True), ("all", False)):  # their totals, in runs (not a macro)
        ds = [d for d in missed if out["datasets"][d]["real"] or not real_only]
        if ds:
            out[f"macro_{label}"]["default_misses"] = {k: sum(missed[d][k] for d in ds) for k in missed[ds[0]]}
    if all("selection_gap" in r["default"] for r in rows):  # why the ceiling's other runs missed (runs)
        for d in t.names:
            gaps = [r["default"]["selection_gap"] for r in rows if r["dataset"] == d]
            out["datasets"][d]["default_selection_gap"] = {k: sum(g[k] for g in gaps) for k in gaps[0]}
    return out


def _pct(x: float) -> str:
    return "–" if x != x else f"{100 * x:.1f}"


def _ci(t: Any) -> str:
    return f"{100 * t[0]:+.1f} [{100 * t[1]:+.1f}, {100 * t[2]:+.1f}]"


def _grids_lines(report: dict[str, Any]) -> list[str]:
    """The pixel grids the protocol decided on (``frame_shifts``) and the defaults' macros on each
    alone; nothing for the frames as given alone."""
    shifts = report.get("rule", {}).get("frame_shifts", [0])
    if shifts == [0]:
        return []
    each = report.get("grids", {})
    per = "; ".join(f"{s} px: real {_pct(each[str(s)]['macro_real'])} %, "
                    f"all {_pct(each[str(s)]['macro_all'])} %" for s in shifts if str(s) in each)
    out = [f"Every frame read on the pixel grids shifted by {', '.join(map(str, shifts))} px "
           "(`frame_shifts`: the `shift:N` transform, 0 = as given; the strided steps read other pixels of "
           "the same scenes), a candidate's runs summed over them: the rates below are the means over the "
           "grids" + (f" (the defaults' useful-hit macros on each grid alone — {per})" if per else "") + ".", ""]
    names = list(each[str(shifts[0])].get("datasets", {})) if str(shifts[0]) in each else []
    if names and all(str(s) in each for s in shifts):  # where the grids part: the defaults per dataset
        out += ["The defaults' useful hits (% of runs) per dataset on each grid alone:", "",
                "| dataset | " + " | ".join(f"{s} px" for s in shifts) + " |", "|---|" + "---|" * len(shifts)]
        out += [f"| {d} | " + " | ".join(_pct(each[str(s)]["datasets"][d]) for s in shifts) + " |"
                for d in names]
        out.append("")
    return out


def to_markdown(report: dict[str, Any]) -> str:
    """The tables: per dataset (rates in % of runs), the macro averages, every knob's decisions."""
    sm = report["summary"]
    out = _grids_lines(report)
    out += ["Per dataset, % of runs (useful = the paper's main-object useful hit; all-obj = every labelled "
            "object >= 95 % kept at >= 0.75 x the union-of-boxes reduction):", "",
            "| dataset | real | frames | runs | objects / frame | valid | x_opt | default useful | in-sample useful | "
            "**left-out useful** | default all-obj | in-sample all-obj | **left-out all-obj** | F | MAE | S |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for d, r in sm["datasets"].items():
        out.append(f"| {d} | {'yes' if r['real'] else 'no'} | {r['frames']} | {r['runs']} | {r['objects_per_frame']:.1f} | "
                   f"{100 * r['valid_share']:.0f} % | {r['x_opt']:.1f} | {_pct(r['default_useful_hits'])} | "
                   f"{_pct(r['in_sample_useful_hits'])} | **{_pct(r['left_out_useful_hits'])}** | "
                   f"{_pct(r['default_all_objects_hits'])} | {_pct(r['in_sample_all_objects_hits'])} | "
                   f"**{_pct(r['left_out_all_objects_hits'])}** | {r.get('f_measure', float('nan')):.2f} | "
                   f"{r.get('mae', float('nan')):.3f} | {r.get('s_measure', float('nan')):.2f} |")
    for label in ("real", "all"):
        m = sm[f"macro_{label}"]
        out.append(f"| **macro, {label}** | | | | | | | {_pct(m['default_useful_hits'])} | {_pct(m['in_sample_useful_hits'])} | "
                   f"**{_pct(m['left_out_useful_hits'])}** | {_pct(m['default_all_objects_hits'])} | "
                   f"{_pct(m['in_sample_all_objects_hits'])} | **{_pct(m['left_out_all_objects_hits'])}** | | | |")
    out += _fresh_markdown(report)
    if "default_best_area_hits" in sm["macro_real"]:
        nan = float("nan")
        out += ["", "Selection ceiling (defaults): % of runs with a useful hit; % with a useful map among "
                "the run's maps (`consensus`: what a perfect choice of the map could reach; the medoid "
                "follows their majority); % that a perfect ranking "
                "of the step's candidates would make useful (each candidate tried first, the others "
                "after it, joined, refined, checked and budgeted as the step does: "
                "`somtorch.tasks.detect.first_place`); % whose kept areas or "
                "any area of the grouping hold one box that alone (with the tolerance) would be a useful "
                "hit — what a perfect choice among the step's candidates could reach — and % where that "
                "holds or the segments mostly on the object (more than half their pixels) have a box "
                "that would be one: an oracle's grouping of the same segments beside the step's own "
                "(`somtorch.evaluation.grouping_ceiling`):", "",
                "| dataset | default useful | best map of the run | best candidate first | best single area "
                "| best grouping of its segments |",
                "|---|---|---|---|---|---|"]
        out += [f"| {d} | {_pct(r['default_useful_hits'])} | {_pct(r.get('default_best_map_hits', nan))} | "
                f"{_pct(r.get('default_first_place_hits', nan))} | {_pct(r['default_best_area_hits'])} | "
                f"{_pct(r.get('default_best_grouping_hits', nan))} |" for d, r in sm["datasets"].items()]
        out += [f"| **macro, {label}** | {_pct(sm[f'macro_{label}']['default_useful_hits'])} | "
                f"{_pct(sm[f'macro_{label}'].get('default_best_map_hits', nan))} | "
                f"{_pct(sm[f'macro_{label}'].get('default_first_place_hits', nan))} | "
                f"{_pct(sm[f'macro_{label}']['default_best_area_hits'])} | "
                f"{_pct(sm[f'macro_{label}'].get('default_best_grouping_hits', nan))} |"
                for label in ("real", "all")]
    misses = {d: r["default_misses"] for d, r in sm["datasets"].items() if "default_misses" in r}
    if misses:
        out += ["", "How the other runs missed (defaults), in runs: the main object kept < 50 % (another "
                "thing kept instead), 50-95 % (split, or its box cut short), or >= 95 % with a reduction "
                "under 0.75 x x_opt (too much kept beside it):", "",
                "| dataset | runs | useful | < 50 % kept | 50-95 % kept | too much kept |",
                "|---|---|---|---|---|---|"]
        cols = ("useful", "wrong", "partial", "too_much")
        out += [f"| {d} | {sm['datasets'][d]['runs']} | " + " | ".join(str(m[k]) for k in cols) + " |"
                for d, m in misses.items()]
        for label in ("real", "all"):
            tot = sm[f"macro_{label}"].get("default_misses")
            if tot:
                out.append(f"| **total, {label}** | {sum(tot.values())} | "
                           + " | ".join(str(tot[k]) for k in cols) + " |")
    gaps = {d: r["default_selection_gap"] for d, r in sm["datasets"].items() if "default_selection_gap" in r}
    if gaps:
        reasons = list(next(iter(gaps.values())))
        out += ["", "The selection gap (defaults): the runs that missed although one area's box alone would "
                "have been a useful hit, by what became of the best-ranked such area (the verdicts of "
                "`metrics.json`'s `candidates`; `somtorch.evaluation.selection_gap`), in runs:", "",
                "| dataset | " + " | ".join(reasons) + " |", "|---|" + "---|" * len(reasons)]
        out += [f"| {d} | " + " | ".join(str(g[k]) for k in reasons) + " |"
                for d, g in gaps.items() if any(g.values())]
        for label, real_only in (("real", True), ("all", False)):
            tot = {k: sum(g[k] for d, g in gaps.items() if sm["datasets"][d]["real"] or not real_only)
                   for k in reasons}
            out.append(f"| **total, {label}** | " + " | ".join(str(tot[k]) for k in reasons) + " |")
    choice = report["in_sample_choice"]
    out += ["", f"In-sample choice: {', '.join(f'{k}={v}' for k, v in choice.items()) or 'the defaults'}.", "",
            "Left-out choices (each made without the dataset):", ""]
    by_choice: dict[str, list[str]] = {}
    for d, f in report["folds"].items():
        by_choice.setdefault(", ".join(f"{k}={v}" for k, v in f["choice"].items()) or "the defaults", []).append(d)
    for c, ds in by_choice.items():
        out.append(f"- {c}: {', '.join(ds)}")
    out += ["", "Every knob, each value against the defaults (paired, same seeds; differences in points of the "
            "useful-hit rate, real macro with its 95 % bootstrap interval; worst = the dataset of the largest loss):", "",
            "| knob | default | value | useful, real macro | all-obj, real macro | useful, all datasets | worst | "
            "adoptable | non-inferior | verdict |", "|---|---|---|---|---|---|---|---|---|---|"]
    for k, kn in report["knobs"].items():
        for i, e in enumerate(kn["values"]):
            out.append(f"| {k if i == 0 else ''} | {kn['default'] if i == 0 else ''} | {e['value']}"
                       f"{' (neutral)' if e['neutral'] else ''} | {_ci(e['useful'])} | {_ci(e['all_objects'])} | "
                       f"{_ci(e['useful_all'])} | {e['worst'][0]} {100 * e['worst'][1]:+.1f} | "
                       f"{('yes (' + e['path'] + ')') if e['adopt'] else 'no'} | {'yes' if e['non_inferior'] else 'no'} | "
                       f"{kn['verdict'] if i == 0 else ''} |")
    robust = report.get("robustness") or {}
    if robust:
        names = list(report["rows"][0].get("baselines") or {}) if report["rows"] else []
        head = "| transform | useful | all-obj | runs | useful % | " + "".join(f"{n} useful % | "
                                                                          for n in names)
        out += ["", "Robustness (defaults; every frame transformed; useful / all-objects hits, and the "
                "useful share of the runs — the task baselines' on the same transformed frames, one run "
                "each, – where one does not apply):", "", head.rstrip(),
                "|---|---|---|---|---|" + "---|" * len(names)]

        def row(label: str, scores: list[dict[str, Any]], peers: list[dict[str, Any]]) -> str:
            runs = sum(x["runs"] for x in scores)
            cells = [f"| {label} | {sum(x['useful_hits'] for x in scores)} | "
                     f"{sum(x['all_objects_hits'] for x in scores)} | {runs} | {_useful_share(scores)} |"]
            for n in names:
                got = [p[n] for p in peers if p.get(n) is not None]
                cells.append(f" {_useful_share(got)} |")
            return "".join(cells)

        out.append(row("as given", [r["default"] for r in report["rows"]],
                       [r.get("baselines") or {} for r in report["rows"]]))
        for k in robust:
            v = list(robust[k].values())
            out.append(row(k, v, [x.get("baselines") or {} for x in v]))
            if len(v) < len(report["rows"]):  # a transform of some frames: those frames as given too
                same = [r for r in report["rows"] if r["frame"] in robust[k]]
                out.append(row(f"{k}: the same frames as given", [r["default"] for r in same],
                               [r.get("baselines") or {} for r in same]))
    from .validate_baselines import baselines_markdown

    return "\n".join(out) + "\n" + baselines_markdown(report)


def _fresh_markdown(report: dict[str, Any]) -> list[str]:
    """The defaults (and the in-sample choice) on fresh seeds beside the seeds chosen on (lines of
    ``validate.md``; none where ``fresh_seeds`` was off)."""
    fresh, sm = report.get("fresh_seeds"), report["summary"]
    if not fresh:
        return []
    s0, n = report["rule"]["seed"], report["rule"]["ensemble"]
    choice = fresh["choice"]
    parts = [("default", "default")] + ([("in_sample", "in-sample")] if choice else [])
    head = "| dataset | " + " | ".join(f"{lab} useful | **fresh seeds** | {lab} all-obj | **fresh seeds**"
                                       for _, lab in parts) + " |"
    a, b = fresh["seeds"]
    shift, main = fresh.get("shift", 0), report["rule"].get("frame_shifts", [0])
    where = "as given" if main == [0] else f"on the grids shifted by {', '.join(map(str, main))} px"
    grid = (f", each frame on a pixel grid shifted by {shift} px (`shift:{shift}`: the strided steps read "
            "other pixels of the same scene)" if shift else "")
    out = ["", f"On fresh seeds: the same frames scored again on seeds {a}–{b}{grid}, "
           f"runs nothing was chosen on (the protocol chose on seeds {s0}–{s0 + n - 1} of the frames "
           f"{where}, and the rules were designed looking at those runs too), % of runs:", "", head,
           "|---|" + "---|---|---|---|" * len(parts)]

    def cells(chosen: dict[str, Any], new: dict[str, Any]) -> str:
        return " | ".join(f"{_pct(chosen[f'{p}_{m}'])} | **{_pct(new[f'{p}_{m}'])}**"
                          for p, _ in parts for m in ("useful_hits", "all_objects_hits"))

    out += [f"| {d} | {cells(sm['datasets'][d], r)} |" for d, r in fresh["datasets"].items()]
    out += [f"| **macro, {lab}** | {cells(sm[f'macro_{lab}'], fresh[f'macro_{lab}'])} |"
            for lab in ("real", "all")]
    if choice:
        dec = fresh["decision"]
        out += ["", f"The in-sample choice ({', '.join(f'{k}={v}' for k, v in choice.items())}) against the "
                f"defaults on the fresh seeds: useful, real macro {_ci(dec['useful'])}, all datasets "
                f"{_ci(dec['useful_all'])}; worst {dec['worst'][0]} {100 * dec['worst'][1]:+.1f}: "
                + ("**confirmed** (adopted again)." if fresh["confirmed"] else
                   f"**not confirmed**: not adopted there ({'; '.join(dec['reasons']) or 'no gain'}).")]
    return out


def _useful_share(scores: list[dict[str, Any]]) -> str:
    """The useful share of the runs of ``scores`` (count dicts) in %, or – without a run."""
    runs = sum(x["runs"] for x in scores)
    return f"{100 * sum(x['useful_hits'] for x in scores) / runs:.1f}" if runs else "–"


def gallery(cache: Any, path: Path, overrides: dict[str, Any] | None = None, member: int = 0) -> Path:
    """A picture of one member of a frame cache (:class:`experiments.validate_cache.SceneCache`): disparity (turbo, px), ground mask (blue), object masks (green
    outline), kept boxes with the tolerance (red, with confidence), and its verdict."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from somtorch.viz import identified_percent

    if not 0 <= member < cache.base.ensemble:
        raise ValueError(f"gallery member {member} must be in [0, ensemble={cache.base.ensemble})")
    ground, members = cache.members(overrides or {})
    m = members[member]
    sc = cache.scene
    d = np.where(sc.valid.numpy(), sc.disparity.numpy(), np.nan)
    fig, ax = plt.subplots(figsize=(7.5, 7.5 * sc.height / sc.width + 0.8), dpi=64)
    lo, hi = np.nanpercentile(d, [1, 99])
    im = ax.imshow(d, cmap="turbo", vmin=lo, vmax=hi)
    fig.colorbar(im, ax=ax, fraction=0.03, pad=0.01, label="disparity [px]")
    if ground is not None:
        tint = np.zeros((*ground.mask.shape, 4))
        tint[ground.mask.numpy()] = (0.15, 0.35, 1.0, 0.7)  # RGBA: the removed ground plane
        ax.imshow(tint)
    if sc.objects is not None:
        ax.contour((sc.objects > 0).numpy().astype(float), levels=[0.5], colors="lime", linewidths=1.2)
    for a, b in zip(m.kept, m.reduction.boxes):
        x0, y0, x1, y1 = b
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="red", lw=2))
        ax.text(x0 + 3, y0 + 12, f"{a.confidence:.2f}" if a.confidence is not None else "", color="red",
                fontsize=9, weight="bold")
    s = m.score
    said = (f"identified {identified_percent(s.identified_fraction)}, reduction {s.reduction_union:.1f} % "
               f"(x_opt {s.x_opt:.1f} %): {'useful' if s.useful_hit else 'not useful'}"
               + (", no object (whole map kept)" if m.no_object else ""))
    ax.set_title(f"{cache.spec.name} (seed {m.seed}) — {said}\nred: kept boxes (confidence); "
                 "green: labelled objects; blue: ground mask", fontsize=9)
    ax.set_axis_off()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
