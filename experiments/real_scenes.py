"""``python -m experiments.real_scenes``: the pipeline on every shared scene with an object mask.

Each scene is run with ``ensemble`` seeds trained at once and scored against its hand-labelled
mask (main object, and every object id separately). Writes ``results.json`` and ``results.md``
(the README table) into the Hydra run directory. Presets: ``+preset=paper`` / ``+preset=robust``.

    python -m experiments.real_scenes ensemble=20
    python -m experiments.real_scenes ensemble=20 +preset=paper
    python -m experiments.real_scenes ensemble=20 features=nor
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import hydra
import numpy as np
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from experiments.scenes import dev_scenes
from experiments.schema import RunConfig

# absolute, so that the console script and python -m find the same configs from any directory
CONF_DIR = str(Path(__file__).resolve().parents[1] / "conf")
log = logging.getLogger("somtorch.real_scenes")

# the development scenes given as ground truth (or as shipped), declared in conf/scene_lists/dev.yaml
DEFAULT_SCENES = [s.folder for s in dev_scenes() if not s.computed]


@dataclass
class ScenesConfig(RunConfig):
    scenes: list[str] = field(default_factory=lambda: list(DEFAULT_SCENES))


ConfigStore.instance().store(name="real_scenes_schema", node=ScenesConfig)


def evaluate(cfg: ScenesConfig) -> dict:
    """Run and score every scene; returns the JSON-ready results."""
    from somtorch.disparity.scene import load_scene
    from somtorch.pipeline import run_pipeline
    from somtorch.tasks.scoring import score_reduction

    data_dir = Path(to_absolute_path(cfg.paths.data_dir))
    missing = [s for s in cfg.scenes if not (data_dir / s).is_dir()]
    if missing:
        raise FileNotFoundError(f"scene folders not found under {data_dir}: {missing} (set paths.data_dir)")
    scenes = [load_scene(data_dir / s) for s in cfg.scenes]  # every file checked before any training
    for s, spec in zip(scenes, cfg.scenes):
        if s.objects is None:
            raise ValueError(f"{data_dir / spec} has no objects.png: it cannot be scored")
    rows = []
    for spec, scene in zip(cfg.scenes, scenes):
        t0 = time.perf_counter()
        res = run_pipeline(scene, cfg, metrics=False)
        wall = time.perf_counter() - t0
        scores = [m.score for m in res.members]
        per_object = {}
        for info in scene.object_info:
            mask = scene.object_mask(info.id)
            if not bool((mask & scene.valid).any()):
                continue
            s_obj = [score_reduction(m.reduction, mask, scene.valid) for m in res.members]
            per_object[info.name] = {"id": info.id, "identified_95": sum(s.identified_95 for s in s_obj),
                                     "mean_identified_fraction": float(np.mean([s.identified_fraction for s in s_obj]))}
        hits = [s.reduction_union for s in scores if s.identified_95]
        row = {
            "scene": spec, "runs": len(scores), "grid": f"{cfg.som.rows}x{cfg.som.cols}",
            "mode": "OR" if cfg.features.train_stride > 1 else "NOR", "train_px": len(res.train_features),
            "identified_100": sum(s.identified_100 for s in scores),
            "identified_95": sum(s.identified_95 for s in scores),
            "useful_hits": sum(s.useful_hit for s in scores),
            "mean_identified_fraction": float(np.mean([s.identified_fraction for s in scores])),
            "reduction_95_mean": float(np.mean(hits)) if hits else None,
            "reduction_95_min": float(np.min(hits)) if hits else None,
            "reduction_95_max": float(np.max(hits)) if hits else None,
            "x_opt": scores[0].x_opt,
            "ground_found": res.ground is not None,
            "timings_ms_per_run": {k: 1e3 * v / len(scores) if k in ("objects", "reduction") else 1e3 * v
                                   for k, v in res.timings.items()},
            "wall_s": wall, "per_object": per_object,
        }
        rows.append(row)
        log.info("%s: identified>=95 %d/%d, useful %d, mean reduction %s, x_opt %.1f", spec, row["identified_95"],
                 row["runs"], row["useful_hits"], row["reduction_95_mean"], row["x_opt"])
    return {"label": cfg.label, "config": OmegaConf.to_container(OmegaConf.structured(cfg)), "rows": rows}


def to_markdown(results: dict) -> str:
    """The README table: one row per scene."""
    head = ("| scene | preset | grid | mode | runs | ≥95 % identified | 100 % | useful hits | mean reduction (≥95 % runs) "
            "| x_opt | ms: train / segment (whole ensemble) / objects (per run) |\n|---|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in results["rows"]:
        t = r["timings_ms_per_run"]
        red = "–" if r["reduction_95_mean"] is None else f"{r['reduction_95_mean']:.1f} %"
        lines.append(f"| {r['scene']} | {results['label']} | {r['grid']} | {r['mode']} | {r['runs']} | "
                     f"{r['identified_95']} | {r['identified_100']} | {r['useful_hits']} | {red} | {r['x_opt']:.1f} % | "
                     f"{t.get('train', 0):.0f} / {t.get('segment', 0):.0f} / {t.get('objects', 0):.1f} |")
    lines.append("")
    lines.append("| scene | object | runs with ≥95 % identified | mean identified fraction |\n|---|---|---|---|")
    for r in results["rows"]:
        for name, o in r["per_object"].items():
            lines.append(f"| {r['scene']} | {o['id']}: {name} | {o['identified_95']}/{r['runs']} | "
                         f"{o['mean_identified_fraction']:.2f} |")
    return "\n".join(lines) + "\n"


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="real_scenes")
def main(dcfg: DictConfig) -> dict:
    from somtorch.atomic import write_bytes, write_json

    cfg: ScenesConfig = OmegaConf.to_object(dcfg)
    out = Path(HydraConfig.get().runtime.output_dir)
    results = evaluate(cfg)
    write_bytes(out / "results.md", to_markdown(results).encode())
    write_json(out / "results.json", results)
    log.info("tables in %s", out / "results.md")
    return results


if __name__ == "__main__":
    main()
