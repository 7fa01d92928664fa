"""Disparity video: the pipeline frame by frame, each SOM warm-started from the previous frame's.

A scene changes little from one frame to the next, so :class:`SequenceRunner` keeps what it can:

* **the SOM**: frame 1 trains cold (the configured schedule); every later frame starts from the
  previous weights and trains ``warm_epochs`` batch-map epochs with a small radius
  (``warm_sigma`` → the schedule's final radius), which adapts the map instead of re-ordering it;
* **the ground plane**: re-used while it still explains the new frame (its inlier share stays ≥
  ``ground_keep`` × the share it had when fitted), refitted otherwise and every
  ``ground_every`` frames;
* **buffers**: the camera and the config are the sequence's; the SOM's grid and generators live
  across frames;
* **work nobody reads**: a warm frame computes features for the pixels the object step reads
  (every ``map_stride``-th in y and x, :func:`~somtorch.pipeline.map_stride`) and the training
  pixels, and labels those only; the y, x scaling is the full map's, the disparity scaling comes
  from those pixels.

:func:`iter_sequence` is the library iterator; ``python -m experiments.video`` the Hydra
experiment (a synthetic camera motion over a real scene when no sequence is given), and
``benchmarks/bench_video.py`` measures frames per second, warm against cold.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace

import torch

from .config import PipelineConfig, WarmStartConfig
from .core import SOM
from .core.threads import contended
from .disparity.scene import Scene
from .pipeline import (MemberResult, _Timer, detect, detect_runs, map_stride, on_support, prepare, read_map,
                       segment_runs)
from .segmenters import Segmentation, _from_prototypes
from .tasks.ground import GroundPlane, fit_ground_plane, rim_share, view_rim
from .tasks.segmentation import segment

__all__ = ["FrameResult", "SequenceRunner", "iter_sequence", "pan_sequence"]

_W = WarmStartConfig  # the defaults, declared once in somtorch.config


@dataclass
class FrameResult:
    """One frame: its members' results, whether it was warm-started, whether the ground plane was
    re-used, and the seconds per stage."""

    index: int
    members: list[MemberResult]
    warm: bool
    ground_reused: bool
    ground: GroundPlane | None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def seconds(self) -> float:
        """The frame's time in all: the sum of its stage timings."""
        return sum(self.timings.values())


