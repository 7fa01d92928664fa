"""``python -m experiments.validate``: leave-one-scene-out validation of the tuned constants.

Every development scene (``conf/scene_lists/dev.yaml``) is scored with the current defaults and with
each value of ``grid`` (one constant changed at a time). Then, for each scene in turn, every
constant's value is chosen on the *other* scenes (the value with the most useful hits there; the
default wins ties) and the combination is scored on the left-out scene. The report puts three
figures side by side, per scene and in total:

* **default** — the configuration as composed (no tuning);
* **in-sample** — the constants chosen on all scenes, scored on the same scenes (fitted);
* **left-out** — the constants chosen without the scene, scored on it (what a new scene can expect).

A change to the object rule is adopted only if it raises the left-out total. Segmentations are
computed once per scene and upstream setting (features, ground, SOM, training), so a grid of
object-step constants costs one object step per value.

    python -m experiments.validate                               # the grid of conf/validate.yaml
    python -m experiments.validate ensemble=10 'scenes=[kitti,oakd_toy]'
    python -m experiments.validate '+grid={objects.merge: [0.5, 1.0]}'

Writes ``validate.json`` (every per-scene, per-candidate figure and the choices of every fold)
and ``validate.md`` into the Hydra run folder.
"""

from __future__ import annotations

if __name__ == "__main__":  # --help before the heavy imports (torch, Hydra)
    from .help import maybe_print_help

    maybe_print_help("validate")

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from . import CONF
from .schema import RunConfig, register

CONF_DIR = str(CONF)
log = logging.getLogger("somtorch.validate")
UPSTREAM = ("features", "ground", "som", "train", "baseline", "method", "ensemble", "seed")


@dataclass
class ValidateConfig(RunConfig):
    """The pipeline config plus the scenes and the grid of values tried.

    Attributes:
        scenes: the development scenes scored (None = every development scene).
        grid: ``{"group.field": [values]}`` tried instead of each default, one constant at a time.
        gallery: a folder: one picture of member 0 per scene (defaults); None = no pictures.
        min_gain: a value replaces the default only if it gains more than min_gain x the runs.
        transforms: robustness checks: every scene transformed (``flip``, ``resample:F``, ``pole``, ``border``, ``specks``; experiments.scenes.add_junk) and scored with the defaults.
    """

    scenes: Optional[list[str]] = None
    grid: dict[str, list[Any]] = field(default_factory=dict)
    gallery: Optional[str] = None  # a folder: one picture of member 0 per scene (defaults)
    min_gain: float = 0.02  # a value replaces the default only if it gains > min_gain x the runs
    # robustness: every scene transformed (experiments.scenes.add_junk: "flip", "resample:F",
    # "pole", "border", "specks") and scored with the defaults, beside the scenes as they are
    transforms: list[str] = field(default_factory=list)


def _key(overrides: dict[str, Any]) -> str:
    return ",".join(f"{k}={overrides[k]}" for k in sorted(overrides)) or "default"


