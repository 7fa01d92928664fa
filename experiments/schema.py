"""Typed schemas of the Hydra configs: a typo or a wrong type fails before any work starts.

The pipeline's own dataclasses (``somtorch.pipeline``) are the schema of their groups, so the
library and the configs cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from somtorch.outputs import OutputConfig
from somtorch.pipeline import PipelineConfig


@dataclass
class DataConfig:
    """Where the disparity comes from.

    ``source``: ``"motorcycle"`` (the embedded Middlebury scene of scikit-image), a scene folder
    (every layout of ../shared/data) or a disparity file (PFM, 16-bit PNG, NPY, NPZ). With ``left``
    and ``right`` set instead, the disparity is computed with OpenCV StereoSGBM (``sgbm``). Every
    ``conf/data`` option sets ``source``, ``left`` and ``right`` (null where unused), so a missing
    mandatory value (``???``) fails at composition.
    """

    source: Optional[str] = MISSING
    disparity_file: Optional[str] = None
    left: Optional[str] = MISSING
    right: Optional[str] = MISSING
    sgbm: dict[str, Any] = field(default_factory=dict)
    name: Optional[str] = None
    # camera of a stereo pair (point clouds need it): focal length and principal point in px,
    # baseline in baseline_unit; cx/cy default to the image centre
    focal_px: Optional[float] = None
    baseline: Optional[float] = None
    baseline_unit: str = "m"
    cx: Optional[float] = None
    cy: Optional[float] = None
    doffs: float = 0.0


@dataclass
class PathsConfig:
    data_dir: str = "../shared/data"
    output_dir: str = "outputs"


@dataclass
class RunConfig(PipelineConfig):
    """The pipeline's own config (features, som, train, ground, objects, reduction, ensemble, seed,
    object_id) plus where the data comes from and what is written."""

    data: DataConfig = field(default_factory=DataConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    paths: PathsConfig = field(default_factory=PathsConfig)
    label: str = "robust"  # a name for the configuration (set by presets; shown in tables)


def register() -> None:
    """Register the schemas in Hydra's ConfigStore (idempotent)."""
    cs = ConfigStore.instance()
    cs.store(name="run_schema", node=RunConfig)
