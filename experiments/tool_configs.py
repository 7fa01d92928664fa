"""The schemas of the two report tools, ``python -m experiments.ground_report`` and
``python -m experiments.synth_gallery`` (no torch: ``--help`` reads them without it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from somtorch.config import GroundConfig

from .data_schema import PathsConfig
from .synth_config import SynthConfig

__all__ = ["GroundReportConfig", "SynthGalleryConfig"]


@dataclass
class GroundReportConfig:
    """``python -m experiments.ground_report``: the ground step alone under two configs, side by side.

    Attributes:
        before: the first ground config (``before.rule=position`` …; default: the defaults).
        after: the second ground config (default: the support rule).
        datasets: the registry's datasets (conf/datasets.yaml; None = the real ones).
        frames: single frames instead (None = every frame of those datasets).
        paths: where the shared data is (``paths.data_dir``).
    """

    before: GroundConfig = field(default_factory=GroundConfig)
    after: GroundConfig = field(default_factory=lambda: GroundConfig(rule="support"))
    datasets: Optional[list[str]] = None
    frames: Optional[list[str]] = None
    paths: PathsConfig = field(default_factory=PathsConfig)


@dataclass
class SynthGalleryConfig:
    """``python -m experiments.synth_gallery``: one picture per family of the synthetic generator.

    Attributes:
        families: families drawn, one picture each (default: every family, as the generator's).
        seeds: one row per seed.
        cameras: the camera of each seed, in turn.
        scale: image size factor (1 = each camera's full size).
        out: the folder of the pictures (None = docs/gallery of the checkout).
    """

    families: list[str] = field(default_factory=lambda: list(SynthConfig().families))
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2, 3])
    cameras: list[str] = field(default_factory=lambda: ["oakd", "kitti", "middlebury", "oakd"])
    scale: float = 1.0
    out: Optional[str] = None
