"""Configuration of paper steps 1a–1b: the input features, the SOM, its training, the baseline
segmenters (see :mod:`somtorch.config`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from . import options
from .constraints import BOOL, NON_NEGATIVE, POSITIVE, POSITIVE_INT, Choice, Interval, OneOf, Validated


# ----------------------------------------------------------------------------------- step 1a: input
@dataclass
class FeatureConfig(Validated):
    """Input data set (paper step 1a): each valid pixel → (y, x, d), see :mod:`somtorch.disparity.features`.

    Attributes:
        normalize: ``"image"`` (y, x scaled by the longer image side, d by the same factor after
            ``d_weight``), ``"minmax"`` (each feature to [0, 1], the paper's reading) or ``"none"``.
        d_weight: weight of the disparity feature (2 = disparity counts twice as much as position).
        d_mode: the disparity feature: ``"raw"`` (d) or ``"plane_residual"`` (d − the verified ground
            plane's disparity at the pixel, clipped at 0: the height of what protrudes from the support
            surface, in disparity px; the object step then reads it too). Without a verified plane the
            feature is d.
        train_stride: 1 = NOR (train on every valid pixel), 10 = OR (every 10th pixel in y and x,
            the paper's runtime-optimised mode); the whole map is always segmented.
        color_weight: append the left image's Y, Cb, Cr (each in [0, 1]) times this weight to
            every pixel vector (0 = off; needs the scene's image).
        reference_pixels: the pipeline's strides (``train_stride``, ``objects.map_stride``) are
            counted on an image of this many pixels (640 × 480) and scale with √(pixels /
            reference_pixels) on larger and smaller images, see :meth:`stride_at`; 0 = strides in
            pixels as given (the paper's reading).
        median: a map whose per-pixel noise sets the ground band (``ground.noise_band`` × σ >
            ``ground.tol_px``, σ its :func:`~somtorch.tasks.ground.noise_sigma`: a dense sensor's
            noise) is read through a median of the valid disparities in this window (odd,
            :func:`~somtorch.disparity.filters.median_filter`) by every step, ground plane included —
            or in a wider one where the noise the median leaves would still set the band
            (:func:`~somtorch.pipeline.denoised`: 5 × 5 for σ = 0.8 px, 7 × 7 for 1.1 px); 0 = never
            (the paper's reading). σ ≤ 0.14 px on every stereo and GT map of the corpus:
            none of them is filtered (``docs/tuned_constants.md``). The outputs keep the map as given.
            A map with less noise than the trigger (0.14–0.25 px: it would gain too) can be passed
            through :func:`~somtorch.disparity.filters.median_filter` before the pipeline.
    """

    _group: ClassVar[str] = "features"
    _constraints: ClassVar[dict[str, Any]] = {
        "normalize": Choice(options.NORMALIZATIONS),
        "d_weight": POSITIVE, "d_mode": Choice(options.D_MODES),
        "color_weight": NON_NEGATIVE, "train_stride": POSITIVE_INT,
        "reference_pixels": Interval(0, None, integer=True), "median": Interval(0, None, integer=True),
    }
    _relations: ClassVar[list[tuple[Any, str]]] = [
        (lambda c: c.median == 0 or c.median % 2 == 1,
         "median={c.median} must be 0 (never) or an odd window"),
    ]

    normalize: str = "image"
    d_weight: float = 2.0
    d_mode: str = "raw"
    color_weight: float = 0.0
    train_stride: int = 10
    reference_pixels: int = 307_200
    median: int = 3

    def stride_at(self, stride: int, height: int, width: int) -> int:
        """``stride`` (counted on ``reference_pixels``) on a ``height × width`` image: times
        √(height · width / reference_pixels), rounded, at least 1 — on a larger image and on a
        smaller one alike, so that a scene trains on as many pixels and its object step reads as
        many at any resolution (session 27; until then a smaller image kept the strides as given,
        and at a quarter of the resolution the object step read a sixteenth of the pixels). A
        stride of 1 stays 1.

        >>> f = FeatureConfig()
        >>> f.stride_at(10, 960, 1280), f.stride_at(10, 240, 320), f.stride_at(2, 240, 320)
        (20, 5, 1)
        >>> f.stride_at(1, 960, 1280)
        1
        """
        scale = 1.0 if self.reference_pixels == 0 else (height * width / self.reference_pixels) ** 0.5
        return 1 if stride == 1 else max(1, int(stride * scale + 0.5))


# ------------------------------------------------------------------------------------ step 1b: SOM
@dataclass
class SOMConfig(Validated):
    """The map: ``rows × cols`` neurons on a rectangular or hexagonal grid.

    Attributes:
        rows, cols: grid size (one neuron = one segment; ``som=grid4x7`` is the paper's).
        topology: ``"rectangular"`` or ``"hexagonal"`` neighbours.
        toroidal: the grid wraps around at its edges.
        init: initial weights (:data:`somtorch.config.options.INITS`).
    """

    _group: ClassVar[str] = "som"
    _constraints: ClassVar[dict[str, Any]] = {
        "rows": POSITIVE_INT, "cols": POSITIVE_INT, "topology": Choice(options.TOPOLOGIES),
        "toroidal": BOOL, "init": Choice(options.INITS),
    }

    rows: int = 8
    cols: int = 8
    topology: str = "rectangular"
    toroidal: bool = False
    init: str = "random"


@dataclass
class TrainConfig(Validated):
    """SOM training (paper step 1b); the defaults of :meth:`somtorch.core.som.SOM.fit`.

    Attributes:
        mode: ``"batch"`` (batch map), ``"minibatch"`` or ``"online"`` (Kohonen's rule, the paper's).
        epochs: passes over the training pixels.
        lr: initial learning rate α0 (online / minibatch).
        sigma: initial neighbourhood radius σ0 in grid units; None = ``max(rows, cols) / 2``.
        lr_decay, sigma_decay: decay schedules (:data:`somtorch.core.decay.DECAYS`).
        neighborhood: neighbourhood function (:data:`somtorch.core.neighborhood.NEIGHBORHOODS`).
        order: ``"random"`` or ``"sequential"`` sample order.
        batch_size: samples per step of the minibatch rule.
        parallel: ``"none"``; ``"data"`` (data-parallel batch map on ``torch.distributed``: each rank
            trains on its shard of the pixels, statistics all-reduced per epoch; batch mode only) or
            ``"members"`` (ensemble members dealt to the ranks and gathered). Needs a process group
            (``torchrun ... -m experiments.distributed``, ``docs/scaling.md``).
    """

    _group: ClassVar[str] = "train"
    _constraints: ClassVar[dict[str, Any]] = {
        "mode": Choice(options.MODES), "epochs": POSITIVE_INT, "lr": POSITIVE,
        "sigma": Interval(0, None, open_lo=True, optional=True),
        "lr_decay": Choice(options.DECAYS), "sigma_decay": Choice(options.DECAYS),
        "neighborhood": Choice(options.NEIGHBORHOODS), "order": Choice(options.ORDERS),
        "batch_size": POSITIVE_INT, "parallel": OneOf(("none", "data", "members")),
    }
    _relations: ClassVar[list[tuple[Any, str]]] = [
        (lambda c: c.parallel != "data" or c.mode == "batch",
         "parallel='data' trains the batch map; got mode={c.mode!r} (use parallel='members' for it)"),
    ]

    mode: str = "batch"
    epochs: int = 10
    lr: float = 0.5
    sigma: float | None = None
    lr_decay: str = "asymptotic"
    sigma_decay: str = "asymptotic"
    neighborhood: str = "gaussian"
    order: str = "random"
    batch_size: int = 256
    parallel: str = "none"


@dataclass
class BaselineConfig(Validated):
    """Parameters of the baseline segmenters (``method`` other than ``"som"``).

    ``n_segments`` (SLIC) None = the SOM's K = rows·cols, so every method splits the map into about
    as many segments; k-means always uses K centres. ``fz_*``: Felzenszwalb's scale, smoothing and
    minimum segment size in px; ``slic_compactness`` suits a [0, 1] disparity image.

    Attributes:
        kmeans_iterations: Lloyd iterations of method=kmeans.
        kmeans_init: "kmeans++" or "sample" (K random pixels).
        n_segments: SLIC's segment count (None = the SOM's K = rows x cols).
        slic_compactness: SLIC's colour/space trade-off, for a [0, 1] disparity image.
        fz_scale: Felzenszwalb's scale (larger = larger segments).
        fz_sigma: Felzenszwalb's Gaussian smoothing before segmenting.
        fz_min_size: Felzenszwalb's minimum segment size in px.
    """

    _group: ClassVar[str] = "baseline"
    _constraints: ClassVar[dict[str, Any]] = {
        "kmeans_iterations": POSITIVE_INT, "kmeans_init": OneOf(("kmeans++", "sample")),
        "n_segments": Interval(1, None, integer=True, optional=True), "slic_compactness": POSITIVE,
        "fz_scale": POSITIVE, "fz_sigma": NON_NEGATIVE, "fz_min_size": POSITIVE_INT,
    }

    kmeans_iterations: int = 20
    kmeans_init: str = "kmeans++"
    n_segments: int | None = None
    slic_compactness: float = 0.03
    fz_scale: float = 1000.0
    fz_sigma: float = 0.5
    fz_min_size: int = 200
