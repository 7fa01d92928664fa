"""The paper's pipeline (Fig. 6) as a list of timed stages: clean → ground → features → segment
(step 1b, any registered segmenter, :mod:`somtorch.segmenters`) → objects (step 1c,
:func:`~somtorch.tasks.detect.find_objects`) → reduction (step 1d) → score.

``run_pipeline(scene)`` with no config does exactly what ``somtorch-run`` does with no overrides
(the defaults live in :mod:`somtorch.config`). It trains ``ensemble`` maps at once (one per seed)
and returns, per member, all object areas, the kept ones, the reduced map and, when the scene has
an object mask, the score. Point clouds and files are produced by the callers, so this module stays
free of I/O.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Any

import torch

from . import interrupt
from .consensus import choose, compact, merge_runs, shifted
from .config import (AreaConfig, BaselineConfig, FeatureConfig, GroundConfig, PipelineConfig, ReductionConfig,
                     SOMConfig, TrainConfig)
from .core.threads import contended
from .disparity.features import Features, make_features, relative_disparity
from .disparity.filters import median_filter, median_noise
from .disparity.scene import Scene
from .fallbacks import fallback_summary, warn_fallbacks  # noqa: F401  (fallback_summary: its old home)
from .resources import Estimate, estimate
from .results import MemberResult, PipelineResult
from .segmenters import METHODS, SEGMENTERS, Segmentation, run_segmenter
from .tasks.context import MapContext
from .tasks.detect import find_objects, first_place
from .tasks.ground import GroundPlane, fit_ground_plane, noise_sigma
from .tasks.objects import ObjectArea
from .tasks.reduction import Reduction, reduce_map, valid_integral
from .tasks.refine import solidity_square
from .tasks.scoring import optimal_reduction, score_reduction

__all__ = ["AreaConfig", "BaselineConfig", "FeatureConfig", "GroundConfig", "METHODS", "MemberResult",
           "ObjectSetup", "PipelineConfig", "PipelineResult", "ReductionConfig", "SOMConfig", "TrainConfig",
           "detect", "detect_runs", "map_stride", "object_setup", "run_pipeline", "segment_runs",
           "train_stride", "unscorable"]
DETERMINISTIC_METHODS = tuple(n for n, s in SEGMENTERS.items() if s.deterministic)
log = logging.getLogger("somtorch.pipeline")


class _Timer:
    """Seconds per stage: ``with timer("ground"): ...`` adds to ``timer.t["ground"]``."""

    def __init__(self) -> None:
        self.t: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        interrupt.checkpoint(f"during stage {stage}")
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.t[stage] = self.t.get(stage, 0.0) + time.perf_counter() - t0


def _min_pixels(cfg: PipelineConfig) -> int:
    """Valid pixels a map needs: one per SOM neuron, at least 16."""
    return max(16, cfg.som.rows * cfg.som.cols if cfg.method in ("som", "minisom") else 16)


def denoised(scene: Scene, cfg: PipelineConfig) -> tuple[Scene, int]:
    """The scene every step reads, and the median window it was read through (0 = none): where the
    map's per-pixel noise sets the ground band (``cfg.ground.noise_band`` × σ > ``cfg.ground.tol_px``,
    σ = :func:`~somtorch.tasks.ground.noise_sigma`), its valid disparities through a median
    (:func:`~somtorch.disparity.filters.median_filter`) of a ``cfg.features.median`` window, or of
    the smallest wider odd one whose left-over noise (:func:`~somtorch.disparity.filters.median_noise`)
    no longer sets the band, at most the object step's solidity square (``objects.solidity_size``
    × the shorter side: what is thinner is not kept as an object anyway); else the scene as given.
    A dense sensor's noise splits one surface into speckled segments that no opening, link or box
    rule puts back together (``docs/tuned_constants.md``)."""
    return read_map(scene, cfg)[:2]


def read_map(scene: Scene, cfg: PipelineConfig) -> tuple[Scene, int, float | None]:
    """:func:`denoised`, and the per-pixel noise σ (px) of the scene it returns, for the ground
    band (:func:`~somtorch.tasks.ground.fit_ground_plane`'s ``sigma``): as measured where the map
    is read as given; where it was filtered, what the median leaves of the measured noise
    (:func:`~somtorch.disparity.filters.median_noise`), which the filtered map's neighbour
    differences cannot read; None where nothing was measured (``features.median`` ≤ 1: the
    ground fit measures it)."""
    k = cfg.features.median
    if k <= 1:
        return scene, 0, None
    sigma = noise_sigma(scene.disparity, scene.valid)
    band = cfg.ground.noise_band
    if band * sigma <= cfg.ground.tol_px:
        return scene, 0, sigma
    # a wider window while what the median leaves still sets the band, up to the object step's
    # solidity square (what is thinner than it is not kept as an object anyway)
    widest = max(k, solidity_square(scene.disparity.shape, cfg.objects.solidity_size))
    while band * median_noise(sigma, k) > cfg.ground.tol_px and k + 2 <= widest:
        k += 2
    return (replace(scene, disparity=median_filter(scene.disparity, scene.valid, k)), k,
            median_noise(sigma, k))


def unscorable(scene: Scene, object_id: int | None = None) -> str | None:
    """Why no run on ``scene`` can be scored, in one line, or None: the scene has an object mask, and
    the object the runs are scored against (``object_id``; None: the main object) has no pixel with
    a valid disparity (a matcher leaves a textureless object without any). :func:`prepare` refuses
    such a scene before any work; ``somtorch-run`` reduces it unscored, ``somtorch-study`` refuses
    the sweep."""
    if scene.objects is None:
        return None
    mask = scene.scored_mask(object_id)
    if mask is not None and bool((mask & scene.valid).any()):
        return None
    what = "the main object" if object_id is None else f"object {object_id}"
    return f"scene {scene.name!r}: {what} has no pixel with a valid disparity, so no run of it can be scored"


def check_usable(scene: Scene, cfg: PipelineConfig) -> None:
    """The degenerate-input checks of :func:`prepare` (see there)."""
    why = unscorable(scene, cfg.object_id)
    if why is not None:
        raise ValueError(f"{why}; leave its labels out (Scene.objects None) to reduce it unscored")
    n = scene.n_valid
    need = _min_pixels(cfg)
    if n < need:
        raise ValueError(f"scene {scene.name!r}: only {n} valid pixel(s); the segmentation needs at least {need} "
                         f"(one per SOM neuron, {cfg.som.rows}x{cfg.som.cols}); is the right disparity file loaded?")

    def flat(d: torch.Tensor) -> tuple[float, float, bool]:
        lo, hi = float(d.min()), float(d.max())
        return lo, hi, hi - lo <= 1e-6 * max(1.0, abs(hi))

    # a 1/16 sample that already varies proves the whole map does (its spread can only be larger,
    # by at least as much as its largest value grows); only a flat-looking sample needs every pixel
    sample = torch.masked_select(scene.disparity[::4, ::4], scene.valid[::4, ::4])
    constant = sample.numel() < 2 or flat(sample)[2]
    if constant:
        lo, hi, constant = flat(torch.masked_select(scene.disparity, scene.valid))
    if constant:
        raise ValueError(f"scene {scene.name!r}: every valid pixel has disparity {lo:g} px, a constant map with "
                         "nothing to single out" + (" (an all-zero map: the file holds no disparity, or "
                                                    "0 should mean 'invalid' and does not in this format)" if lo == 0 else ""))


def prepare(scene: Scene, cfg: PipelineConfig, timer: _Timer | None = None, *,
            ground_fn: Callable[[torch.Tensor], GroundPlane | None] | None = None, grid: int = 1,
            sigma: float | None = None
            ) -> tuple[torch.Tensor, GroundPlane | None, torch.Tensor, Features, Features]:
    """Stages clean, ground and features: ``(valid, ground, usable, features, training features)``.

    ``ground_fn(valid)``: where the ground plane comes from instead of a fit (a video re-uses the
    previous frame's plane). ``grid``: feature vectors only for the usable pixels on every
    ``grid``-th row and column and on the training grid (a warm video frame, whose object step
    reads no other pixel; the scaling then comes from those pixels); ``usable`` is always the whole
    map's. ``sigma``: the map's :func:`~somtorch.tasks.ground.noise_sigma` if already measured
    (by :func:`denoised`'s trigger), passed to the ground fit.

    Raises:
        ValueError: before any work, for a map no segmentation can use: fewer valid pixels than
            the SOM has neurons (or than 16), or one disparity everywhere (a constant map — an
            all-zero file usually means its invalid value was not declared); and for a labelled
            scene whose scored object has no valid pixel (:func:`unscorable`).
    """
    timer = timer or _Timer()
    check_usable(scene, cfg)
    valid = scene.valid
    with timer("ground"):
        ground = ground_fn(valid) if ground_fn is not None else fit_ground_plane(scene.disparity, valid, cfg.ground,
                                                                                 sigma=sigma)
    stride = train_stride(scene, cfg)
    if ground is not None and not bool((valid & ~ground.mask)[::stride, ::stride].any()):
        # an empty floor or table seen from above: the plane is the whole map, and cutting it would
        # leave nothing to train on. The map is segmented whole (the object step's contrast rule,
        # with its fail-safe), as if no plane had been found.
        log.warning("scene %s: the ground plane holds %d of the %d valid pixels and leaves none to train on "
                    "(every %dth pixel); it is not removed, the map is segmented whole", scene.name,
                    int(ground.mask.sum()), scene.n_valid, stride)
        ground = None
    with timer("features"):
        work = on_support(scene, ground, cfg.features)[0]
        # the plane's pixels leave the map, except under heights above it (they are its level 0)
        usable = valid if ground is None or work is not scene else valid & ~ground.mask
        rows = usable
        if grid > 1:  # the grid's pixels and the training pixels
            rows = torch.zeros_like(usable)
            rows[::grid, ::grid] = usable[::grid, ::grid]
            rows[::stride, ::stride] = usable[::stride, ::stride]
        f = cfg.features
        feats = make_features(work.disparity, rows, normalize=f.normalize, d_weight=f.d_weight,
                              image=scene.image if f.color_weight > 0 else None, color_weight=f.color_weight)
        train = feats.subsample(stride)
        if len(train) == 0:
            raise ValueError(f"features.train_stride={cfg.features.train_stride} (every {stride}th pixel at "
                             f"{scene.width}x{scene.height}) leaves no valid pixel of scene {scene.name!r} to "
                             "train on; use a smaller stride")
    return valid, ground, usable, feats, train


def on_support(scene: Scene, ground: GroundPlane | None,
               features: FeatureConfig) -> tuple[Scene, GroundPlane | None]:
    """The scene and plane the segmentation and the object step read: as given, or — with
    ``features.d_mode="plane_residual"`` and a plane the support test verified
    (:attr:`~somtorch.tasks.ground.GroundPlane.support`) — the scene whose disparity is the height
    above the plane (:func:`~somtorch.disparity.features.relative_disparity`) and the plane at
    height 0 (same band and mask), so that the areas' contrast, joining and ground clutter are
    measured against the support surface too. Valid mask, image and objects are unchanged.

    A plane found by the position rule alone is not used: a forward camera's floor recedes to a
    horizon and everything beyond its far end (walls, buildings) stands high above its extension.
    """
    if features.d_mode == "raw" or ground is None or not ground.support:
        return scene, ground
    h, w = scene.disparity.shape
    height = relative_disparity(scene.disparity, ground.disparity(h, w))
    # at height 0 (its own disparity cache: a field outside init)
    level = replace(ground, a=0.0, b=0.0, c=0.0, bend=(0.0, 0.0, 0.0))
    return replace(scene, disparity=height), level


@dataclass
class ObjectSetup:
    """What the object step reads of a scene, the same for every map of a run (each segments the
    same pixels): the scene and plane of :func:`on_support`, the object step's stride, the
    :class:`~somtorch.tasks.context.MapContext` of the strided map, the reduction's valid-pixel
    integral at full size, the scored mask and its ``x_opt``. Built by :func:`object_setup`, once
    per run rather than once per map (:func:`detect_runs`)."""

    scene: Scene
    ground: GroundPlane | None
    stride: int
    ocfg: AreaConfig
    ctx: MapContext
    integral: torch.Tensor
    obj_mask: torch.Tensor | None
    x_opt: float | None

    def serves(self, labels: torch.Tensor) -> bool:
        """Whether a map's ``(E, H, W)`` labels segment the pixels this setup was built for: the
        scene's size, and on the object step's grid (every ``stride``-th pixel, all the setup reads
        of a map: ``ctx.usable``) the same labelled pixels."""
        s = self.stride
        return tuple(labels.shape[-2:]) == tuple(self.scene.valid.shape) and \
            torch.equal(labels[0, ::s, ::s] >= 0, self.ctx.usable)


def object_setup(scene: Scene, labels: torch.Tensor, ground: GroundPlane | None, cfg: PipelineConfig
                 ) -> ObjectSetup:
    """The :class:`ObjectSetup` of ``scene`` (as read by :func:`read_map`), for maps segmenting the
    pixels of ``labels`` ``(E, H, W)`` (``labels[0] >= 0``) with ``ground`` as fitted."""
    scene, ground = on_support(scene, ground, cfg.features)
    st = map_stride(scene, cfg)
    disp, valid, strided, g, ocfg = _strided(scene, labels[:1], ground, replace(cfg.objects, map_stride=st))
    ctx = MapContext.build(disp, valid, strided[0] >= 0, g, ocfg, cfg.reduction, st)
    integral = ctx.integral if st == 1 else valid_integral(scene.valid)  # the reduction's: full size
    obj_mask, x_opt = None, None
    if scene.objects is not None:
        obj_mask = scene.scored_mask(cfg.object_id)
        x_opt = optimal_reduction(obj_mask, scene.valid, integral)  # the same for every member
    return ObjectSetup(scene, ground, st, ocfg, ctx, integral, obj_mask, x_opt)


def detect(scene: Scene, seg: Segmentation, ground: GroundPlane | None, cfg: PipelineConfig,
           timer: _Timer | None = None, *, first_place_ceiling: bool = False,
           warn: bool = True, setup: ObjectSetup | None = None) -> list[MemberResult]:
    """Stages objects, reduction and score of every member of ``seg`` (steps 1c, 1d), on the scene
    and plane of :func:`on_support` (``ground`` as fitted). ``first_place_ceiling``: on a scene with a
    labelled object, also set each member's :attr:`MemberResult.first_place` (an analysis: each
    candidate tried first until one makes the run useful; seconds per scene). ``warn``: log the
    members' fallbacks (:func:`~somtorch.fallbacks.warn_fallbacks`). ``setup``: the scene's
    :func:`object_setup` if already built for these pixels (built here otherwise)."""
    timer = timer or _Timer()
    with timer("objects"):  # every member segments the same pixels: one context for all
        if setup is None or not setup.serves(seg.labels):
            setup = object_setup(scene, seg.labels, ground, cfg)
        st, ocfg, ctx, integral = setup.stride, setup.ocfg, setup.ctx, setup.integral
        # the object step reads int64 labels: a map held as int16 is widened on its grid alone
        labels = (seg.labels if st == 1 else seg.labels[:, ::st, ::st]).long().contiguous()
    scene, obj_mask, x_opt = setup.scene, setup.obj_mask, setup.x_opt
    h, w = scene.disparity.shape
    r = cfg.reduction
    members = []
    for e in range(seg.labels.shape[0]):
        interrupt.checkpoint(f"in the object step, member {e + 1}/{seg.labels.shape[0]}")
        with timer("objects"):
            found = find_objects(labels[e], seg.ref_disparity[e], seg.grid_d2, ctx, ocfg)
            grid_areas = found.areas  # on the object step's grid, for first_place below
            if st > 1:
                found.areas = [_full_size(a, st, h, w) for a in found.areas]
                found.kept = [_full_size(a, st, h, w) for a in found.kept]
                found.candidates = [replace(c, area=_full_size(c.area, st, h, w)) for c in found.candidates]
        def reduced(boxes: list[tuple[int, int, int, int]]) -> Reduction:  # step 1d on the full map
            return reduce_map(boxes, scene.valid, tolerance_px=r.tolerance_px, tolerance_frac=r.tolerance_frac,
                              tolerance_image=r.tolerance_image, integral=integral)
        with timer("reduction"):
            red = reduced([a.box for a in found.kept])
        score = score_reduction(red, obj_mask, scene.valid, x_opt=x_opt) if obj_mask is not None else None
        first = None
        if first_place_ceiling and score is not None:
            def useful(kept: list[ObjectArea]) -> bool:  # what the reduced map would keep (nothing: all)
                got = reduced([_full_size(a, st, h, w).box for a in kept] or [(0, 0, w - 1, h - 1)])
                return score_reduction(got, obj_mask, scene.valid, x_opt=x_opt).useful_hit
            first = score.useful_hit or first_place(grid_areas, found.stats, labels[e], ocfg, ctx, useful)
        members.append(MemberResult(seg.seeds[e], found.areas, found.kept, red, score, found.stats,
                                    found.no_object, found.candidates, found.unranked, first))
    if warn:
        warn_fallbacks(scene.name, members)
    return members


def segment_runs(feats: Features, train: Features, scene: Scene, usable: torch.Tensor, cfg: PipelineConfig,
                 **kwargs: Any) -> Iterator[Segmentation]:
    """Step 1b for every map of the runs (:attr:`PipelineConfig.maps`), one set of ``E`` maps at a
    time (lazily: :func:`detect_runs` reads each before the next is trained); ``kwargs``, such as
    ``progress`` or ``log_training``, reach the first map's training only."""
    timer = kwargs.pop("timer", None)
    extra = {"timer": timer} if timer is not None else {}
    for k in range(cfg.maps):
        first = kwargs if k == 0 else {}
        yield run_segmenter(feats, train, scene, usable, shifted(cfg, k), **extra, **first)


def detect_runs(scene: Scene, segs: Iterable[Segmentation], ground: GroundPlane | None, cfg: PipelineConfig,
                timer: _Timer | None = None, *, first_place_ceiling: bool = False
                ) -> tuple[Segmentation, list[MemberResult]]:
    """:func:`detect` on each map of :func:`segment_runs`; with several maps per run, each run keeps
    the map of the consensus (:func:`somtorch.consensus.choose`). Returns the kept maps as one
    segmentation and their member results. ``segs`` may hold their labels as int16 (a cache of
    them, :func:`~somtorch.consensus.compact`): the object step widens to int64 only the grid it
    reads (:func:`detect`), and a map waiting for the consensus is held as int16 (a map has far fewer
    segments); the kept labels come back as int64."""
    held, per_map = [], []
    setup = None
    for s in segs:
        if setup is None:  # once per run: every map segments the same pixels (detect checks)
            with (timer or _Timer())("objects"):
                setup = object_setup(scene, s.labels, ground, cfg)
        per_map.append(detect(scene, s, ground, cfg, timer, first_place_ceiling=first_place_ceiling,
                              warn=cfg.maps == 1, setup=setup))
        if cfg.maps == 1:
            return (s if s.labels.dtype == torch.long else replace(s, labels=s.labels.long())), per_map[0]
        held.append(compact(s))  # (a held int16 map is kept as it is, not copied)
        del s  # not alive while the next set of maps is trained and labelled
    with (timer or _Timer())("objects"):  # the consensus is step 1c's choice among the maps
        chosen, members = choose(per_map)
    warn_fallbacks(scene.name, members)
    return merge_runs(held, chosen), members


def train_stride(scene: Scene, cfg: PipelineConfig) -> int:
    """The training stride on ``scene``: ``features.train_stride`` at its resolution
    (:meth:`~somtorch.config.FeatureConfig.stride_at`)."""
    return cfg.features.stride_at(cfg.features.train_stride, *scene.valid.shape)


def map_stride(scene: Scene, cfg: PipelineConfig) -> int:
    """The stride the object step uses on ``scene``: ``objects.map_stride`` at its resolution
    (:meth:`~somtorch.config.FeatureConfig.stride_at`), or the largest smaller one whose
    grid still holds as many valid pixels as the segmentation needs (a small map is read whole;
    logged as a warning naming the setting)."""
    s = cfg.features.stride_at(cfg.objects.map_stride, *scene.valid.shape)
    if s == 1:
        return 1
    need = _min_pixels(cfg)
    h, w = scene.valid.shape
    t = min(s, max(h, w))
    # a grid of -(-h // t) x -(-w // t) points cannot hold `need` valid pixels when it has fewer points
    while t > 1 and ((-(-h // t)) * (-(-w // t)) < need or int(scene.valid[::t, ::t].sum()) < need):
        t -= 1
    if t < s:
        log.warning("scene %s: objects.map_stride=%d (every %dth pixel at %dx%d) leaves fewer than %d valid pixels "
                    "on the grid the object step reads; it reads %s instead", scene.name, cfg.objects.map_stride, s,
                    w, h, need,
                    "every pixel" if t == 1 else f"every {t}th pixel")
    return t


def _strided(scene: Scene, labels: torch.Tensor, ground: GroundPlane | None, cfg: AreaConfig):
    """The maps the object step reads: every ``cfg.map_stride``-th pixel in y and x (all at 1).

    The ground plane is re-expressed in the sampled pixel coordinates.
    """
    s = cfg.map_stride
    if s == 1:
        return scene.disparity, scene.valid, labels, ground, cfg
    g = None if ground is None else replace(ground, a=ground.a * s, b=ground.b * s,
                                            bend=tuple(v * s * s for v in ground.bend),
                                            mask=ground.mask[::s, ::s].contiguous())
    return (scene.disparity[::s, ::s].contiguous(), scene.valid[::s, ::s].contiguous(),
            labels[:, ::s, ::s].contiguous(), g, cfg)


def _full_size(area: ObjectArea, s: int, h: int, w: int) -> ObjectArea:
    """An area found on a map sampled every ``s`` pixels, in the full map's pixel coordinates."""
    def box(b: tuple[int, int, int, int] | None) -> tuple[int, int, int, int] | None:
        if b is None or b[2] < b[0]:
            return b
        return (b[0] * s, b[1] * s, min(w - 1, b[2] * s), min(h - 1, b[3] * s))
    return replace(area, box=box(area.box), segment_box=box(area.segment_box), pixels=area.pixels * s * s)


def resource_estimate(scene: Scene, cfg: PipelineConfig) -> Estimate:
    """Peak memory and time :func:`run_pipeline` will need on ``scene`` (:mod:`somtorch.resources`),
    from sizes only: the training pixels are counted on the stride grid of the valid mask."""
    from .core.native import available

    s = train_stride(scene, cfg)
    h, w = scene.valid.shape
    # the compiled kernels serve a CPU run where they build (the online loop: Gaussian neighbourhood
    # only); a GPU counts as fast as they are (not measured)
    native = not str(cfg.device).startswith("cpu") or available() and (
        cfg.train.mode != "online" or cfg.train.neighborhood == "gaussian")
    return estimate(height=h, width=w, valid=scene.n_valid, train=int(scene.valid[::s, ::s].sum()), native=native,
                    dim=3 + 3 * (cfg.features.color_weight > 0), units=cfg.som.rows * cfg.som.cols,
                    members=cfg.runs, maps=cfg.maps, epochs=cfg.train.epochs, mode=cfg.train.mode,
                    batch_size=cfg.train.batch_size, method=cfg.method, iterations=cfg.baseline.kmeans_iterations,
                    map_stride=cfg.features.stride_at(cfg.objects.map_stride, h, w))


def run_pipeline(scene: Scene, cfg: PipelineConfig | None = None, *, progress: bool = False,
                 metrics: bool = True,
                 log_training: Callable[[str, float, int], Any] | None = None) -> PipelineResult:
    """Run steps 1a–1d on ``scene`` (see the module docstring). Timings are in seconds per stage.

    Args:
        progress: show a progress bar while training.
        metrics: compute quantization and topographic error of the trained maps.
        log_training: called as ``log_training(tag, value, epoch)`` once per epoch with the mean
            quantization / topographic error of the members (e.g. ``SummaryWriter.add_scalar``);
            it runs inside training, so its cost is included in the ``train`` timing.
    """
    cfg = cfg or PipelineConfig()
    timer = _Timer()
    # SIGINT / SIGTERM stop it between epochs, chunks, members (somtorch.interrupt); torch threads no
    # more than the cores other processes leave free (the same bits at any count; tests/test_pipeline.py)
    with interrupt.deferred(), contended():
        with timer("ground"):  # (the noise estimate: the ground band's input)
            scene, window, sigma = read_map(scene, cfg)
        valid, ground, usable, feats, train = prepare(scene, cfg, timer, sigma=sigma)
        work = on_support(scene, ground, cfg.features)[0]  # (a superpixel segmenter reads its disparity)
        segs = segment_runs(feats, train, work, usable, cfg, progress=progress, log_training=log_training,
                            timer=timer)
        seg, members = detect_runs(scene, segs, ground, cfg, timer)
    runs = seg.labels.shape[0]
    qe = te = torch.full((runs,), float("nan"))
    if metrics and seg.som is not None:
        with timer("errors"):
            qe, te = seg.som.quantization_error(train.x), seg.som.topographic_error(train.x)
    elif metrics and seg.prototypes is not None:
        from .core.metrics import quantization_error
        with timer("errors"):
            qe = quantization_error(train.x, seg.prototypes)
    return PipelineResult(feats, train, seg.som, seg.labels, seg.ref_disparity, members, timer.t, qe, te, ground,
                          cfg.method, seg.prototypes, seg, cfg, window)
