"""The schema of ``python -m experiments.synth`` (standard library only: ``--help`` reads it without torch)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from somtorch.config.options import SYNTH_FAMILIES

__all__ = ["SynthConfig"]


@dataclass
class SynthConfig:
    """``python -m experiments.synth``: generated frames written into the cache.

    Attributes:
        families: families to generate (``somtorch.synth.FAMILIES``).
        cameras: cameras to generate for (``somtorch.synth.CAMERAS``).
        n: frames per family x camera (seeds ``start`` to ``start + n - 1``).
        start: first seed.
        scale: image size factor (1 = each camera's full size).
        workers: processes, one frame per task (each on one thread).
        cache: the corpus folder; null = ``$SOMTORCH_CORPUS``, else ``$SOMTORCH_CACHE/corpus``, else
            ``~/.cache/somtorch/corpus`` (what ``experiments.datasets`` reads).
    """

    families: list[str] = field(default_factory=lambda: list(SYNTH_FAMILIES))
    cameras: list[str] = field(default_factory=lambda: ["oakd"])
    n: int = 10
    start: int = 0
    scale: float = 1.0
    workers: int = 2
    cache: Optional[str] = None
