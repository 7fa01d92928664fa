"""The ground step alone on the development frames (``conf/datasets.yaml``, synthetic ones left
out unless named): plane found or not, its inlier share and the share of the labelled objects'
pixels inside its mask, under two ground configs side by side.

    python -m experiments.ground_report                         # defaults vs the support rule
    python -m experiments.ground_report --after rule=either foot_frac=0.04

(``somtorch-validate`` runs the whole pipeline 30 times per scene; this reads only the ground step,
seconds per scene.) Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import fields, replace

from .datasets import frames, load_frame


def _config(pairs: list[str]):
    from somtorch.config import GroundConfig

    types = {f.name: f.type for f in fields(GroundConfig)}
    kw = {}
    for p in pairs:
        k, v = p.split("=", 1)
        if k not in types:
            raise SystemExit(f"unknown ground key {k!r}; known: {sorted(types)}")
        t = types[k] if isinstance(types[k], str) else types[k].__name__
        kw[k] = (v.lower() in ("1", "true", "yes")) if t == "bool" else int(v) if t == "int" else \
            float(v) if t == "float" else v
    return replace(GroundConfig(), **kw)


def _row(scene, cfg) -> tuple[str, str]:
    from somtorch.disparity.filters import remove_speckles
    from somtorch.evaluation import ground_object_share
    from somtorch.tasks.ground import fit_ground_plane

    valid = remove_speckles(scene.disparity, scene.valid, max_size_frac=0.0)
    g = fit_ground_plane(scene.disparity, valid, cfg)
    if g is None:
        return "no", "–"
    return f"yes ({g.inlier_frac:.0%})", f"{ground_object_share(g, scene):.1%}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(__import__("pathlib").Path(__file__).resolve().parents[1].parent
                                          / "shared" / "data"))
    ap.add_argument("--before", nargs="*", default=[], help="ground key=value pairs (default: the defaults)")
    ap.add_argument("--after", nargs="*", default=["rule=support"],
                    help="ground key=value pairs (default: the support rule)")
    ap.add_argument("--datasets", nargs="*", default=None, help="dataset names (default: all)")
    ap.add_argument("--frames", nargs="*", default=None, help="frame names (default: all)")
    a = ap.parse_args(argv)
    before, after = _config(a.before), _config(a.after)
    print(f"before: {' '.join(a.before) or 'defaults'}; after: {' '.join(a.after) or 'defaults'}\n")
    print("| frame | plane before | plane after | objects in ground mask before | after | s |")
    print("|---|---|---|---|---|---|")
    synthetic = None if a.datasets or a.frames else False
    for spec in frames(a.datasets, a.frames, synthetic=synthetic):
        scene = load_frame(spec, a.data)
        t0 = time.perf_counter()
        (fb, sb), (fa, sa) = _row(scene, before), _row(scene, after)
        print(f"| {spec.name} | {fb} | {fa} | {sb} | {sa} | {time.perf_counter() - t0:.1f} |", flush=True)


if __name__ == "__main__":
    main()
