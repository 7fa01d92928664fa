"""``python -m experiments.ground_report``: the ground step alone on the development frames
(``conf/datasets.yaml``, synthetic ones left out unless named): plane found or not, its inlier share
and the share of the labelled objects' pixels inside its mask, under two ground configs side by side.

    python -m experiments.ground_report                              # defaults vs the support rule
    python -m experiments.ground_report after.rule=either after.support_frac=0.5
    python -m experiments.ground_report 'frames=[kitti,oakd_toy]' before.rule=none

(``somtorch-validate`` runs the whole pipeline 30 times per scene; this reads only the ground step,
seconds per scene.) Prints a Markdown table on stdout.
"""

from __future__ import annotations

if __name__ == "__main__":  # --help before the heavy imports (torch, Hydra)
    from .help import maybe_print_help

    maybe_print_help("ground_report")

import logging
import time
from pathlib import Path

import hydra
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from . import CONF
from .schema import register
from .tool_configs import GroundReportConfig

CONF_DIR = str(CONF)
log = logging.getLogger("somtorch.ground_report")
register()


def _row(scene, cfg) -> tuple[str, str]:
    from somtorch.disparity.filters import remove_speckles
    from somtorch.evaluation import ground_object_share
    from somtorch.tasks.ground import fit_ground_plane

    valid = remove_speckles(scene.disparity, scene.valid, max_size_frac=0.0)
    g = fit_ground_plane(scene.disparity, valid, cfg)
    if g is None:
        return "no", "–"
    return f"yes ({g.inlier_frac:.0%})", f"{ground_object_share(g, scene):.1%}"


def _changed(cfg) -> str:
    from dataclasses import fields

    from somtorch.config import GroundConfig

    base = GroundConfig()
    return " ".join(f"{f.name}={getattr(cfg, f.name)}" for f in fields(cfg)
                    if getattr(cfg, f.name) != getattr(base, f.name)) or "defaults"


def report(cfg: GroundReportConfig) -> str:
    """The Markdown table (one row per frame), every file read before the first row."""
    from .datasets import frames, load_frame

    data_dir = Path(to_absolute_path(cfg.paths.data_dir))
    synthetic = None if cfg.datasets or cfg.frames else False
    specs = frames(cfg.datasets, cfg.frames, synthetic=synthetic)
    scenes = [load_frame(s, data_dir) for s in specs]
    lines = [f"before: {_changed(cfg.before)}; after: {_changed(cfg.after)}", "",
             "| frame | plane before | plane after | objects in ground mask before | after | s |", "|---|---|---|---|---|---|"]
    for spec, scene in zip(specs, scenes):
        t0 = time.perf_counter()
        (fb, sb), (fa, sa) = _row(scene, cfg.before), _row(scene, cfg.after)
        lines.append(f"| {spec.name} | {fb} | {fa} | {sb} | {sa} | {time.perf_counter() - t0:.1f} |")
    return "\n".join(lines) + "\n"


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="ground_report")
def main(dcfg: DictConfig) -> str:
    from .schema import one_line_errors

    with one_line_errors(log):
        cfg: GroundReportConfig = OmegaConf.to_object(dcfg)
        text = report(cfg)
    print(text, end="", flush=True)  # the command's product: the table on stdout
    return text


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, GroundReportConfig)


if __name__ == "__main__":
    cli()
