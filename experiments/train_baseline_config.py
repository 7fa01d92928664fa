"""The schema of ``somtorch-train-baseline`` (``python -m experiments.train_baseline``): the learned
baseline's three config groups (declared once, in :mod:`somtorch.config.learned`) and the run's own keys."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig

from .data_schema import PathsConfig

__all__ = ["TrainBaselineConfig"]


@dataclass
class TrainBaselineConfig:
    """``somtorch-train-baseline``: the learned baseline trained on generated frames (never real ones).

    Attributes:
        model: the network (somtorch.config.learned.LearnedModelConfig).
        data: the generated training frames (LearnedDataConfig).
        fit: the optimisation and its seed (LearnedFitConfig).
        folds: also train one model without each camera of data.cameras (the validation's leave-one-dataset-out folds).
        budget_minutes: refuse a run whose estimated time (2 idle cores) exceeds this many minutes.
        max_memory_frac: refuse a run whose estimated peak memory exceeds this share of the available memory.
        workers: processes that render the missing frames.
        retrain: train again even where the cache holds the model.
        cache: the model cache (null = $SOMTORCH_CACHE/learned, else ~/.cache/somtorch/learned).
        corpus: the generated frames' cache (null = the generator's: $SOMTORCH_CORPUS, $SOMTORCH_CACHE/corpus, ...).
        paths: paths.data_dir is the real data, under which no training frame may lie.
    """

    model: LearnedModelConfig = field(default_factory=LearnedModelConfig)
    data: LearnedDataConfig = field(default_factory=LearnedDataConfig)
    fit: LearnedFitConfig = field(default_factory=LearnedFitConfig)
    folds: bool = False
    budget_minutes: float = 15.0
    max_memory_frac: float = 0.5
    workers: int = 2
    retrain: bool = False
    cache: Optional[str] = None
    corpus: Optional[str] = None
    paths: PathsConfig = field(default_factory=PathsConfig)
