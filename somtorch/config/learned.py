"""Configuration of the learned baseline (:mod:`somtorch.baselines.learned`): the network, its
synthetic training data and the optimisation, declared once (``somtorch-train-baseline`` reads them).

The training data are frames of the procedural generator only (:mod:`somtorch.synth`); the seeds
start at :attr:`LearnedDataConfig.first_seed`, far above the corpus seeds (``conf/datasets.yaml``:
0..5) that the validation and Table 1-2 score, so no scored synthetic frame is ever trained on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from .constraints import BOOL, FRACTION, POSITIVE, POSITIVE_INT, Interval, Validated

__all__ = ["LearnedDataConfig", "LearnedFitConfig", "LearnedModelConfig"]

_FAMILIES = ["stairs", "garden", "road", "room", "tabletop", "hands", "fence", "clutter"]
_CAMERAS = ["oakd", "kitti", "middlebury"]


class _Names:
    """A non-empty list of distinct strings (the generator checks the names themselves)."""

    def check(self, name: str, value: Any) -> None:
        if (not isinstance(value, list | tuple) or not value or len(set(value)) != len(value)
                or not all(isinstance(v, str) for v in value)):
            raise ValueError(f"{name} must be a non-empty list of distinct names; got {value!r}")


class _Widths:
    def check(self, name: str, value: Any) -> None:
        if (not isinstance(value, list | tuple) or not 1 <= len(value) <= 5
                or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in value)):
            raise ValueError(f"{name} must be a list of 1-5 positive ints (channels per level); got {value!r}")


@dataclass
class LearnedModelConfig(Validated):
    """The network: a U-Net that maps a scale-normalised disparity map to the main object's mask.

    Attributes:
        widths: channels of each encoder level (the last one is the bottleneck); each level halves
            the resolution, so ``height`` and ``width`` must divide by ``2 ** (len(widths) - 1)``.
        groups: GroupNorm groups of every convolution (must divide every width).
        height: rows of the network's input (every map is resized to ``height x width``).
        width: columns of the network's input.
        image: also feed the left image (RGB in [0, 1]; off: disparity and valid mask only).
        threshold: probability above which a pixel belongs to the predicted mask.
        min_area: connected parts of the mask smaller than this share of the image are no box.
    """

    _group: ClassVar[str] = "model"
    _constraints: ClassVar[dict[str, Any]] = {
        "widths": _Widths(), "groups": POSITIVE_INT, "height": Interval(8, 2048, integer=True),
        "width": Interval(8, 2048, integer=True), "image": BOOL, "threshold": Interval(0, 1, open_lo=True, open_hi=True),
        "min_area": FRACTION,
    }
    _relations: ClassVar[list] = [
        (lambda c: all(w % c.groups == 0 for w in c.widths), "groups={c.groups} must divide every width {c.widths}"),
        (lambda c: c.height % 2 ** (len(c.widths) - 1) == 0 and c.width % 2 ** (len(c.widths) - 1) == 0,
         "height={c.height} and width={c.width} must divide by 2 ** (len(widths) - 1)"),
    ]

    widths: list[int] = field(default_factory=lambda: [16, 32, 64, 128])
    groups: int = 4
    height: int = 64
    width: int = 96
    image: bool = False
    threshold: float = 0.5
    min_area: float = 0.002

    @property
    def in_channels(self) -> int:
        """Input channels: normalised disparity, valid mask (+ RGB with ``image``)."""
        return 2 + (3 if self.image else 0)


@dataclass
class LearnedDataConfig(Validated):
    """The synthetic training set: every family x camera, seeds ``first_seed ..``, GT and SGBM versions.

    Attributes:
        families: generator families (``somtorch.synth.FAMILIES``).
        cameras: generator cameras (``somtorch.synth.CAMERAS``).
        frames: training frames per family x camera (each in a GT and an SGBM version). 48 since
            session 25 (with 16 epochs): on the same 96 held-out synthetic frames, mask IoU 0.65 and
            the main object in the best box 53 % of the time, against 0.46 / 30 % for 16 frames x 8
            epochs and 0.57 / 43 % for 16 x 32 (docs/validation.md, "learned vs SOM vs geometry").
        held_out: held-out frames per family x camera (the seeds after the training ones), scored
            into the checkpoint's sidecar.
        first_seed: the first seed; far above the corpus seeds (0..5) that the validation scores.
        scale: image size factor of the generated frames (0.5 = half each camera's size).
        sgbm: also train on the SGBM version of each frame (off: GT disparity only).
    """

    _group: ClassVar[str] = "data"
    _constraints: ClassVar[dict[str, Any]] = {
        "families": _Names(), "cameras": _Names(), "frames": POSITIVE_INT,
        "held_out": POSITIVE_INT, "first_seed": Interval(1000, None, integer=True),
        "scale": Interval(0, 1, open_lo=True), "sgbm": BOOL,
    }

    families: list[str] = field(default_factory=lambda: list(_FAMILIES))
    cameras: list[str] = field(default_factory=lambda: list(_CAMERAS))
    frames: int = 48
    held_out: int = 2
    first_seed: int = 1000
    scale: float = 0.5
    sgbm: bool = True


@dataclass
class LearnedFitConfig(Validated):
    """The optimisation: AdamW on BCE + soft Dice, a cosine learning rate, random horizontal flips.

    Attributes:
        epochs: passes over the training set (16 since session 25: see ``LearnedDataConfig.frames``).
        batch_size: frames per step.
        lr: peak learning rate (cosine decay to 5 % of it over the run). 1e-3 since session 24: at
            3e-3 three of the four default models (the full one and two of its folds) came out dead
            (:func:`~somtorch.baselines.learned.train.check_alive`).
        weight_decay: AdamW's decoupled weight decay.
        flip: flip each training frame left-right with probability 1/2 (from the seed's generator).
        seed: the seed of the initial weights, the order of the frames and the flips.
    """

    _group: ClassVar[str] = "fit"
    _constraints: ClassVar[dict[str, Any]] = {
        "epochs": POSITIVE_INT, "batch_size": POSITIVE_INT, "lr": POSITIVE, "weight_decay": Interval(0, None),
        "flip": BOOL, "seed": Interval(0, None, integer=True),
    }

    epochs: int = 16
    batch_size: int = 16
    lr: float = 1e-3
    weight_decay: float = 1e-4
    flip: bool = True
    seed: int = 0
