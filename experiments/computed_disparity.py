"""Generalisation check on computed disparity: the shared ground-truth scenes, re-matched by SGBM.

The object masks of ``../shared/data`` were drawn on the left images, so they also score a disparity
map that a stereo matcher computes from the same pair. This script does that for the four scenes
with a stereo pair or an estimate (KITTI's ``disp_est.png``; SGBM on the Middlebury Motorcycle,
ETH3D terrace and FlyingThings3D pairs, ``somtorch.disparity.compute_disparity`` with our default
SGBM settings and a search range that covers the scene) and runs the pipeline with any overrides:

    python -m experiments.computed_disparity                      # robust defaults, 100 runs
    python -m experiments.computed_disparity --runs 20 --set objects.min_purity=0

It prints one Markdown row per scene (runs ≥ 95 % identified, useful hits, mean reduction, x_opt,
and runs ≥ 95 % identified for every labelled object id, scored on the same reductions).
SGBM leaves holes and junk (no match within the search range at the left border, speckles) like
the OAK-D maps, so these scenes test the object rule on computed input with a known answer.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from experiments.scenes import dev_scenes, load_dev_scene
from somtorch.disparity.scene import Scene
from somtorch.pipeline import PipelineConfig, run_pipeline
from somtorch.tasks.scoring import score_reduction

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
# the development scenes whose disparity is computed (conf/scene_lists/dev.yaml)
PAIRS = {s.name: s for s in dev_scenes() if s.computed}


def computed_scene(name: str, data_dir: Path = DATA) -> Scene:
    """The scene ``name`` of :data:`PAIRS` with its computed disparity and the ground-truth masks."""
    return load_dev_scene(PAIRS[name], data_dir)


def apply_override(cfg: PipelineConfig, assignment: str) -> PipelineConfig:
    """``group.field=value`` on a copy of ``cfg`` (value parsed as the field's current type)."""
    key, _, value = assignment.partition("=")
    group, _, fld = key.partition(".")
    if not fld or not hasattr(cfg, group) or not hasattr(getattr(cfg, group), fld):
        raise ValueError(f"--set {assignment!r}: expected group.field=value with a PipelineConfig field")
    sub = getattr(cfg, group)
    current = getattr(sub, fld)
    typed = (value.lower() in ("1", "true", "yes")) if isinstance(current, bool) else type(current)(value)
    return dataclasses.replace(cfg, **{group: dataclasses.replace(sub, **{fld: typed})})


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100, help="seeds per scene (one ensemble)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data-dir", type=Path, default=DATA)
    ap.add_argument("--scenes", nargs="*", default=list(PAIRS), choices=list(PAIRS))
    ap.add_argument("--set", action="append", default=[], metavar="GROUP.FIELD=VALUE",
                    help="override a pipeline setting, e.g. objects.min_purity=0 (repeatable)")
    args = ap.parse_args(argv)
    if not args.data_dir.is_dir():
        raise SystemExit(f"{args.data_dir}: the shared data folder does not exist")
    cfg = PipelineConfig(ensemble=args.runs, seed=args.seed)
    for a in args.set:
        cfg = apply_override(cfg, a)
    rows = []
    print("| scene | runs | ≥ 95 % | useful hits | mean reduction | x_opt | ≥ 95 % per object id |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes:
        scene = computed_scene(name, args.data_dir)
        members = run_pipeline(scene, cfg, metrics=False).members
        scores = [m.score for m in members]
        per_object = {}  # every labelled object with a valid pixel, scored on the same reductions
        for info in scene.object_info:
            mask = scene.object_mask(info.id)
            if bool((mask & scene.valid).any()):
                per_object[info.id] = sum(score_reduction(m.reduction, mask, scene.valid).identified_95
                                          for m in members)
        row = {"scene": name, "runs": len(scores), "identified_95": sum(s.identified_95 for s in scores),
               "useful_hits": sum(s.useful_hit for s in scores),
               "reduction_mean": float(np.mean([s.reduction_union for s in scores])), "x_opt": scores[0].x_opt,
               "per_object_identified_95": per_object}
        rows.append(row)
        objs = ", ".join(f"{i}: {n}" for i, n in per_object.items())
        print(f"| {name} | {row['runs']} | {row['identified_95']} | {row['useful_hits']} | "
              f"{row['reduction_mean']:.1f} | {row['x_opt']:.1f} | {objs} |", flush=True)
    return rows


if __name__ == "__main__":
    main()
