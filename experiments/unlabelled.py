"""What the object rule keeps on the shared scenes that have no object mask.

The OAK-D folders ``corridor``, ``desk``, ``kid_bedroom`` and ``pov_controllers`` ship SGBM disparity
but no mask, so no hit can be scored; what can be counted is how often the kept area is junk that
the checks of :func:`somtorch.tasks.refine.kept_areas` are meant to reject — an area whose box is
mostly other segments (purity below 0.25) or whose segments are streaks and speckles (relative
solidity below 0.25) — whatever the checks are set to:

    python -m experiments.unlabelled                                  # robust defaults, 100 runs
    python -m experiments.unlabelled --set objects.min_solidity=0     # without the solidity test

It prints one Markdown row per scene (runs, kept areas below each bound, median purity and
solidity of the kept areas). Look at ``areas.png`` of ``python -m experiments.run data=file
data.source=…`` to judge the picks themselves.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from somtorch.disparity.scene import load_scene
from somtorch.pipeline import PipelineConfig, run_pipeline

from .computed_disparity import DATA, apply_override

SCENES = ("oakd_stereodemo/corridor", "oakd_stereodemo/desk", "oakd_stereodemo/kid_bedroom",
          "oakd_stereodemo/pov_controllers")
BOUND = 0.25  # the default min_purity and min_solidity: below it a kept area counts as junk


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100, help="seeds per scene (one ensemble)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data-dir", type=Path, default=DATA)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES), help="folders under the data dir")
    ap.add_argument("--set", action="append", default=[], metavar="GROUP.FIELD=VALUE",
                    help="override a pipeline setting, e.g. objects.min_solidity=0 (repeatable)")
    args = ap.parse_args(argv)
    if not args.data_dir.is_dir():
        raise SystemExit(f"{args.data_dir}: the shared data folder does not exist")
    missing = [s for s in args.scenes if not (args.data_dir / s).is_dir()]
    if missing:
        raise SystemExit(f"scene folders not found under {args.data_dir}: {missing}")
    cfg = PipelineConfig(ensemble=args.runs, seed=args.seed)
    for a in args.set:
        cfg = apply_override(cfg, a)
    rows = []
    print(f"| scene | runs | purity < {BOUND} | solidity < {BOUND} | median purity | median solidity |")
    print("|---|---|---|---|---|---|")
    for spec in args.scenes:
        members = run_pipeline(load_scene(args.data_dir / spec), cfg, metrics=False).members
        found = [m for m in members if not m.no_object]  # fail-safe runs keep the whole map: not junk
        purity = np.array([m.kept[0].purity for m in found] or [np.nan])
        solid = np.array([m.kept[0].solidity for m in found] or [np.nan])
        row = {"scene": spec, "runs": len(members), "no_object": len(members) - len(found),
               "low_purity": int((purity < BOUND).sum()),
               "low_solidity": int((solid < BOUND).sum()), "median_purity": float(np.median(purity)),
               "median_solidity": float(np.median(solid))}
        rows.append(row)
        print(f"| {spec} | {row['runs']} | {row['low_purity']} | {row['low_solidity']} | "
              f"{row['median_purity']:.2f} | {row['median_solidity']:.2f} |", flush=True)
    return rows


if __name__ == "__main__":
    main()
