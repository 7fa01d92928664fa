"""Configuration of paper step 1d (reduction), of a run's outputs, of sequences, and the whole
pipeline's (see :mod:`somtorch.config`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from . import options
from .constraints import BOOL, NON_NEGATIVE, POSITIVE, POSITIVE_INT, Choice, Interval, OneOf, Validated
from .objects import AreaConfig, GroundConfig
from .segmentation import BaselineConfig, FeatureConfig, SOMConfig, TrainConfig


# ---------------------------------------------------------------------------- step 1d: reduction
@dataclass
class ReductionConfig(Validated):
    """Tolerance margin around each kept box (paper Fig. 16): the sum of the three terms.

    Attributes:
        tolerance_px: a margin in px.
        tolerance_frac: a margin of this share of the box side (the paper's 5 %).
        tolerance_image: a margin of this share of the image diagonal (the default, 1.5 %).
    """

    _group: ClassVar[str] = "reduction"
    _constraints: ClassVar[dict[str, Any]] = {
        "tolerance_px": NON_NEGATIVE, "tolerance_frac": NON_NEGATIVE, "tolerance_image": NON_NEGATIVE,
    }

    tolerance_px: float = 0.0
    tolerance_frac: float = 0.0
    tolerance_image: float = 0.015


# ------------------------------------------------------------------------------------- outputs
@dataclass
class OutputConfig(Validated):
    """Which artefacts a run writes.

    Attributes:
        maps: write the pictures (disparity, segments, kept areas, reduced map, summary; PNG) and
            the reduced map (``reduced.npz``).
        pointcloud: write the point clouds of the full and the reduced map (PLY).
        render: also render the reduced point cloud to PNG.
        checkpoint: write the SOM's weights (``som.safetensors``).
        tensorboard: write TensorBoard logs (training curves, maps, hparams) under ``tb/``.
        voxel_size: voxel down-sampling of the point cloud, in the camera's baseline unit (None = off).
        render_backend: ``"auto"`` (Open3D if it imports, else matplotlib), ``"open3d"``, ``"matplotlib"``.
        member: the ensemble member drawn in the pictures.
    """

    _group: ClassVar[str] = "output"
    _constraints: ClassVar[dict[str, Any]] = {
        "maps": BOOL, "pointcloud": BOOL, "render": BOOL, "voxel_size": Interval(0, None, open_lo=True, optional=True),
        "render_backend": OneOf(("auto", "open3d", "matplotlib")), "checkpoint": BOOL, "tensorboard": BOOL,
        "member": Interval(0, None, integer=True),
    }

    maps: bool = True
    pointcloud: bool = True
    render: bool = True
    voxel_size: float | None = None
    render_backend: str = "auto"
    checkpoint: bool = True
    tensorboard: bool = True
    member: int = 0


@dataclass
class WarmStartConfig(Validated):
    """A disparity sequence (:class:`somtorch.video.SequenceRunner`).

    Attributes:
        warm: each frame's SOM starts from the previous frame's weights (False: every frame cold).
        warm_epochs: batch-map epochs of a warm frame.
        warm_sigma: neighbourhood radius a warm frame starts from (chosen on a synthetic pan over
            the Motorcycle, ``docs/scaling.md``: 1.0 lost the object in 5 of 40 frames, 2.0 in none).
        ground_keep: the ground plane is re-used while its inlier share stays ≥ this × its share
            when fitted.
        ground_every: the ground plane is refitted at least every this many frames.
    """

    _group: ClassVar[str] = "sequence"
    _constraints: ClassVar[dict[str, Any]] = {
        "warm": BOOL, "warm_epochs": POSITIVE_INT, "warm_sigma": POSITIVE,
        "ground_keep": Interval(0, 1, open_lo=True), "ground_every": POSITIVE_INT,
    }

    warm: bool = True
    warm_epochs: int = 2
    warm_sigma: float = 2.0
    ground_keep: float = 0.9
    ground_every: int = 15


# ---------------------------------------------------------------------------------- resources
@dataclass
class ResourcesConfig(Validated):
    """The check before any work (:mod:`somtorch.resources`): a job whose estimated peak memory
    exceeds ``max_memory_frac`` of the memory available, or whose estimated time exceeds
    ``max_hours``, is refused with one line.

    Attributes:
        check: estimate memory and time before any work and refuse what exceeds the budget (False: skip).
        max_memory_frac: the memory budget, as a share of the memory available (MemAvailable, cgroup limit).
        max_hours: the time budget in hours (the estimate is rough: it refuses the absurd).
    """

    _group: ClassVar[str] = "resources"
    _constraints: ClassVar[dict[str, Any]] = {
        "check": BOOL, "max_memory_frac": Interval(0, None, open_lo=True), "max_hours": POSITIVE,
    }

    check: bool = True
    max_memory_frac: float = 0.8
    max_hours: float = 24.0


# ------------------------------------------------------------------------------------ pipeline
@dataclass
class PipelineConfig(Validated):
    """The whole pipeline: ``method`` (segmenter of step 1b, see :data:`somtorch.segmenters.SEGMENTERS`),
    its groups, ``ensemble`` members (seeds ``seed … seed + ensemble − 1``), the scored
    ``object_id`` (None = the scene's main object(s)) and the torch ``device`` the SOM trains and
    labels the pixels on (``"cpu"``, ``"cuda"``, ``"cuda:1"``, ``"mps"``; the object step runs on
    the CPU).

    Attributes:
        method: the segmenter of step 1b ("som"; baselines: see somtorch.segmenters.SEGMENTERS).
        ensemble: SOMs trained at once, one per seed (seed, seed + 1, ...).
        seed: seed of the first member.
        consensus: maps trained per run, each with a seed of its own; the run keeps the one whose
            reduced map agrees best with the others' (:mod:`somtorch.consensus`). 1 = one map per
            run, the paper's. A deterministic method trains one map whatever this says.
        object_id: the scored object id of the scene's mask (None = the scene's main object(s)).
        device: torch device the SOM trains and labels pixels on ("cpu", "cuda", "cuda:1", "mps").
    """

    _constraints: ClassVar[dict[str, Any]] = {
        "method": Choice(options.METHODS), "ensemble": POSITIVE_INT, "consensus": POSITIVE_INT,
        "seed": Interval(0, None, integer=True), "object_id": Interval(1, None, integer=True, optional=True),
    }

    method: str = "som"
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    som: SOMConfig = field(default_factory=SOMConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    ground: GroundConfig = field(default_factory=GroundConfig)
    objects: AreaConfig = field(default_factory=AreaConfig)
    reduction: ReductionConfig = field(default_factory=ReductionConfig)
    ensemble: int = 1
    seed: int = 0
    consensus: int = 5
    object_id: int | None = None
    device: str = "cpu"

    @property
    def runs(self) -> int:
        """Members actually computed: ``ensemble``, or 1 for a deterministic method."""
        return 1 if options.METHODS[self.method] else self.ensemble

    @property
    def maps(self) -> int:
        """Maps trained per run: ``consensus``, or 1 for a deterministic method."""
        return 1 if options.METHODS[self.method] else self.consensus


def with_overrides(cfg: PipelineConfig, overrides: dict[str, Any]) -> PipelineConfig:
    """A copy of ``cfg`` with ``{"group.field": value}`` (or top-level ``"field"``) changed, validated.

    >>> with_overrides(PipelineConfig(), {"objects.merge": 0.5}).objects.merge
    0.5
    """
    from dataclasses import fields, replace

    changes: dict[str, dict[str, Any]] = {}
    top: dict[str, Any] = {}
    for key, value in overrides.items():
        group, _, name = key.rpartition(".")
        target = getattr(cfg, group, None) if group else cfg
        if target is None or name not in {f.name for f in fields(target)}:
            raise ValueError(f"override {key!r}: not a field of the pipeline config")
        if group:
            changes.setdefault(group, {})[name] = value
        else:
            top[name] = value
    return replace(cfg, **top, **{g: replace(getattr(cfg, g), **c) for g, c in changes.items()})