class SceneCache:
    """One development scene: its segmentations per upstream setting, scores per candidate."""

    def __init__(self, spec: Any, scene: Any, base: Any) -> None:
        self.spec, self.scene, self.base = spec, scene, base
        self._seg: dict[str, Any] = {}
        self._target: Any = None  # the scene's all-objects target, computed once
        self.scores: dict[str, dict[str, Any]] = {}

    def members(self, overrides: dict[str, Any]) -> tuple[Any, list]:
        """``(ground plane, member results)`` of the base config with ``overrides``; the segmentation
        is computed once per upstream setting (features, ground, SOM, training)."""
        from dataclasses import replace

        import torch

        from somtorch.config import with_overrides
        from somtorch.pipeline import detect, prepare
        from somtorch.segmenters import run_segmenter

        cfg = with_overrides(self.base, overrides)
        up = _key({k: v for k, v in overrides.items() if k.split(".")[0] in UPSTREAM})
        if up not in self._seg:
            valid, ground, usable, feats, train = prepare(self.scene, cfg)
            seg = run_segmenter(feats, train, self.scene, usable, cfg)
            # kept as int16 (a SOM has far fewer neurons): 30 members x 22 scenes x every upstream
            # setting of the grid as int64 label maps outgrew 24 GiB
            small = seg.labels.to(torch.int16) if int(seg.labels.max()) < 2 ** 15 else seg.labels
            self._seg[up] = (ground, replace(seg, labels=small, som=None))  # (the object step reads no map)
        ground, seg = self._seg[up]
        return ground, detect(self.scene, replace(seg, labels=seg.labels.long()), ground, cfg)

    def score(self, overrides: dict[str, Any]) -> dict[str, Any]:
        from somtorch.evaluation import all_objects, ground_object_share

        key = _key(overrides)
        if key in self.scores:
            return self.scores[key]
        ground, members = self.members(overrides)
        if self._target is None:
            self._target = all_objects(self.scene)
        target = self._target
        s = [m.score for m in members]
        self.scores[key] = {
            "runs": len(s), "useful_hits": sum(x.useful_hit for x in s),
            "identified_95": sum(x.identified_95 for x in s),
            "all_objects_hits": sum(target.hit(m.reduction) for m in members),
            "no_object": sum(m.no_object for m in members),
            # how the other runs missed: the wrong object (< 50 % of the main object kept), partial
            # (50-95 %), too much kept (>= 95 % but a reduction under 0.75 x x_opt)
            "misses": {"wrong": sum(x.identified_fraction < 0.5 for x in s),
                       "partial": sum(0.5 <= x.identified_fraction < 0.95 for x in s),
                       "too_much": sum(x.identified_95 and not x.useful_hit for x in s)},
            "mean_reduction": sum(x.reduction_union for x in s) / len(s), "x_opt": s[0].x_opt,
            "ground_object_frac": ground_object_share(ground, self.scene),
        }
        return self.scores[key]


    def gallery(self, path: Path, overrides: dict[str, Any] | None = None, member: int = 0) -> Path:
        """A picture of one member: disparity (turbo, px), ground mask (blue), object masks (green
        outline), kept boxes with the tolerance (red, with confidence), and its verdict."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import numpy as np

        from somtorch.viz import identified_percent

        if not 0 <= member < self.base.ensemble:
            raise ValueError(f"gallery member {member} must be in [0, ensemble={self.base.ensemble})")
        ground, members = self.members(overrides or {})
        m = members[member]
        sc = self.scene
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
        verdict = (f"identified {identified_percent(s.identified_fraction)}, reduction {s.reduction_union:.1f} % "
                   f"(x_opt {s.x_opt:.1f} %): {'useful' if s.useful_hit else 'not useful'}"
                   + (", no object (whole map kept)" if m.no_object else ""))
        ax.set_title(f"{self.spec.name} (seed {m.seed}) — {verdict}\nred: kept boxes (confidence); "
                     "green: labelled objects; blue: ground mask", fontsize=9)
        ax.set_axis_off()
        fig.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path)
        plt.close(fig)
        return path


def choose(caches: list[Any], grid: dict[str, list[Any]], defaults: dict[str, Any], min_gain: float = 0.0
           ) -> dict[str, Any]:
    """Each constant's value with the most useful hits (then all-objects hits) summed over ``caches``,
    the others at their default. A value replaces the default only if it gains more than
    ``min_gain ×`` the runs of ``caches`` in useful hits (0: any gain; ties keep the default).
    Returns only the changed constants."""
    picked: dict[str, Any] = {}
    for k, values in grid.items():
        def total(v: Any) -> tuple[int, int]:
            rows = [c.score(_overrides(k, v, defaults)) for c in caches]
            return sum(r["useful_hits"] for r in rows), sum(r["all_objects_hits"] for r in rows)
        base = total(defaults[k])
        margin = min_gain * sum(c.score({}).get("runs", 0) for c in caches)
        best_v, best = defaults[k], base
        for v in values:
            t = total(v)
            if t > best and t[0] - base[0] > margin:
                best_v, best = v, t
        picked.update(_overrides(k, best_v, defaults))
    return picked


def _overrides(key: str, value: Any, defaults: dict[str, Any]) -> dict[str, Any]:
    """The overrides of one grid value; a key ``"a.b+c.d"`` sets several fields at once (``value`` a list)."""
    if value == defaults[key]:
        return {}
    names = key.split("+")
    values = list(value) if len(names) > 1 else [value]
    if len(values) != len(names):
        raise ValueError(f"grid {key!r}: value {value!r} must give {len(names)} values")
    return dict(zip(names, values))


def _default_of(cfg: Any, key: str) -> Any:
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def evaluate(cfg: ValidateConfig) -> dict[str, Any]:
    """Run the protocol of the module docstring; returns the JSON-ready report."""
    from .scenes import check_junk_kind, dev_scenes, load_dev_scene

    for kind in cfg.transforms:  # before any work: a typo must not cost the whole protocol
        check_junk_kind(kind)
    specs = dev_scenes(cfg.scenes)
    data_dir = Path(to_absolute_path(cfg.paths.data_dir))
    grid = {k: list(v) for k, v in cfg.grid.items()}
    base = cfg  # a ValidateConfig is a PipelineConfig: the extra fields do not reach the pipeline
    defaults = {k: _default_of(base, k) if "+" not in k else [_default_of(base, n) for n in k.split("+")]
                for k in grid}
    caches = []
    for spec in specs:  # every file is read (and every map computed) before any training
        caches.append(SceneCache(spec, load_dev_scene(spec, data_dir), base))
    t0 = time.perf_counter()
    for c in caches:
        c.score({})
        for k, values in grid.items():
            for v in values:
                c.score(_overrides(k, v, defaults))
        log.info("%s: default %d useful of %d (%.1f s)", c.spec.name, c.scores["default"]["useful_hits"],
                 c.scores["default"]["runs"], time.perf_counter() - t0)
    in_sample = choose(caches, grid, defaults, cfg.min_gain)
    rows = []
    for i, c in enumerate(caches):
        others = caches[:i] + caches[i + 1:]
        fold = choose(others, grid, defaults, cfg.min_gain)
        strict = choose(others, grid, defaults, 0.0)
        rows.append({"scene": c.spec.name, "computed": c.spec.computed, "default": c.score({}),
                     "in_sample": c.score(in_sample), "left_out": c.score(fold), "fold_choice": fold,
                     "left_out_strict": c.score(strict), "fold_choice_strict": strict})
    totals = {part: {m: sum(r[part][m] for r in rows) for m in ("runs", "useful_hits", "all_objects_hits",
                                                                  "identified_95", "no_object")}
              for part in ("default", "in_sample", "left_out", "left_out_strict")}
    if cfg.gallery is not None:
        for c in caches:
            c.gallery(Path(to_absolute_path(cfg.gallery)) / f"{c.spec.name}.png")
    robustness = {t: transformed(caches, t) for t in cfg.transforms}
    return {"grid": grid, "defaults": defaults, "in_sample_choice": in_sample, "rows": rows, "totals": totals,
            "candidates": {c.spec.name: c.scores for c in caches}, "robustness": robustness,
            "wall_s": time.perf_counter() - t0}


def transformed(caches: list[SceneCache], kind: str) -> dict[str, dict[str, Any]]:
    """The default scores of every scene of ``caches`` transformed by ``add_junk(scene, kind)``,
    by scene name. A transform is a check of the rule (a mirrored or resampled scene is as easy
    as the original; a pole in front of the object is a failure class), not a tuning scene: the
    folds never see it. Scenes already resampled are skipped by a resampling transform."""
    from .scenes import add_junk

    out = {}
    for c in caches:
        if kind.startswith("resample:") and (c.spec.junk or "").startswith("resample:"):
            continue
        t0 = time.perf_counter()
        tc = SceneCache(c.spec, add_junk(c.scene, kind, seed=sum(map(ord, c.spec.name))), c.base)
        out[c.spec.name] = tc.score({})
        sc = out[c.spec.name]
        log.info("%s (%s): default %d useful of %d (%.1f s)", c.spec.name, kind, sc["useful_hits"],
                 sc["runs"], time.perf_counter() - t0)
    return out


def to_markdown(report: dict[str, Any]) -> str:
    """The left-out table: per scene default / in-sample / left-out useful and all-objects hits."""
    out = ["| scene | runs | default useful | in-sample useful | **left-out useful** | left-out, any gain | "
           "default all-obj | left-out all-obj | no object | default misses: wrong / partial / too much | "
           "ground ∩ objects | left-out choice |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    miss = {"wrong": 0, "partial": 0, "too_much": 0}
    for r in report["rows"]:
        d, i, lo, st = r["default"], r["in_sample"], r["left_out"], r["left_out_strict"]
        choice = ", ".join(f"{k}={v}" for k, v in r["fold_choice"].items()) or "defaults"
        m = d["misses"]
        for k in miss:
            miss[k] += m[k]
        out.append(f"| {r['scene']} | {d['runs']} | {d['useful_hits']} | {i['useful_hits']} | **{lo['useful_hits']}** | "
                   f"{st['useful_hits']} | {d['all_objects_hits']} | {lo['all_objects_hits']} | {d['no_object']} | "
                   f"{m['wrong']} / {m['partial']} / {m['too_much']} | "
                   f"{d['ground_object_frac']:.1%} | {choice} |")
    t = report["totals"]
    out.append(f"| **total** | {t['default']['runs']} | {t['default']['useful_hits']} | {t['in_sample']['useful_hits']} | "
               f"**{t['left_out']['useful_hits']}** | {t['left_out_strict']['useful_hits']} | "
               f"{t['default']['all_objects_hits']} | {t['left_out']['all_objects_hits']} | "
               f"{t['default']['no_object']} | {miss['wrong']} / {miss['partial']} / {miss['too_much']} | | "
               f"in-sample choice: {', '.join(f'{k}={v}' for k, v in report['in_sample_choice'].items()) or 'defaults'} |")
    out += ["", "Useful hits per candidate (one constant changed):", "",
            "| candidate | " + " | ".join(r["scene"] for r in report["rows"]) + " | total |",
            "|---" * (len(report["rows"]) + 2) + "|"]
    cands = report["candidates"]
    names = [r["scene"] for r in report["rows"]]
    for key in cands[names[0]]:
        vals = [cands[n][key]["useful_hits"] if key in cands[n] else None for n in names]
        if None in vals:
            continue
        out.append(f"| {key} | " + " | ".join(map(str, vals)) + f" | {sum(vals)} |")
    robust = report.get("robustness") or {}
    if robust:
        kinds = list(robust)
        out += ["", "Robustness (defaults; every scene transformed, useful / all-objects hits):", "",
                "| scene | as given | " + " | ".join(kinds) + " |", "|---" * (len(kinds) + 2) + "|"]
        sums = {k: [0, 0, 0] for k in ["as given", *kinds]}
        for r in report["rows"]:
            cells = []
            for k in ["as given", *kinds]:
                sc = r["default"] if k == "as given" else robust[k].get(r["scene"])
                if sc is None:
                    cells.append("–")
                    continue
                sums[k][0] += sc["useful_hits"]
                sums[k][1] += sc["all_objects_hits"]
                sums[k][2] += sc["runs"]
                cells.append(f"{sc['useful_hits']} / {sc['all_objects_hits']}")
            out.append(f"| {r['scene']} | " + " | ".join(cells) + " |")
        out.append("| **total** | " + " | ".join(f"**{u} / {a}** of {n}" for u, a, n in sums.values()) + " |")
    return "\n".join(out) + "\n"


ConfigStore.instance().store(name="validate_schema", node=ValidateConfig)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="validate")
def main(dcfg: DictConfig) -> int:
    from .cli import configure_threads

    configure_threads()
    from .schema import one_line_errors
    from somtorch.atomic import write_staged

    with one_line_errors(log):
        cfg: ValidateConfig = OmegaConf.to_object(dcfg)
        out = Path(HydraConfig.get().runtime.output_dir)
        report = evaluate(cfg)
    write_staged(out, {"validate.md": to_markdown(report).encode(), "validate.json": report})
    t = report["totals"]
    log.info("useful hits: default %d, in-sample %d, left-out %d of %d; tables in %s", t["default"]["useful_hits"],
             t["in_sample"]["useful_hits"], t["left_out"]["useful_hits"], t["default"]["runs"], out / "validate.md")
    return int(t["left_out"]["useful_hits"])


register()
def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, ValidateConfig)


if __name__ == "__main__":
    cli()
