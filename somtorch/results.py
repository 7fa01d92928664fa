"""What :func:`~somtorch.pipeline.run_pipeline` returns: per run (:class:`MemberResult`) and for the
whole call (:class:`PipelineResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from .config import PipelineConfig
from .core import SOM
from .disparity.features import Features
from .segmenters import Segmentation
from .tasks.candidates import Candidate
from .tasks.ground import GroundPlane
from .tasks.objects import NeuronStats, ObjectArea
from .tasks.reduction import Reduction
from .tasks.scoring import Score

__all__ = ["MemberResult", "PipelineResult"]


@dataclass
class MemberResult:
    """Results of one ensemble member."""

    seed: int
    areas: list[ObjectArea]
    kept: list[ObjectArea]
    reduction: Reduction
    score: Score | None
    stats: NeuronStats
    no_object: bool = False  # nothing convincing was found: the whole map is kept
    # what became of each area the selection looked at, and how many it left out by reason
    # (tasks.candidates.Candidate, ObjectResult.unranked): metrics.json's "candidates"
    candidates: list[Candidate] = field(default_factory=list)
    unranked: dict[str, int] = field(default_factory=dict)
    # whether a perfect ranking of its candidates would have made it useful (detect(...,
    # first_place_ceiling=True): tasks.detect.first_place); None where not asked for or nothing to score
    first_place: bool | None = None
    # PipelineConfig.consensus: which of the run's maps was kept, and its mean IoU of kept pixels with
    # the others' (somtorch.consensus; None with one map per run)
    consensus_map: int = 0
    agreement: float | None = None
    # ... and how many of the run's maps were useful on their own (a scene with a labelled object; None
    # with one map per run or nothing to score): a perfect choice among the maps keeps a useful one
    # wherever this is above 0, the medoid follows the majority
    maps_useful: int | None = None


@dataclass
class PipelineResult:
    """What :func:`run_pipeline` returns: the segmentation and, per ensemble member, its kept areas,
    reduction and score.

    Attributes:
        features: the features of every valid pixel (those that are segmented).
        train_features: the features the segmenter was trained on (every ``train_stride``-th pixel).
        som: the trained maps (method ``som`` / ``minisom``); None for the other methods.
        labels: segment per pixel ``(E, H, W)``; -1 = not segmented (invalid or ground plane).
        ref_disparity: reference disparity of each segment in px ``(E, K)``.
        members: one :class:`MemberResult` per ensemble member.
        timings: seconds per stage.
        quantization_error: per member ``(E,)``.
        topographic_error: per member ``(E,)``.
        ground: the verified ground plane, or None.
        method: the segmenter's name.
        prototypes: feature-space centres ``(E, K, D)`` (SOM weights, k-means centres), or None.
        segmentation: the segmenter's own result, or None.
        config: the config that made it.
        median: the window of the median the map was read through (``features.median`` or wider
            where the map is noisy, :func:`denoised`), 0 = read as given.
    """

    features: Features
    train_features: Features
    som: SOM | None  # the trained maps (method "som" / "minisom"); None for the other methods
    labels: torch.Tensor  # (E, H, W) segment per pixel; -1 = not segmented (invalid or ground plane)
    ref_disparity: torch.Tensor  # (E, K) px
    members: list[MemberResult]
    timings: dict[str, float]
    quantization_error: torch.Tensor
    topographic_error: torch.Tensor
    ground: GroundPlane | None = None
    method: str = "som"
    prototypes: torch.Tensor | None = None  # (E, K, D) feature-space centres (SOM weights, k-means)

    segmentation: Segmentation | None = None
    config: PipelineConfig | None = None  # the config that made it
    median: int = 0  # the median window the map was read through (0 = as given)

    @property
    def num_segments(self) -> int:
        """Segments per member ``K`` (neurons, clusters or superpixels)."""
        return int(self.ref_disparity.shape[-1])
