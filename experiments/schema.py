"""Typed schemas of the Hydra configs: a typo or a wrong type fails before any work starts.

The pipeline's own dataclasses (``somtorch.pipeline``) are the schema of their groups, so the
library and the configs cannot drift apart.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from somtorch.outputs import OutputConfig
from somtorch.pipeline import PipelineConfig


def _sgbm_schema() -> type:
    """A mutable mirror of :class:`somtorch.disparity.stereo.SGBMParams` (same fields, types and
    defaults, declared there once): ``data.sgbm.numDisparities=64`` is then a plain override."""
    import typing

    from somtorch.disparity.stereo import SGBMParams

    hints = typing.get_type_hints(SGBMParams)
    cls = dataclasses.make_dataclass("SGBMConfig", [(f.name, hints[f.name], field(default=f.default))
                                                    for f in dataclasses.fields(SGBMParams)])
    cls.__module__ = __name__  # a config holding it pickles by reference (the validation's workers)
    return cls


SGBMConfig = _sgbm_schema()


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
    disparity_scale: Optional[float] = None  # stored value x scale = px (e.g. 0.25: Middlebury 2003 disp2.png)
    left: Optional[str] = MISSING
    right: Optional[str] = MISSING
    sgbm: SGBMConfig = field(default_factory=SGBMConfig)  # type: ignore[valid-type]
    name: Optional[str] = None
    # camera of a stereo pair (point clouds need it): focal length and principal point in px,
    # baseline in baseline_unit; cx/cy default to the image centre
    focal_px: Optional[float] = None
    baseline: Optional[float] = None
    baseline_unit: str = "m"
    cx: Optional[float] = None
    cy: Optional[float] = None
    doffs: float = 0.0
    # or one calibration file: stereodemo JSON, Middlebury/ETH3D calib.txt or KITTI calib_cam_to_cam.txt
    # (replaces the folder's own camera for a scene or file too)
    calibration: Optional[str] = None
    # the official KITTI 2015 layout: source = the training folder, frame = its number
    frame: Optional[str] = None


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
    from pathlib import Path

    from omegaconf import OmegaConf

    cs = ConfigStore.instance()
    cs.store(name="run_schema", node=RunConfig)
    # ${stem:${data.source}}: a file input's run folder and scene are named after the file
    OmegaConf.register_new_resolver("stem", lambda p: Path(str(p)).stem or "file", replace=True)


@contextlib.contextmanager
def one_line_errors(log: logging.Logger) -> Iterator[None]:
    """Bad input at the command line ends in one line (the message and a hint), exit status 2; the
    full traceback with ``HYDRA_FULL_ERROR=1``. Unexpected errors keep their traceback."""
    from omegaconf.errors import OmegaConfBaseException

    from somtorch.validation import SomtorchError

    try:
        yield
    except (ValueError, TypeError, FileNotFoundError, RuntimeError, SomtorchError, OmegaConfBaseException) as err:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        msg = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        log.error("%s: %s", type(err).__name__, msg)  # into run.log
        print(f"error: {msg} (the full traceback: HYDRA_FULL_ERROR=1)", file=sys.stderr)
        raise SystemExit(2) from None