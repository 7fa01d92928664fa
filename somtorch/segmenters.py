"""Paper step 1b as a registry of segmenters: each turns the pixel features into one :class:`Segmentation`.

Every segmenter registers under its name (``register``) and is scored by the same object step,
reduction and scoring, so baselines compare like for like:

* ``"som"`` — our SOM (``som`` / ``train`` groups), E members trained as one tensor op;
* ``"minisom"`` — the MiniSom library the paper cites, one map per seed (online rule only);
* ``"kmeans"`` — Lloyd's k-means on the same features with K = rows·cols, batched over seeds;
* ``"slic"`` / ``"felzenszwalb"`` — scikit-image superpixels of the disparity image (deterministic:
  one run whatever ``ensemble`` says).

Segmenters without a grid (k-means, superpixels) refuse ``objects.rule="paper"`` (the paper links
neurons adjacent on the SOM grid): linking through a grid they do not have would silently mean
something else.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any

import torch

from .config import PipelineConfig
from .config.options import register_method
from .core import SOM, StepInfo
from .disparity.features import Features
from .tasks.segmentation import segment

__all__ = ["METHODS", "SEGMENTERS", "Segmentation", "Segmenter", "register", "run_segmenter"]


@dataclass
class Segmentation:
    """What step 1b hands to the object step.

    Attributes:
        labels: segment of every pixel, −1 where not segmented (invalid or ground) ``(E, H, W)``.
        ref_disparity: reference disparity of each segment in px ``(E, K)``.
        grid_d2: squared SOM-grid distances ``(K, K)``, or None for segmenters without a grid.
        prototypes: feature-space centres ``(E, K, D)`` (SOM weights, k-means centres) or None.
        som: the trained maps (``"som"`` / ``"minisom"``) or None.
        seeds: the seed of each member.
    """

    labels: torch.Tensor
    ref_disparity: torch.Tensor
    grid_d2: torch.Tensor | None
    prototypes: torch.Tensor | None
    som: SOM | None
    seeds: list[int]

    @property
    def num_segments(self) -> int:
        """Segments per member ``K``."""
        return int(self.ref_disparity.shape[-1])


@dataclass(frozen=True)
class Segmenter:
    """A registered segmenter: ``fn(feats, train, scene, usable, cfg, runs, progress, callback)``."""

    name: str
    fn: Callable[..., Segmentation]
    deterministic: bool = False
    has_grid: bool = False


SEGMENTERS: dict[str, Segmenter] = {}


def register(name: str, *, deterministic: bool = False, has_grid: bool = False) -> Callable:
    """Decorator: register ``fn`` as the segmenter ``name`` (and ``name`` as a valid ``method``)."""
    def deco(fn: Callable[..., Segmentation]) -> Callable[..., Segmentation]:
        register_method(name, deterministic)
        SEGMENTERS[name] = Segmenter(name, fn, deterministic, has_grid)
        return fn
    return deco


def _from_prototypes(weight: torch.Tensor, feats: Features, grid_d2: torch.Tensor | None, som: SOM | None,
                     seeds: list[int]) -> Segmentation:
    """A segmentation whose pixels are labelled later (by :func:`run_segmenter`, timed apart)."""
    units = feats.to_pixel_units(weight)  # (E, K, D): y px, x px, d px[, Y, Cb, Cr]
    return Segmentation(None, units[..., 2], grid_d2, weight, som, seeds)  # type: ignore[arg-type]


def _new_som(cfg: PipelineConfig, runs: int, dim: int, device: str = "cpu") -> SOM:
    return SOM.from_config(cfg.som, dim, ensemble=runs, seed=cfg.seed, device=device)


def resolve_device(name: str) -> torch.device:
    """``PipelineConfig.device`` as a :class:`torch.device`, checked to exist on this machine."""
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError) as e:
        raise ValueError(f"device={name!r} is not a torch device ({e}); use 'cpu', 'cuda', 'cuda:1' or 'mps'") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device={name!r} but torch.cuda.is_available() is False on this machine (CPU build of "
                         "torch, or no GPU): use device=cpu")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ValueError(f"device={name!r} but this machine has {torch.cuda.device_count()} CUDA device(s)")
    if dev.type == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
        raise ValueError(f"device={name!r} but MPS is not available here: use device=cpu")
    return dev


@register("som", has_grid=True)
def _som(feats: Features, train: Features, scene: Any, usable: torch.Tensor, cfg: PipelineConfig, runs: int,
         progress: bool, log_training: Callable[[str, float, int], Any] | None) -> Segmentation:
    dev = resolve_device(cfg.device)
    som, tc = _new_som(cfg, runs, train.x.shape[-1], str(dev)), cfg.train
    x = train.x.to(dev)
    callback = None
    if log_training is not None:
        def callback(info: StepInfo) -> None:
            step = round(info.epoch)
            log_training("train/quantization_error", float(som.quantization_error(x).mean()), step)
            log_training("train/topographic_error", float(som.topographic_error(x).mean()), step)
            log_training("train/sigma", float(info.sigma.mean()), step)
            log_training("train/bmu_skipped", info.skipped, step)
    if tc.parallel != "none":
        som = _fit_parallel(som, train, cfg)
    else:
        som.fit(x, mode=tc.mode, epochs=tc.epochs, lr=tc.lr, sigma=tc.sigma, lr_decay=tc.lr_decay,
                sigma_decay=tc.sigma_decay, neighborhood=tc.neighborhood, order=tc.order,
                batch_size=tc.batch_size, init=cfg.som.init, progress=progress, callback=callback)
    return _from_prototypes(som.weight.detach(), feats, som.grid_d2, som, som.seeds)


def _fit_parallel(som: SOM, train: Features, cfg: PipelineConfig) -> SOM:
    """``train.parallel``: the same map trained across the ranks of the process group."""
    from somtorch.core.distributed import fit_data_parallel, fit_members_parallel, shard_range

    import torch.distributed as dist

    tc = cfg.train
    if not (dist.is_available() and dist.is_initialized()):
        raise ValueError(f"train.parallel={tc.parallel!r} needs a torch.distributed process group: launch with "
                         "torchrun ... -m experiments.distributed (docs/scaling.md)")
    if tc.parallel == "data":
        som.initialize(train.x, cfg.som.init)  # every rank holds all features: start as one process would
        start, stop = shard_range(len(train), dist.get_rank(), dist.get_world_size())
        return fit_data_parallel(som, train.x[start:stop], epochs=tc.epochs, init=cfg.som.init, sigma=tc.sigma,
                                 sigma_decay=tc.sigma_decay, neighborhood=tc.neighborhood)
    return fit_members_parallel(
        cfg.som.rows, cfg.som.cols, train.x, ensemble=som.ensemble, seed=som.seeds[0],
        fit_kwargs={"mode": tc.mode, "epochs": tc.epochs, "lr": tc.lr, "sigma": tc.sigma, "lr_decay": tc.lr_decay,
                    "sigma_decay": tc.sigma_decay, "neighborhood": tc.neighborhood, "order": tc.order,
                    "batch_size": tc.batch_size, "init": cfg.som.init},
        som_kwargs={"topology": cfg.som.topology, "toroidal": cfg.som.toroidal})


@register("minisom", has_grid=True)
def _minisom(feats: Features, train: Features, scene: Any, usable: torch.Tensor, cfg: PipelineConfig, runs: int,
             progress: bool, log_training: Any) -> Segmentation:
    from .baselines.minisom_som import train_minisom

    tc, s = cfg.train, cfg.som
    if tc.mode != "online":
        raise ValueError(f"method='minisom' trains with MiniSom's online rule; got train.mode={tc.mode!r} "
                         "(use train=online)")
    som = _new_som(cfg, runs, train.x.shape[-1])
    som.weight = train_minisom(train.x, s.rows, s.cols, seeds=som.seeds, epochs=tc.epochs, sigma=tc.sigma,
                               lr=tc.lr, order=tc.order, neighborhood=tc.neighborhood,
                               init="pca" if s.init == "pca" else "sample").to(som.weight)
    return _from_prototypes(som.weight.detach(), feats, som.grid_d2, som, som.seeds)


@register("kmeans")
def _kmeans(feats: Features, train: Features, scene: Any, usable: torch.Tensor, cfg: PipelineConfig, runs: int,
            progress: bool, log_training: Any) -> Segmentation:
    from .baselines.kmeans import kmeans

    centers = kmeans(train.x, cfg.som.rows * cfg.som.cols, ensemble=runs, seed=cfg.seed,
                     iterations=cfg.baseline.kmeans_iterations, init=cfg.baseline.kmeans_init).centers
    return _from_prototypes(centers, feats, None, None, [cfg.seed + e for e in range(runs)])


def _superpixels(method: str) -> Callable[..., Segmentation]:
    def fn(feats: Features, train: Features, scene: Any, usable: torch.Tensor, cfg: PipelineConfig, runs: int,
           progress: bool, log_training: Any) -> Segmentation:
        from .baselines.superpixels import superpixel_labels
        from .tasks.objects import neuron_stats

        b = cfg.baseline
        labels = superpixel_labels(scene.disparity, usable, method=method,
                                   n_segments=b.n_segments or cfg.som.rows * cfg.som.cols,
                                   compactness=b.slic_compactness, scale=b.fz_scale, sigma=b.fz_sigma,
                                   min_size=b.fz_min_size)[None]
        # a segment's reference disparity is its mean disparity
        stats = neuron_stats(labels[0], scene.disparity, int(labels.max()) + 1)
        ref_d = torch.nan_to_num(stats.mean_d).float()[None]
        return Segmentation(labels, ref_d, None, None, None, [cfg.seed])
    return fn


for _name in ("slic", "felzenszwalb"):
    register(_name, deterministic=True)(_superpixels(_name))

METHODS = tuple(SEGMENTERS)


def run_segmenter(feats: Features, train: Features, scene: Any, usable: torch.Tensor, cfg: PipelineConfig, *,
                  progress: bool = False, log_training: Callable[[str, float, int], Any] | None = None,
                  timer: Callable[[str], Any] = lambda stage: nullcontext()) -> Segmentation:
    """Run the segmenter ``cfg.method`` (checks first that it can honour ``cfg.objects.rule``).

    ``timer(stage)``: a context manager timing the stages ``"train"`` and ``"segment"`` (the BMU
    labelling of every pixel, for segmenters with prototypes).
    """
    seg = SEGMENTERS[cfg.method]
    if not seg.has_grid and cfg.objects.rule == "paper":
        raise ValueError(f"method={cfg.method!r} has no SOM grid, so objects.rule=paper (neurons adjacent on "
                         "the grid) cannot be honoured; use objects.rule=salient")
    with timer("train"):
        out = seg.fn(feats, train, scene, usable, cfg, cfg.runs, progress, log_training)
    with timer("segment"):
        if out.labels is None:
            dev = out.prototypes.device  # label where the map was trained (a GPU for device=cuda)
            out.labels = segment(out.prototypes, feats.x.to(dev), feats.pixels.to(dev), feats.shape)  # (E, H, W)
        if out.labels.device.type != "cpu":  # the object step and the outputs work on the CPU
            out.labels, out.ref_disparity = out.labels.cpu(), out.ref_disparity.cpu()
            out.prototypes = out.prototypes.cpu() if out.prototypes is not None else None
            out.grid_d2 = out.grid_d2.cpu() if out.grid_d2 is not None else None
            if out.som is not None:
                out.som.to("cpu")
    return out
