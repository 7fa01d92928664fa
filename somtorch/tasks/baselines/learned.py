"""The learned baseline (:mod:`somtorch.baselines.learned`) as the task baseline ``learned``.

``learned`` runs the network trained with the default configs
(:class:`~somtorch.config.learned.LearnedModelConfig`, ``LearnedDataConfig``, ``LearnedFitConfig``)
on every family x camera of the generator; ``TaskBaseline.without(camera)`` is the same network
trained without that camera's frames, the fold the validation uses for a dataset taken with that
camera. The models come from the cache (``somtorch-train-baseline`` trains them; a missing one is
a one-line error naming the command), loaded once per process. The mask's parts become obstacle
boxes, best first, so :func:`~somtorch.tasks.reduction.reduce_map` and the scorers treat them like
the SOM's kept areas. On the CPU it is deterministic.
"""

from __future__ import annotations

from typing import Any

import torch

from somtorch.baselines.learned.model import UNet
from somtorch.baselines.learned.predict import predict_parts
from somtorch.baselines.learned.store import model_key, trained_model
from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig

from .registry import Obstacle, map_arrays, register_task_baseline

__all__ = ["LearnedBoxes", "fold_data", "learned_boxes"]


def learned_boxes(disparity: torch.Tensor, valid: torch.Tensor, camera: Any = None, *, model: UNet) -> list[Obstacle]:
    """The obstacles ``model`` finds on one map, best first (``camera`` is not used).

    Shape:
        ``disparity`` float ``(H, W)`` in px, ``valid`` bool ``(H, W)``.
    """
    map_arrays(disparity, valid)  # the registry's checks (shapes, at least 16 valid pixels)
    return [Obstacle(p.box, p.disparity, p.pixels) for p in predict_parts(model, disparity, valid)]


def fold_data(without_camera: str | None = None, data: LearnedDataConfig | None = None) -> LearnedDataConfig:
    """The training data of the fold that leaves out ``without_camera``'s frames (None: all cameras)."""
    base = LearnedDataConfig() if data is None else data
    if without_camera is None:
        return base
    cams = [c for c in base.cameras if c != without_camera]
    if not cams:
        raise ValueError(f"leaving out camera {without_camera!r} leaves no training camera of {base.cameras}")
    return LearnedDataConfig(**{**base.as_dict(), "cameras": cams})


class LearnedBoxes:
    """``fn(disparity, valid, camera=None) -> list[Obstacle]`` with the cached model of a fold.

    Args:
        without_camera: the generator camera whose frames the model never saw (None: it saw all).
    """

    def __init__(self, without_camera: str | None = None) -> None:
        self.without_camera = without_camera
        self._model: UNet | None = None

    def model(self) -> UNet:
        """The fold's model, loaded from the cache on the first call."""
        if self._model is None:
            self._model = trained_model(LearnedModelConfig(), fold_data(self.without_camera), LearnedFitConfig())
        return self._model

    def __call__(self, disparity: torch.Tensor, valid: torch.Tensor, camera: Any = None) -> list[Obstacle]:
        return learned_boxes(disparity, valid, camera, model=self.model())


_FOLDS: dict[str, LearnedBoxes] = {}


def _fold(camera: str) -> LearnedBoxes:
    if camera not in _FOLDS:
        _FOLDS[camera] = LearnedBoxes(without_camera=camera)
    return _FOLDS[camera]


def _model_key() -> str:
    """The key of the model the default configs train
    (:func:`~somtorch.baselines.learned.store.model_key`)."""
    return model_key(LearnedModelConfig(), LearnedDataConfig(), LearnedFitConfig())


register_task_baseline("learned", LearnedBoxes(), deterministic=True, left_out=_fold, identity=_model_key)
