"""Training and held-out scoring of the learned baseline, deterministic on the CPU.

:func:`fit` trains a :class:`~somtorch.baselines.learned.model.UNet` on prepared tensors with
AdamW on ``BCE + soft Dice`` and a cosine learning rate; every random choice (initial weights, the
order of the frames, the flips) comes from one :class:`torch.Generator` seeded with
``fit.seed``, and it runs under ``torch.use_deterministic_algorithms(True)``: the same data, config,
seed and thread count give the same weights, bit for bit.

:func:`evaluate` scores a model on prepared frames at the network's size: the mask IoU with the
main object, the IoU of the best box with the main object's box, and the share of frames whose best
box holds at least 95 % of the main object's pixels (the "identified" rule of the scoring).
:func:`check_alive` refuses a network whose positive evidence died in training (no held-out pixel
above its output bias): it would mark every frame alike.

:func:`estimate` predicts the time and memory of a training run from sizes alone (before any work).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from somtorch.baselines.learned.model import UNet
from somtorch.baselines.learned.predict import mask_parts
from somtorch.config.learned import LearnedFitConfig, LearnedModelConfig
from somtorch.validation import SomtorchError, check_tensor

__all__ = ["TrainEstimate", "TrainingCollapsedError", "check_alive", "estimate", "evaluate", "fit",
           "forward_macs"]

# Seconds per multiply-accumulate of one training step (forward + backward + AdamW), per frame, on
# one 2-core development CPU with both threads, idle: the default network (~0.25 GMAC a forward
# pass at 64 x 96) trained 768 frames x 9 epochs in 92.8 s (13.4 ms a frame and epoch; session 25).
# Until session 25 it was 9 x larger (fitted under a load average of ~7), so the 15-minute budget
# refused runs of two minutes. Typical, not a bound: a loaded machine takes longer.
_T_MAC_TRAIN = 13.4e-3 / 0.25e9
_T_MAC_EVAL = _T_MAC_TRAIN / 3
_T_FRAME_PREP = 0.02  # reading and preparing one cached frame
_ACT_FACTOR = 8  # activations held for the backward pass: ~8 floats per output element of a convolution


@contextlib.contextmanager
def _deterministic() -> Iterator[None]:
    prev = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(prev)


def _loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    bce = F.binary_cross_entropy_with_logits(logits, target)
    p = torch.sigmoid(logits)
    inter = (p * target).sum(dim=(1, 2, 3))
    dice = 1 - (2 * inter + 1) / (p.sum(dim=(1, 2, 3)) + target.sum(dim=(1, 2, 3)) + 1)
    return bce + dice.mean()


def _lr(step: int, total: int, peak: float) -> float:
    """Cosine from ``peak`` to 5 % of it over ``total`` steps (a short linear warm-up first)."""
    warm = max(1, total // 20)
    if step < warm:
        return peak * (step + 1) / warm
    t = (step - warm) / max(1, total - warm)
    return peak * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * t)))


def fit(inputs: torch.Tensor, targets: torch.Tensor, model_cfg: LearnedModelConfig, fit_cfg: LearnedFitConfig, *,
        progress: bool = False, log: Callable[[str, float, int], None] | None = None) -> UNet:
    """Train a new network on ``inputs`` → ``targets``.

    Args:
        inputs: prepared frames (:func:`~somtorch.baselines.learned.data.prepare_input`).
        targets: the main object's share of each pixel (:func:`~somtorch.baselines.learned.data.prepare_target`).
        model_cfg: the network; fit_cfg: the optimisation and the seed.
        progress: a tqdm bar over the steps.
        log: ``log(tag, value, step)`` for each step's loss and learning rate (e.g. TensorBoard's
            ``SummaryWriter.add_scalar``).

    Returns:
        The trained network (in eval mode).

    Shape:
        inputs :math:`(N, C, h, w)`, targets :math:`(N, 1, h, w)`.
    """
    from tqdm.auto import tqdm

    check_tensor("inputs", inputs, ndim=4, dtype=torch.float32)
    check_tensor("targets", targets, ndim=4, dtype=torch.float32)
    n = inputs.shape[0]
    if targets.shape != (n, 1, *inputs.shape[2:]) or inputs.shape[1:] != (model_cfg.in_channels, model_cfg.height,
                                                                           model_cfg.width):
        raise ValueError(f"inputs {tuple(inputs.shape)} / targets {tuple(targets.shape)} do not fit the model "
                         f"({model_cfg.in_channels} channels, {model_cfg.height}x{model_cfg.width})")
    gen = torch.Generator().manual_seed(fit_cfg.seed)
    with _deterministic():
        model = UNet(model_cfg, generator=gen)
        opt = torch.optim.AdamW(model.parameters(), lr=fit_cfg.lr, weight_decay=fit_cfg.weight_decay)
        per_epoch = math.ceil(n / fit_cfg.batch_size)
        total = per_epoch * fit_cfg.epochs
        bar = tqdm(total=total, desc="training", unit="step", disable=not progress)
        model.train()
        step = 0
        for _ in range(fit_cfg.epochs):
            order = torch.randperm(n, generator=gen)
            flips = torch.rand(n, generator=gen) < 0.5
            for b in range(per_epoch):
                idx = order[b * fit_cfg.batch_size:(b + 1) * fit_cfg.batch_size]
                x, y = inputs[idx], targets[idx]  # (B, C, h, w), (B, 1, h, w)
                if fit_cfg.flip:
                    f = flips[idx][:, None, None, None]
                    x, y = torch.where(f, x.flip(-1), x), torch.where(f, y.flip(-1), y)
                lr = _lr(step, total, fit_cfg.lr)
                for group in opt.param_groups:
                    group["lr"] = lr
                loss = _loss(model(x), y)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                loss_v = loss.item()
                if log is not None:
                    log("train/loss", loss_v, step)
                    log("train/lr", lr, step)
                bar.set_postfix(loss=f"{loss_v:.3f}", refresh=False)
                bar.update()
                step += 1
        bar.close()
    return model.eval()


class TrainingCollapsedError(SomtorchError, RuntimeError):
    """A trained network that raises no pixel above its output bias (see :func:`check_alive`)."""


@torch.no_grad()
def check_alive(model: UNet, inputs: torch.Tensor, *, batch_size: int = 32) -> None:
    """Raise unless some pixel of ``inputs`` gets a logit above the head's bias.

    The head weighs the last block's ReLU features; where every feature it weighs positively is 0 on
    every frame (dead units: at ``fit.lr`` 3e-3 three of the four default models of session 24),
    no pixel gets any evidence for the object, the probability never exceeds sigmoid(bias), and the
    network marks every frame alike whatever it shows (its "mask" is the threshold's side of that
    bias). Such a model is refused before it is saved: its scores would be the bias's, not a
    network's.

    Raises:
        TrainingCollapsedError: names the fields that change the run (``fit.lr``, ``fit.seed``).

    Shape:
        inputs :math:`(N, C, h, w)`: prepared frames (the held-out ones).
    """
    model.eval()
    top = max(float(model(inputs[i:i + batch_size]).max()) for i in range(0, len(inputs), batch_size))
    bias = float(model.head.bias.max())
    if top <= bias:
        raise TrainingCollapsedError(
            f"the trained network raises none of the {len(inputs)} held-out frames' pixels above its output "
            f"bias ({bias:.3f}): its positive evidence died in training and it marks every frame alike; "
            "nothing was saved. Train again with a lower fit.lr or another fit.seed")


def _box_iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    iw = min(a[2], b[2]) - max(a[0], b[0]) + 1
    ih = min(a[3], b[3]) - max(a[1], b[1]) + 1
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    area = (a[2] - a[0] + 1) * (a[3] - a[1] + 1) + (b[2] - b[0] + 1) * (b[3] - b[1] + 1)
    return inter / (area - inter)


@torch.no_grad()
def evaluate(model: UNet, inputs: torch.Tensor, targets: torch.Tensor, *, batch_size: int = 32) -> dict[str, float]:
    """Held-out scores at the network's size (see the module docstring); means over the frames.

    Shape:
        inputs :math:`(N, C, h, w)`, targets :math:`(N, 1, h, w)`.
    """
    model.eval()
    cfg = model.cfg
    probs = torch.cat([torch.sigmoid(model(inputs[i:i + batch_size])) for i in range(0, len(inputs), batch_size)])
    mask_iou, box_iou, hit = [], [], []
    for p, x, t in zip(probs[:, 0], inputs, targets[:, 0]):
        truth = t > 0.5
        pred = p > cfg.threshold
        union = int((truth | pred).sum())
        mask_iou.append(int((truth & pred).sum()) / union if union else 1.0)
        valid = x[1] > 0.5
        found = mask_parts(p, x[0], valid, threshold=cfg.threshold, min_area=cfg.min_area)
        ys, xs = truth.nonzero(as_tuple=True)
        if not found or len(ys) == 0:
            box_iou.append(0.0)
            hit.append(0.0)
            continue
        best = found[0].box
        box_iou.append(_box_iou(best, (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max()))))
        inside = (xs >= best[0]) & (xs <= best[2]) & (ys >= best[1]) & (ys <= best[3])
        hit.append(float(inside.float().mean() >= 0.95))
    n = max(1, len(mask_iou))
    return {"frames": len(mask_iou), "mask_iou": sum(mask_iou) / n, "box_iou": sum(box_iou) / n,
            "identified_95": sum(hit) / n}


def forward_macs(cfg: LearnedModelConfig) -> int:
    """Multiply-accumulates of one forward pass of one frame (the 3x3 and 1x1 convolutions)."""
    w, h0, w0 = list(cfg.widths), cfg.height, cfg.width
    macs = 0
    for i, (c_in, c_out) in enumerate(zip([cfg.in_channels] + w[:-1], w)):
        px = (h0 >> i) * (w0 >> i)
        macs += px * 9 * (c_in * c_out + c_out * c_out)
        if i < len(w) - 1:  # the decoder block of this level
            macs += px * 9 * ((w[i + 1] + c_out) * c_out + c_out * c_out)
    return macs + h0 * w0 * w[0]


@dataclass(frozen=True)
class TrainEstimate:
    """Predicted seconds (frames to render, preparation, training, held-out scoring) and peak bytes."""

    render_s: float
    prepare_s: float
    train_s: float
    eval_s: float
    peak_bytes: int

    @property
    def seconds(self) -> float:
        """The whole estimate in seconds: rendering, preparation, training and evaluation."""
        return self.render_s + self.prepare_s + self.train_s + self.eval_s


def estimate(model_cfg: LearnedModelConfig, fit_cfg: LearnedFitConfig, *, train_frames: int, held_out_frames: int,
             frames_to_render: int = 0, render_s_per_frame: float = 0.25, workers: int = 1) -> TrainEstimate:
    """Time and memory of a run from sizes alone: frames to render (``render_s_per_frame`` CPU
    seconds each, on ``workers`` processes), the prepared tensors, the training steps and the
    activations of one batch (see the constants above)."""
    macs = forward_macs(model_cfg)
    n = train_frames + held_out_frames
    px = model_cfg.height * model_cfg.width
    data_b = n * (model_cfg.in_channels + 1) * px * 4
    act_b = fit_cfg.batch_size * _ACT_FACTOR * 4 * sum(
        (px >> (2 * i)) * c * 2 for i, c in enumerate(model_cfg.widths))
    params = sum(9 * c_in * c_out for c_in, c_out in zip([model_cfg.in_channels] + model_cfg.widths[:-1],
                                                          model_cfg.widths)) * 3
    peak = int(2 * data_b + act_b + params * 4 * 4 + (256 << 20))
    return TrainEstimate(render_s=frames_to_render * render_s_per_frame / max(1, workers),
                         prepare_s=n * _T_FRAME_PREP,
                         train_s=train_frames * fit_cfg.epochs * macs * _T_MAC_TRAIN,
                         eval_s=held_out_frames * macs * _T_MAC_EVAL, peak_bytes=peak)
