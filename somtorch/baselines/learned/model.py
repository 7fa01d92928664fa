"""The network of the learned baseline: a small U-Net (Ronneberger et al., MICCAI 2015).

Each encoder level is two 3x3 convolutions (GroupNorm, ReLU) and a 2x2 max-pool; each decoder level
upsamples bilinearly, concatenates the encoder's features of that level and applies two more
convolutions; a 1x1 convolution gives one logit per pixel: the main object. With the default
:class:`~somtorch.config.learned.LearnedModelConfig` (widths 16-32-64-128) it has about half a
million parameters.

The initial weights come from a :class:`torch.Generator` (:func:`init_weights`), never from torch's
global random state: ``UNet(cfg, generator=torch.Generator().manual_seed(s))`` is the same network
for the same ``s``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from somtorch.config.learned import LearnedModelConfig

__all__ = ["UNet", "init_weights", "parameter_count"]


def _block(c_in: int, c_out: int, groups: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.GroupNorm(groups, c_out), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1, bias=False), nn.GroupNorm(groups, c_out), nn.ReLU(inplace=True),
    )


class UNet(nn.Module):
    """The main object's logit at every pixel of a normalised disparity map.

    Args:
        cfg: the hyper-parameters (input channels, widths, GroupNorm groups).
        generator: the initial weights' random source (None: a generator seeded with 0).

    Shape:
        - input: :math:`(B, C, H, W)`, ``C = cfg.in_channels``, ``H, W`` divisible by
          ``2 ** (len(cfg.widths) - 1)``.
        - output: :math:`(B, 1, H, W)` logits.
    """

    def __init__(self, cfg: LearnedModelConfig, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        w, g = list(cfg.widths), cfg.groups
        self.down = nn.ModuleList([_block(c_in, c_out, g) for c_in, c_out in zip([cfg.in_channels] + w[:-1], w)])
        self.up = nn.ModuleList([_block(w[i + 1] + w[i], w[i], g) for i in reversed(range(len(w) - 1))])
        self.head = nn.Conv2d(w[0], 1, 1)
        init_weights(self, torch.Generator().manual_seed(0) if generator is None else generator)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The main object's mask logits of a batch of prepared frames.

        Shape:
            ``x`` ``(B, in_channels, H, W)`` with H and W divisible by ``2 ** (len(widths) - 1)``
            → ``(B, 1, H, W)`` logits.
        """
        skips = []
        for i, block in enumerate(self.down):
            x = block(x if i == 0 else F.max_pool2d(x, 2))  # (B, w_i, H / 2^i, W / 2^i)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))  # (B, w_i, H / 2^i, W / 2^i)
        return self.head(x)  # (B, 1, H, W)


@torch.no_grad()
def init_weights(model: nn.Module, generator: torch.Generator) -> None:
    """He-uniform convolutions (fan-in, ReLU gain), zero biases, unit GroupNorm; all from ``generator``
    in the modules' order."""
    for m in model.modules():
        if isinstance(m, nn.Conv2d):
            fan_in = m.in_channels * m.kernel_size[0] * m.kernel_size[1]
            bound = math.sqrt(6.0 / fan_in)
            m.weight.copy_(torch.rand(m.weight.shape, generator=generator) * 2 * bound - bound)
            if m.bias is not None:
                m.bias.zero_()
        elif isinstance(m, nn.GroupNorm):
            m.weight.fill_(1.0)
            m.bias.zero_()


def parameter_count(model: nn.Module) -> int:
    """Trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