class SequenceRunner:
    """Steps 1a–1d on a stream of frames (see the module docstring).

    Args:
        cfg: the pipeline config (``method`` must be ``"som"``; the batch map is used for the
            warm frames whatever ``train.mode`` the cold frame uses).
        warm: False = every frame cold (the reference the warm frames are compared with).
        warm_epochs: batch-map epochs of a warm frame.
        warm_sigma: initial radius of a warm frame (grid units).
        ground_keep: re-use the plane while its inlier share is ≥ this × its share when fitted.
        ground_every: refit the plane at least every this many frames.
        reuse_ground: re-use the plane across frames (default: as ``warm``).
    """

    def __init__(self, cfg: PipelineConfig | None = None, *, warm: bool = _W.warm, warm_epochs: int = _W.warm_epochs,
                 warm_sigma: float = _W.warm_sigma, ground_keep: float = _W.ground_keep,
                 ground_every: int = _W.ground_every, reuse_ground: bool | None = None) -> None:
        self.cfg = cfg or PipelineConfig()
        if self.cfg.method != "som":
            raise ValueError(f"a warm-started sequence needs method='som'; got {self.cfg.method!r}")
        WarmStartConfig(warm, warm_epochs, warm_sigma, ground_keep, ground_every)  # the checks, named
        self.warm, self.warm_epochs, self.warm_sigma = warm, warm_epochs, warm_sigma
        self.ground_keep, self.ground_every = ground_keep, ground_every
        self.reuse_ground = warm if reuse_ground is None else reuse_ground
        self.som: SOM | None = None
        self._ground: GroundPlane | None = None
        self._ground_age = 0
        self._index = 0

    def _ground_for(self, scene: Scene, valid: torch.Tensor,
                    sigma: float | None = None) -> tuple[GroundPlane | None, bool]:
        g, cfg = self._ground, self.cfg.ground
        if self.reuse_ground and g is not None and self._ground_age < self.ground_every:
            h, w = scene.disparity.shape
            mask = valid & ((scene.disparity - g.disparity(h, w)).abs() <= g.tol)
            share = float(mask.sum()) / max(int(valid.sum()), 1)
            if share >= self.ground_keep * g.inlier_frac:
                self._ground_age += 1
                plane = replace(g, mask=mask, inlier_frac=share, rim_frac=rim_share(mask, view_rim(valid)))
                plane._cache = g._cache  # the same plane: its disparity map is not recomputed
                return plane, True
        g = fit_ground_plane(scene.disparity, valid, cfg, sigma=sigma)
        self._ground, self._ground_age = g, 0
        return g, False

    def step(self, scene: Scene) -> FrameResult:
        """Run one frame (the pipeline's own stages; only training starts from the last frame).

        On as many torch threads as other processes leave cores free (:func:`~somtorch.core.threads.contended`;
        the same bits at any count): on a busy 2-core machine two threads made a frame 7x slower.
        """
        with contended():
            return self._step(scene)

    def _step(self, scene: Scene) -> FrameResult:
        cfg, timer, reused = self.cfg, _Timer(), [False]
        with timer("ground"):  # a noisy frame through the median, as run_pipeline reads it
            scene, _, sigma = read_map(scene, cfg)

        def ground_fn(valid: torch.Tensor) -> GroundPlane | None:
            g, reused[0] = self._ground_for(scene, valid, sigma)
            return g

        # a warm frame computes features only where its object step reads (every map_stride-th
        # pixel) and where it trains
        st = map_stride(scene, cfg)
        grid = st if self.warm and self.som is not None else 1
        valid, ground, usable, feats, train = prepare(scene, cfg, timer, ground_fn=ground_fn, grid=grid)
        warm = self.warm and self.som is not None and self.som.dim == train.x.shape[-1]
        work = on_support(scene, ground, cfg.features)[0]  # (a superpixel segmenter reads its disparity)
        if not warm and grid > 1:  # (features of another width than the map's: never with one config)
            valid, ground, usable, feats, train = prepare(scene, cfg, timer, ground_fn=lambda v: ground)
            grid = 1
        if warm:
            tc = cfg.train
            with timer("train"):
                self.som.fit(train.x, mode="batch", epochs=self.warm_epochs, sigma=self.warm_sigma,
                             sigma_decay=tc.sigma_decay, neighborhood=tc.neighborhood, progress=False)
            w = self.som.weight.detach()
            seg: Segmentation = _from_prototypes(w, feats, self.som.grid_d2, self.som, self.som.seeds)
            with timer("segment"):
                # only the pixels the object step reads (every st-th in y and x, 1/st² of the
                # BMUs) and the training ones; the object step never reads the others
                on = feats if grid > 1 else feats.subsample(st)
                seg.labels = segment(w, on.x, on.pixels, on.shape)
            members = detect(scene, seg, ground, cfg, timer)
        else:  # cold: exactly run_pipeline's segmenter and object step (the consensus' map, if several)
            seg, members = detect_runs(scene, segment_runs(feats, train, work, usable, cfg, timer=timer), ground,
                                       cfg, timer)
            self.som = seg.som
        t = dict(timer.t)
        t["ground"] = t.get("ground", 0.0)
        t["objects"] = t.get("objects", 0.0) + t.pop("reduction", 0.0)
        out = FrameResult(self._index, members, warm, reused[0], ground, t)
        self._index += 1
        return out


def iter_sequence(frames: Iterable[Scene], cfg: PipelineConfig | None = None, **kwargs) -> Iterator[FrameResult]:
    """:class:`SequenceRunner` over ``frames``, one :class:`FrameResult` per frame (lazily: a
    frame is read from ``frames`` only when the previous one is done)."""
    runner = SequenceRunner(cfg, **kwargs)
    for scene in frames:
        yield runner.step(scene)


def pan_sequence(scene: Scene, width: int, height: int, frames: int, step_px: int = 4) -> Iterator[Scene]:
    """A synthetic camera motion over a real scene: ``frames`` windows of ``width × height`` sliding
    ``step_px`` to the right per frame, back and forth across the map (objects move along)."""
    from .tiles import crop_scene

    if width > scene.width or height > scene.height:
        raise ValueError(f"a {width} x {height} window does not fit the {scene.width} x {scene.height} scene")
    span = scene.width - width
    y0 = (scene.height - height) // 2
    for i in range(frames):
        pos = (i * step_px) % (2 * span) if span else 0
        x0 = pos if pos <= span else 2 * span - pos
        yield crop_scene(scene, y0, y0 + height, x0, x0 + width)
