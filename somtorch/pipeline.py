"""The paper's pipeline (Fig. 6) as one function: features → SOM → segments → object areas → reduction.

``run_pipeline(scene, PipelineConfig())`` trains ``ensemble`` maps at once (one per seed) and
returns, per member, the label map, all object areas, the kept ones, the reduced map and, when the
scene has an object mask, the score. Point clouds and files are produced by the callers
(``experiments/run.py``), so this module stays free of I/O.

``method`` swaps the segmenter of step 1b while every other step stays the same, so baselines are
scored exactly like the SOM:

* ``"som"`` — our SOM (``som``/``train`` groups), E members trained as one tensor op;
* ``"minisom"`` — the MiniSom library the paper cites, one map per seed (online rule only);
* ``"kmeans"`` — Lloyd's k-means on the same features with K = rows·cols, batched over seeds;
* ``"slic"`` / ``"felzenszwalb"`` — scikit-image superpixels of the disparity image (deterministic:
  one run whatever ``ensemble`` says).

Methods without a SOM grid (k-means, superpixels) link segments through the image only
(``objects.link="grid"`` acts as ``"image"`` for them).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from collections.abc import Callable
from typing import Any

import torch

from .core import SOM, StepInfo
from .disparity.features import Features, make_features
from .disparity.filters import remove_speckles
from .disparity.scene import Scene
from .tasks.ground import GroundConfig, GroundPlane, fit_ground_plane
from .tasks.objects import AreaConfig, NeuronStats, ObjectArea, disparity_spread, find_object_areas, neuron_stats
from .tasks.refine import kept_areas, map_solidity
from .tasks.reduction import Reduction, reduce_map, valid_integral
from .tasks.scoring import Score, optimal_reduction, score_reduction
from .tasks.segmentation import segment
from .core.decay import DECAYS
from .core.grid import TOPOLOGIES
from .core.init import INITS
from .core.neighborhood import NEIGHBORHOODS
from .core.som import MODES, ORDERS
from .disparity.features import NORMALIZATIONS
from .validation import check_choice, check_positive, check_positive_int

METHODS = ("som", "minisom", "kmeans", "slic", "felzenszwalb")
DETERMINISTIC_METHODS = ("slic", "felzenszwalb")


@dataclass
class FeatureConfig:
    """Input data set (paper step 1a); see :mod:`somtorch.disparity.features`.

    ``train_stride`` 1 = NOR (train on every valid pixel), 10 = OR (the paper's runtime-optimised
    mode); the full map is always segmented.
    """

    normalize: str = "image"
    d_weight: float = 2.0
    train_stride: int = 10
    speckle_frac: float = 0.0  # remove_speckles max_size_frac (0 = off; for computed SGBM maps)

    def __post_init__(self) -> None:
        check_choice("features.normalize", self.normalize, NORMALIZATIONS)
        check_positive("features.d_weight", self.d_weight)
        check_positive_int("features.train_stride", self.train_stride)
        check_positive("features.speckle_frac", self.speckle_frac, allow_zero=True)


@dataclass
class SOMConfig:
    rows: int = 8
    cols: int = 8
    topology: str = "rectangular"
    toroidal: bool = False
    init: str = "random"

    def __post_init__(self) -> None:
        check_positive_int("som.rows", self.rows)
        check_positive_int("som.cols", self.cols)
        check_choice("som.topology", self.topology, TOPOLOGIES)
        check_choice("som.init", self.init, INITS)


@dataclass
class TrainConfig:
    """SOM training (paper step 1 b); arguments of :meth:`somtorch.SOM.fit`."""

    mode: str = "batch"
    epochs: int = 10
    lr: float = 0.5
    sigma: float | None = None
    lr_decay: str = "asymptotic"
    sigma_decay: str = "asymptotic"
    neighborhood: str = "gaussian"
    order: str = "random"
    batch_size: int = 256

    def __post_init__(self) -> None:
        check_choice("train.mode", self.mode, MODES)
        check_positive_int("train.epochs", self.epochs)
        check_positive("train.lr", self.lr)
        if self.sigma is not None:
            check_positive("train.sigma", self.sigma)
        check_choice("train.lr_decay", self.lr_decay, DECAYS)
        check_choice("train.sigma_decay", self.sigma_decay, DECAYS)
        check_choice("train.neighborhood", self.neighborhood, NEIGHBORHOODS)
        check_choice("train.order", self.order, ORDERS)
        check_positive_int("train.batch_size", self.batch_size)


@dataclass
class ReductionConfig:
    """Tolerance margin around each kept box (paper Fig. 16); see :func:`~somtorch.tasks.reduction.reduce_map`.

    The default (robust preset) is 2 % of the image diagonal on every side; ``conf/reduction/paper.yaml``
    holds the paper-faithful 5 % of the box side. Measured (100 runs, OR, robust areas): with 5 % of
    the box side a perfectly found Motorcycle (box = 69 % of the image) is never a useful hit
    (reduction 15 % < 0.75 · x_opt = 23.6 %). Together with the box refinement of
    :class:`~somtorch.tasks.objects.AreaConfig` (quantile edges), 2 % of the diagonal raised useful
    hits from 54 to 87 there and from 59 to 85 on FlyingThings3D, KITTI (91) and ETH3D (93)
    unchanged; without a margin KITTI's car loses its last pixels (49), with 1 % the toy (README,
    "What moved the numbers").
    """

    tolerance_px: float = 0.0
    tolerance_frac: float = 0.0
    tolerance_image: float = 0.02

    def __post_init__(self) -> None:
        check_positive("reduction.tolerance_px", self.tolerance_px, allow_zero=True)
        check_positive("reduction.tolerance_frac", self.tolerance_frac, allow_zero=True)
        check_positive("reduction.tolerance_image", self.tolerance_image, allow_zero=True)


@dataclass
class BaselineConfig:
    """Parameters of the baseline segmenters (``method`` other than ``"som"``).

    ``n_segments`` (SLIC) defaults to the SOM's K = rows·cols so that every method splits the map
    into about as many segments; k-means always uses K centres. Felzenszwalb has no segment count:
    ``fz_scale`` 1000 and ``fz_min_size`` 200 px give 55–260 segments on the shared scenes (its
    scikit-image defaults give 200–700). SLIC's ``slic_compactness`` 0.03 suits a [0, 1] disparity
    image: at 0.1 the borders follow fewer depth edges, below 0.01 the ground breaks into bands.
    """

    kmeans_iterations: int = 20
    kmeans_init: str = "kmeans++"
    n_segments: int | None = None
    slic_compactness: float = 0.03
    fz_scale: float = 1000.0
    fz_sigma: float = 0.5
    fz_min_size: int = 200

    def __post_init__(self) -> None:
        check_positive_int("baseline.kmeans_iterations", self.kmeans_iterations)
        check_choice("baseline.kmeans_init", self.kmeans_init, ("kmeans++", "sample"))
        if self.n_segments is not None:
            check_positive_int("baseline.n_segments", self.n_segments)
        check_positive("baseline.slic_compactness", self.slic_compactness)
        check_positive("baseline.fz_scale", self.fz_scale)
        check_positive("baseline.fz_sigma", self.fz_sigma, allow_zero=True)
        check_positive_int("baseline.fz_min_size", self.fz_min_size)


@dataclass
class PipelineConfig:
    method: str = "som"
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    som: SOMConfig = field(default_factory=SOMConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    ground: GroundConfig = field(default_factory=GroundConfig)
    objects: AreaConfig = field(default_factory=AreaConfig)
    reduction: ReductionConfig = field(default_factory=ReductionConfig)
    ensemble: int = 1
    seed: int = 0
    object_id: int | None = None  # scored object; None = the scene's main object(s)

    def __post_init__(self) -> None:
        check_choice("method", self.method, METHODS)
        check_positive_int("ensemble", self.ensemble)

    @property
    def runs(self) -> int:
        """Members actually computed: ``ensemble``, or 1 for a deterministic method."""
        return 1 if self.method in DETERMINISTIC_METHODS else self.ensemble

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class MemberResult:
    """Results of one ensemble member."""

    seed: int
    areas: list[ObjectArea]
    kept: list[ObjectArea]
    reduction: Reduction
    score: Score | None
    stats: NeuronStats


@dataclass
class PipelineResult:
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

    @property
    def num_segments(self) -> int:
        return int(self.ref_disparity.shape[-1])


def _tic() -> float:
    return time.perf_counter()


def run_pipeline(scene: Scene, cfg: PipelineConfig | None = None, *, progress: bool = False,
                 metrics: bool = True,
                 log_training: Callable[[str, float, int], Any] | None = None) -> PipelineResult:
    """Run steps 1a–1d on ``scene`` (see the module docstring). Timings are in seconds per stage.

    Args:
        progress: show a progress bar while training.
        metrics: compute quantization and topographic error of the trained maps.
        log_training: called as ``log_training(tag, value, epoch)`` once per epoch with the mean
            quantization / topographic error of the members (e.g. ``SummaryWriter.add_scalar``);
            it runs inside ``fit``, so its cost is included in the ``train`` timing.
    """
    cfg = cfg or PipelineConfig()
    check_positive_int("ensemble", cfg.ensemble)
    t: dict[str, float] = {}
    t0 = _tic()
    valid = remove_speckles(scene.disparity, scene.valid, max_size_frac=cfg.features.speckle_frac)
    t["clean"] = _tic() - t0
    t0 = _tic()
    ground = fit_ground_plane(scene.disparity, valid, cfg.ground)
    t["ground"] = _tic() - t0
    t0 = _tic()
    usable = valid if ground is None else valid & ~ground.mask
    feats = make_features(scene.disparity, usable, normalize=cfg.features.normalize,
                          d_weight=cfg.features.d_weight)
    train = feats.subsample(cfg.features.train_stride)
    if len(train) == 0:
        raise ValueError(f"features.train_stride={cfg.features.train_stride} leaves no valid pixel of "
                         f"scene {scene.name!r} to train on; use a smaller stride")
    t["features"] = _tic() - t0

    t0 = _tic()
    som, weight, grid_d2, labels = None, None, None, None
    s, tc, runs = cfg.som, cfg.train, cfg.runs
    if cfg.method == "som":
        som = SOM(s.rows, s.cols, 3, ensemble=runs, topology=s.topology, toroidal=s.toroidal, seed=cfg.seed)
        callback = None
        if log_training is not None:
            def callback(info: StepInfo) -> None:
                log_training("train/quantization_error", float(som.quantization_error(train.x).mean()),
                             round(info.epoch))
                log_training("train/topographic_error", float(som.topographic_error(train.x).mean()),
                             round(info.epoch))
                log_training("train/sigma", float(info.sigma.mean()), round(info.epoch))
        som.fit(train.x, mode=tc.mode, epochs=tc.epochs, lr=tc.lr, sigma=tc.sigma, lr_decay=tc.lr_decay,
                sigma_decay=tc.sigma_decay, neighborhood=tc.neighborhood, order=tc.order,
                batch_size=tc.batch_size, init=s.init, progress=progress, callback=callback)
    elif cfg.method == "minisom":
        from .baselines.minisom_som import train_minisom

        if tc.mode != "online":
            raise ValueError(f"method='minisom' trains with MiniSom's online rule; got train.mode={tc.mode!r} "
                             "(use train=online)")
        som = SOM(s.rows, s.cols, 3, ensemble=runs, topology=s.topology, toroidal=s.toroidal, seed=cfg.seed)
        som.weight = train_minisom(train.x, s.rows, s.cols, seeds=som.seeds, epochs=tc.epochs, sigma=tc.sigma,
                                   lr=tc.lr, order=tc.order, neighborhood=tc.neighborhood,
                                   init="pca" if s.init == "pca" else "sample").to(som.weight)
    elif cfg.method == "kmeans":
        from .baselines.kmeans import kmeans

        weight = kmeans(train.x, s.rows * s.cols, ensemble=runs, seed=cfg.seed,
                        iterations=cfg.baseline.kmeans_iterations, init=cfg.baseline.kmeans_init).centers
    else:
        from .baselines.superpixels import superpixel_labels

        b = cfg.baseline
        labels = superpixel_labels(scene.disparity, usable, method=cfg.method,
                                   n_segments=b.n_segments or s.rows * s.cols, compactness=b.slic_compactness,
                                   scale=b.fz_scale, sigma=b.fz_sigma, min_size=b.fz_min_size)[None]
    if som is not None:
        weight, grid_d2 = som.weight.detach(), som.grid_d2
    t["train"] = _tic() - t0

    t0 = _tic()
    if weight is not None:
        labels = segment(weight, feats.x, feats.pixels, feats.shape)
    t["segment"] = _tic() - t0

    stats0, t_stats0 = None, 0.0
    if weight is not None:
        ref_d = feats.to_pixel_units(weight)[..., 2]  # (E, K)
    else:  # superpixels: a segment's reference disparity is its mean disparity (from its statistics)
        t0 = _tic()
        stats0 = neuron_stats(labels[0], scene.disparity, int(labels.max()) + 1)
        ref_d = torch.nan_to_num(stats0.mean_d).float()[None]
        t_stats0 = _tic() - t0  # counted as object-area time, where the statistics are used
    num_k = int(ref_d.shape[-1])
    seeds = som.seeds if som is not None else [cfg.seed + e for e in range(runs)]
    obj_mask, x_opt = None, None
    if scene.objects is not None:
        obj_mask = scene.object_mask(cfg.object_id) if cfg.object_id is not None else scene.main_object_mask
        x_opt = optimal_reduction(obj_mask, scene.valid)  # the same for every member
    members, t_obj, t_red = [], t_stats0, 0.0
    oc = cfg.objects
    residual = None
    t0 = _tic()
    h, w = scene.disparity.shape
    if ground is not None and oc.ground_clutter > 0 and not oc.grow:
        residual = (scene.disparity - ground.disparity(h, w)).abs()
    valid_ii = valid_integral(scene.valid)
    seg_solidity = map_solidity(labels[0], oc)  # every member segments the same pixels
    t_obj += _tic() - t0
    if stats0 is None:  # every member segments the same pixels: their disparity spread is computed once
        t0 = _tic()
        spread = disparity_spread(scene.disparity, labels[0] >= 0)
        t_obj += _tic() - t0
    for e in range(runs):
        t0 = _tic()
        stats = stats0 if stats0 is not None else neuron_stats(labels[e], scene.disparity, num_k, spread=spread)
        areas = find_object_areas(ref_d[e], grid_d2, stats, oc)
        kept = kept_areas(areas, stats, labels[e], oc, valid_integral=valid_ii, ground_residual=residual,
                          clutter_band=oc.ground_clutter * ground.tol if ground is not None else 0.0,
                          disparity=scene.disparity, usable=usable, segmented_solidity=seg_solidity)
        t1 = _tic()
        red = reduce_map([a.box for a in kept], scene.valid, tolerance_px=cfg.reduction.tolerance_px,
                         tolerance_frac=cfg.reduction.tolerance_frac, tolerance_image=cfg.reduction.tolerance_image,
                         integral=valid_ii)
        t_red += _tic() - t1
        t_obj += t1 - t0
        score = score_reduction(red, obj_mask, scene.valid, x_opt=x_opt) if obj_mask is not None else None
        members.append(MemberResult(seeds[e], areas, kept, red, score, stats))
    t["objects"] = t_obj
    t["reduction"] = t_red
    qe = te = torch.full((runs,), float("nan"))
    if metrics and som is not None:
        qe, te = som.quantization_error(train.x), som.topographic_error(train.x)
    elif metrics and weight is not None:
        from .core.metrics import quantization_error
        qe = quantization_error(train.x, weight)
    return PipelineResult(feats, train, som, labels, ref_d, members, t, qe, te, ground, cfg.method, weight)
