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
from typing import Any
from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore

from somtorch.config import ResourcesConfig
from somtorch.outputs import OutputConfig
from somtorch.pipeline import PipelineConfig

from .data_schema import DataSource, PathsConfig
from .synth_config import SynthConfig
from .tool_configs import GroundReportConfig, SynthGalleryConfig


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
class DataConfig(DataSource):
    """:class:`~experiments.data_schema.DataSource` plus the StereoSGBM settings of a stereo pair
    (``data.sgbm.*``, OpenCV's names)."""

    sgbm: SGBMConfig = field(default_factory=SGBMConfig)  # type: ignore[valid-type]


@dataclass
class RunConfig(PipelineConfig):
    """The pipeline's own config (features, som, train, ground, objects, reduction, ensemble, seed,
    object_id) plus where the data comes from and what is written.

    Attributes:
        label: a name for the configuration (set by presets; shown in tables).
    """

    data: DataConfig = field(default_factory=DataConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    paths: PathsConfig = field(default_factory=PathsConfig)
    resources: ResourcesConfig = field(default_factory=ResourcesConfig)  # the check before any work
    label: str = "robust"


GENERIC_LEFT = ("left", "im0", "image_2", "l", "left_rect", "rect_left", "view1", "img_left", "left_image")


def pair_name(left: object) -> str:
    """The name of a stereo pair: its left file's stem, or the folder's when the stem is generic.

    >>> pair_name("/data/toy/left.png"), pair_name("/data/kitchen_l.png")
    ('toy', 'kitchen_l')
    """
    from pathlib import Path

    p = Path(str(left))
    if p.stem.lower() in GENERIC_LEFT and p.parent.name not in ("", ".", "/"):
        return p.parent.name
    return p.stem or "stereo_pair"


def register() -> None:
    """Register the schemas in Hydra's ConfigStore (idempotent)."""
    from pathlib import Path

    from omegaconf import OmegaConf

    cs = ConfigStore.instance()
    cs.store(name="run_schema", node=RunConfig)
    cs.store(name="synth_schema", node=SynthConfig)
    cs.store(name="ground_report_schema", node=GroundReportConfig)
    cs.store(name="synth_gallery_schema", node=SynthGalleryConfig)
    # ${stem:${data.source}}: a file input's run folder and scene are named after the file
    OmegaConf.register_new_resolver("stem", lambda p: Path(str(p)).stem or "file", replace=True)
    # ${pair:${data.left}}: a stereo pair's run folder and scene are named after the left file, or
    # after its folder when the file's name says only "left" (left.png, im0.png, ...)
    OmegaConf.register_new_resolver("pair", pair_name, replace=True)
    # ${experiments_pkg:}: this package's import name (experiments in a checkout, somtorch_experiments
    # installed), for the _target_ of Hydra callbacks in conf/
    OmegaConf.register_new_resolver("experiments_pkg", lambda: __package__, replace=True)
    # hydra/launcher=somtorch: Hydra finds plugins by scanning the hydra_plugins folders on sys.path,
    # which an editable install's import hook does not list; registered here, it is found either way
    from hydra.core.plugins import Plugins
    from hydra_plugins.somtorch_launcher.launcher import SomtorchLauncher

    Plugins.instance().register(SomtorchLauncher)


def to_config(dcfg: Any) -> Any:
    """A composed config as its dataclasses (their rules checked), after refusing a NaN or an
    infinity anywhere in it (a YAML ``.nan`` in a preset, an interpolation): ValueError, one line."""
    from omegaconf import OmegaConf

    from somtorch.config.constraints import nonfinite

    from .cli import FINITE_HINT

    bad = nonfinite(OmegaConf.to_container(dcfg, resolve=True))
    if bad is not None:
        raise ValueError(f"{bad[0]}={bad[1]}: expected a finite number ({FINITE_HINT})")
    return OmegaConf.to_object(dcfg)


def log_to_file(log: logging.Logger, level: int, msg: str, *args: object) -> None:
    """Log a record into the file handlers only (``run.log``), not onto the console: for a message
    the console gets once, as one plain line on stderr."""
    record = log.makeRecord(log.name, level, __file__, 0, msg, args, None)
    for h in logging.getLogger().handlers + log.handlers:
        if isinstance(h, logging.FileHandler) and record.levelno >= h.level:
            h.handle(record)


@contextlib.contextmanager
def one_line_errors(log: logging.Logger) -> Iterator[None]:
    """Bad input at the command line ends in one line (the message and a hint), exit status 2; the
    full traceback with ``HYDRA_FULL_ERROR=1``. Unexpected errors keep their traceback.

    A stop asked for by a signal comes first: an error raised after SIGINT / SIGTERM arrived (a
    library that turned the :class:`~somtorch.interrupt.Interrupted` into an error of its own, a
    clean-up that failed while the run unwound) is the interruption's consequence, not bad input,
    so it is raised as the interruption, the error chained to it: one line and 130 / 143 (and
    ``FAILED`` where :func:`experiments.cli.interruptible` holds the output folder)."""
    from omegaconf.errors import OmegaConfBaseException

    from somtorch import interrupt
    from somtorch.validation import SomtorchError

    try:
        yield
    except (ValueError, TypeError, FileNotFoundError, RuntimeError, SomtorchError, OmegaConfBaseException) as err:
        signum = interrupt.requested()
        if signum is not None:
            raise interrupt.Interrupted(signum, interrupt.where()) from err
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        msg = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        log_to_file(log, logging.ERROR, "%s: %s", type(err).__name__, msg)  # into run.log (stderr: below)
        print(f"error: {msg} (the full traceback: HYDRA_FULL_ERROR=1)", file=sys.stderr)
        raise SystemExit(2) from None