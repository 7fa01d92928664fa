"""A learned baseline: a small U-Net trained on the generator's labelled frames (never on real data).

It answers the question a reviewer asks first: how does the SOM, which needs no training, compare
with a network trained for the task? The network sees a disparity map divided by its 95th
percentile and the valid mask (the image is optional, off by default) and predicts **the main
object's mask** — the object the scoring judges (the generator's id 1, the largest visible object;
a real scene's ``main`` object) — rather than every object's: the task is one kept area, best
first, so one mask is the output that maps onto it without a second, hand-tuned ranking step.
Its connected parts become :class:`~somtorch.tasks.baselines.Obstacle` boxes, best first, like
every task-level baseline (:mod:`somtorch.tasks.baselines.learned` registers it as ``learned``).

* :mod:`.model` — :class:`UNet` (built from :class:`~somtorch.config.learned.LearnedModelConfig`);
* :mod:`.data` — input preparation, the synthetic training frames, the real-data guard;
* :mod:`.train` — :func:`fit`, :func:`evaluate`, :func:`estimate`;
* :mod:`.checkpoint` — safetensors + JSON sidecar; :mod:`.store` — the model cache;
* :mod:`.predict` — :func:`predict_proba`, :func:`predict_parts` (the mask's parts, best first).

The command that trains it is ``somtorch-train-baseline`` (``experiments/train_baseline.py``).
"""

from somtorch.baselines.learned.checkpoint import CheckpointMismatchError, load, save
from somtorch.baselines.learned.data import RealDataError, build_tensors, check_synthetic, prepare_input
from somtorch.baselines.learned.model import UNet, parameter_count
from somtorch.baselines.learned.predict import Part, mask_parts, predict_parts, predict_proba
from somtorch.baselines.learned.store import model_path, train_or_load, trained_model
from somtorch.baselines.learned.train import TrainingCollapsedError, check_alive, estimate, evaluate, fit

__all__ = ["CheckpointMismatchError", "Part", "RealDataError", "TrainingCollapsedError", "UNet",
           "build_tensors", "check_alive", "check_synthetic", "estimate", "evaluate", "fit", "load",
           "mask_parts", "model_path", "parameter_count", "predict_parts", "predict_proba", "prepare_input",
           "save", "train_or_load", "trained_model"]
