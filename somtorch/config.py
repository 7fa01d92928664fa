"""Every configuration of somtorch, declared once.

These dataclasses are the single home of every default: the library reads its defaults from them,
the Hydra schemas *are* them (``experiments/schema.py`` registers them), and ``conf/`` states only
what a preset changes. So ``run_pipeline(scene)`` does exactly what ``somtorch-run`` does with no
overrides.

Validation is declarative: each class lists its ``_constraints`` (field → rule) and, where fields
depend on each other, ``_relations``; :class:`Validated` checks both after ``__init__``, with
messages that name the field (``objects.min_purity must be in [0, 1]; got 2``). Option names are
checked against the registry that implements them, looked up lazily so that this module imports
nothing of somtorch but the error helpers (every layer may import it).

The list of tuned constants of the object step, their values and how each was chosen, is in
``docs/tuned_constants.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

from .constraints import (BOOL, FRACTION, NON_NEGATIVE, POSITIVE, POSITIVE_INT, Choice, Flag, Interval, OneOf,
                          Validated)

__all__ = [
    "AreaConfig", "BaselineConfig", "Choice", "FeatureConfig", "Flag", "GroundConfig", "Interval", "OneOf",
    "OutputConfig", "PipelineConfig", "ReductionConfig", "SOMConfig", "TrainConfig", "Validated", "with_overrides",
]


_SOM = "somtorch.core.som"


# ----------------------------------------------------------------------------------- step 1a: input
@dataclass
class FeatureConfig(Validated):
    """Input data set (paper step 1a): each valid pixel → (y, x, d), see :mod:`somtorch.disparity.features`.

    Attributes:
        normalize: ``"image"`` (y, x scaled by the longer image side, d by the same factor after
            ``d_weight``), ``"minmax"`` (each feature to [0, 1], the paper's reading) or ``"none"``.
        d_weight: weight of the disparity feature (2 = disparity counts twice as much as position).
        train_stride: 1 = NOR (train on every valid pixel), 10 = OR (every 10th pixel in y and x,
            the paper's runtime-optimised mode); the whole map is always segmented.
        color_weight: append the left image's Y, Cb, Cr (each in [0, 1]) times this weight to
            every pixel vector (0 = off; needs the scene's image).
        speckle_frac: remove image-connected speckles of similar disparity smaller than this share
            of the pixels before anything else (OpenCV ``filterSpeckles``; 0 = off).
        reference_pixels: the pipeline's strides (``train_stride``, ``objects.map_stride``,
            ``objects.grow_stride``) are counted on an image of this many pixels (640 × 480), see
            :meth:`stride_at`; 0 = strides in pixels as given (the paper's reading).
    """

    _group: ClassVar[str] = "features"
    _constraints: ClassVar[dict[str, Any]] = {
        "normalize": Choice("somtorch.disparity.features:NORMALIZATIONS"),
        "d_weight": POSITIVE, "color_weight": NON_NEGATIVE, "train_stride": POSITIVE_INT,
        "speckle_frac": Interval(0, 1), "reference_pixels": Interval(0, None, integer=True),
    }

    normalize: str = "image"
    d_weight: float = 2.0
    color_weight: float = 0.0
    train_stride: int = 10
    speckle_frac: float = 0.0
    reference_pixels: int = 307_200

    def stride_at(self, stride: int, height: int, width: int) -> int:
        """``stride`` (counted on ``reference_pixels``) on a ``height × width`` image: times
        √(height · width / reference_pixels) when that is > 1, rounded; a smaller image keeps it,
        a stride of 1 stays 1.

        >>> f = FeatureConfig()
        >>> f.stride_at(10, 960, 1280), f.stride_at(2, 240, 320), f.stride_at(1, 960, 1280)
        (20, 2, 1)
        """
        scale = 1.0 if self.reference_pixels == 0 else (height * width / self.reference_pixels) ** 0.5
        return 1 if stride == 1 else max(1, int(stride * max(scale, 1.0) + 0.5))


# ------------------------------------------------------------------------------------ step 1b: SOM
@dataclass
class SOMConfig(Validated):
    """The map: ``rows × cols`` neurons on a rectangular or hexagonal grid.

    Attributes:
        rows, cols: grid size (one neuron = one segment; ``som=grid4x7`` is the paper's).
        topology: ``"rectangular"`` or ``"hexagonal"`` neighbours.
        toroidal: the grid wraps around at its edges.
        init: initial weights (:data:`somtorch.core.init.INITS`).
    """

    _group: ClassVar[str] = "som"
    _constraints: ClassVar[dict[str, Any]] = {
        "rows": POSITIVE_INT, "cols": POSITIVE_INT, "topology": Choice("somtorch.core.grid:TOPOLOGIES"),
        "toroidal": BOOL, "init": Choice("somtorch.core.init:INITS"),
    }

    rows: int = 8
    cols: int = 8
    topology: str = "rectangular"
    toroidal: bool = False
    init: str = "random"


@dataclass
class TrainConfig(Validated):
    """SOM training (paper step 1b); the defaults of :meth:`somtorch.SOM.fit`.

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
        "mode": Choice(f"{_SOM}:MODES"), "epochs": POSITIVE_INT, "lr": POSITIVE,
        "sigma": Interval(0, None, open_lo=True, optional=True),
        "lr_decay": Choice("somtorch.core.decay:DECAYS"), "sigma_decay": Choice("somtorch.core.decay:DECAYS"),
        "neighborhood": Choice("somtorch.core.neighborhood:NEIGHBORHOODS"), "order": Choice(f"{_SOM}:ORDERS"),
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


# ---------------------------------------------------------------------------------- ground plane
@dataclass
class GroundConfig(Validated):
    """The support surface (floor, road), found by RANSAC in (x, y, d) and verified before removal.

    Attributes:
        enabled: look for a ground plane at all.
        tol_frac: inlier band half-width as a fraction of the map's disparity range (1st–99th
            percentile) …
        tol_px: … but at least this many px.
        min_inlier_frac: a plane needs this share of the valid pixels.
        min_slope_frac: ``b · H`` (disparity gained from top to bottom) must be at least this share
            of the disparity range: a floor spans it, from its horizon to the nearest thing in view;
            a seat, a bed, a table top or a slanted wall spans a part (docs/tuned_constants.md).
        max_top_frac: a plane covering more than this share of the valid pixels of the top third
            of the image is not ground (a wall or a slanted object).
        max_below_frac: a support surface hides what lies beneath it, so at most this share of the
            valid pixels where the plane is in view (plane disparity > band) may lie *behind* it
            (disparity below the band); a ramp, a lattice or a plane through the objects fails
            (1 = no check).
        slope_rows: a ground pixel must also rise down the image like the plane, measured over
            ``slope_rows ×`` the image height above and below it, so the vertical surfaces that
            cross the plane's band (an object's base, legs) stay out of the mask (0 = off).
        iterations: RANSAC hypotheses.
        sample: pixels drawn for RANSAC (and, with ``constrained``, for the tests).
        seed: RANSAC seed (the result does not depend on the SOM seed).
        constrained: the inlier, behind and top tests are RANSAC constraints (estimated on a
            sample for every hypothesis); off: only the best hypothesis is tested.
        tries: passing hypotheses tested on the full map at most, best first.
    """

    _group: ClassVar[str] = "ground"
    _constraints: ClassVar[dict[str, Any]] = {
        "enabled": BOOL, "tol_frac": NON_NEGATIVE, "tol_px": NON_NEGATIVE, "min_inlier_frac": Interval(0, 1, open_lo=True),
        "min_slope_frac": NON_NEGATIVE, "max_top_frac": FRACTION, "max_below_frac": FRACTION,
        "slope_rows": Interval(0, 0.25), "iterations": POSITIVE_INT, "sample": POSITIVE_INT, "seed": Interval(0, None, integer=True),
        "constrained": BOOL, "tries": POSITIVE_INT,
    }

    enabled: bool = True
    tol_frac: float = 0.02
    tol_px: float = 0.5
    min_inlier_frac: float = 0.08
    min_slope_frac: float = 1.0
    max_top_frac: float = 0.15
    max_below_frac: float = 0.1
    slope_rows: float = 0.0
    iterations: int = 400
    sample: int = 5000
    seed: int = 0
    constrained: bool = True
    tries: int = 5


# ------------------------------------------------------------------------------ step 1c: objects
@dataclass
class AreaConfig(Validated):
    """Object-area recognition (paper step 1c), see :mod:`somtorch.tasks.objects` and
    :mod:`somtorch.tasks.refine`.

    The defaults are the ``robust`` rule; ``conf/objects/paper.yaml`` holds the paper's literal rule
    (``link="grid"``, ``spread="range"``, ``similarity=0.1``, ``select="nearest"``, no refinement).

    Linking — which neurons form one area:
        similarity: two linked neurons are similar if their reference disparities differ by less
            than ``similarity ×`` the map's disparity spread.
        connectivity: 4 (grid rows/columns) or 8 (diagonals too) for ``link="grid"``.
        link: ``"grid"`` (adjacent on the SOM grid, the paper's rule), ``"image"`` (their segments
            share a boundary in the image) or ``"both"``.
        spread: ``"range"`` (d_max − d_min, the paper's) or ``"robust"`` (5th–95th percentile).
        min_boundary: two segments touch if their common boundary is at least this share of the
            shorter of their two perimeters.
        hierarchy: the candidates are also the nodes of the areas' merge tree (touching areas
            joined across the smallest disparity step first,
            :func:`~somtorch.tasks.objects.merge_tree`), meant with ``merge`` 0.

    Selection — which areas are kept:
        select: ``"nearest"`` (largest mean disparity, the paper's), ``"salient"`` (ranked by
            contrast to the surrounding segments × ``area_frac ** size_power``) or ``"all"``.
        size_power: weight of the area's size in the salient ranking (0 = contrast alone).
        color_rank: with colour features, an area's salience is its contrast plus
            ``color_rank ×`` the disparity spread × its colour distance to its surroundings
            (Y, Cb, Cr in [0, 1]; 0 = disparity contrast only).
        edge_rank: salience × (share of the area's border on image edges / the map's share) **
            edge_rank, at most 1: a depth boundary no image edge follows is a matching artefact
            (:func:`~somtorch.tasks.detect.image_edges`). 0 = off; no effect without an image.
        facing_rank: salience × cos θ ** facing_rank, θ the tilt of the area's disparity plane
            from the line of sight: a side wall or floor receding to its vanishing point is not an
            obstacle's face (:func:`~somtorch.tasks.objects._facing`). 0 = off.
        min_contrast: salient: minimum contrast as a share of the disparity spread.
        max_area_frac, min_area_frac: size limits as shares of the segmented pixels.
        max_areas: how many areas are kept at most.
        keep_ratio: with ``max_areas > 1``, a further area is kept only if its rank score is at
            least this share of the best one's (1 = only ties; 0 = up to ``max_areas``).
        keep_budget: a further area is kept only if the union of the kept boxes then holds at most
            this share of the valid pixels (the data-reduction budget: every salient area that
            fits is kept, one that would make the reduction too small is skipped; the first area
            is always kept). 1 = no budget.
        fail_safe: when no candidate passes the checks, keep the whole map (and flag
            ``no_object``) instead of the best-ranked candidate.

    Refinement — from a selected area to its kept box:
        merge: join the image-adjacent segments whose mean disparity is within ``merge ×`` the
            area's contrast of its own (0 = off).
        min_purity: the kept box must hold at least this share of its own pixels, of the valid
            pixels inside it, else the next candidate is tried (0 = off).
        min_solidity: the area's segments must keep at least ``min_solidity ×`` the map's own
            share of pixels through an opening with a square of ``solidity_size ×`` the shorter
            image side, else the next candidate is tried (0 = off).
        solidity_size: side of that square as a share of the shorter image side.
        purity_candidates: how many ranked candidates the purity and solidity tests may try.
        grow: replace each kept area by the image-connected region nearer than half-way between
            it and its surroundings.
        grow_stride: the growing, the box refinement and the solidity work on every n-th pixel.
        map_stride: the whole object step reads every n-th pixel of the label map in y and x
            (1 = all; 2 = a quarter of them, about 3× faster): boxes are mapped back to full size
            and the reduction is computed on the full map.
        box_coverage: the box covers the area's largest image-connected pieces up to this share of
            its pixels (1 = all).
        box_quantile: the box spans the ``q … 1 − q`` quantiles of the kept pixels' coordinates.
        ground_clutter: pieces lying within ``ground_clutter ×`` the ground plane's inlier band
            are left out of the box (0 = off).
        drop_specks: image-connected pieces of the area without a solid 3 × 3 block (on the
            refinement grid) are left out of its box: specks and sparse speckle bands at the
            object's disparity stop stretching it.
    """

    _group: ClassVar[str] = "objects"
    _constraints: ClassVar[dict[str, Any]] = {
        "similarity": POSITIVE, "connectivity": OneOf((4, 8)), "link": Choice("somtorch.tasks.objects:LINKS"),
        "spread": Choice("somtorch.tasks.objects:SPREADS"), "min_boundary": NON_NEGATIVE,
        "size_power": NON_NEGATIVE, "color_rank": NON_NEGATIVE, "edge_rank": NON_NEGATIVE,
        "facing_rank": NON_NEGATIVE, "hierarchy": BOOL, "grow": BOOL, "grow_stride": POSITIVE_INT, "map_stride": POSITIVE_INT,
        "box_coverage": Interval(0, 1, open_lo=True), "box_quantile": Interval(0, 0.5, open_hi=True),
        "ground_clutter": NON_NEGATIVE, "drop_specks": BOOL, "merge": NON_NEGATIVE, "min_purity": FRACTION, "min_solidity": FRACTION,
        "solidity_size": Interval(0, 0.5, open_lo=True), "purity_candidates": POSITIVE_INT,
        "select": Choice("somtorch.tasks.objects:SELECTIONS"), "max_areas": POSITIVE_INT, "keep_ratio": FRACTION,
        "keep_budget": Interval(0, 1, open_lo=True),
        "fail_safe": BOOL, "min_contrast": NON_NEGATIVE, "max_area_frac": Interval(0, 1, open_lo=True),
        "min_area_frac": FRACTION,
    }
    _relations: ClassVar[list[tuple[Any, str]]] = [
        (lambda c: c.min_area_frac < c.max_area_frac,
         "need min_area_frac < max_area_frac; got {c.min_area_frac} and {c.max_area_frac}"),
    ]

    similarity: float = 0.05
    connectivity: int = 4
    link: str = "image"
    spread: str = "robust"
    min_boundary: float = 0.1
    hierarchy: bool = False
    size_power: float = 0.25
    color_rank: float = 0.0
    edge_rank: float = 0.0
    facing_rank: float = 0.0
    grow: bool = False
    grow_stride: int = 2
    map_stride: int = 2
    box_coverage: float = 0.99
    box_quantile: float = 0.001
    ground_clutter: float = 3.0
    drop_specks: bool = True
    merge: float = 0.75
    min_purity: float = 0.25
    min_solidity: float = 0.25
    solidity_size: float = 0.02
    purity_candidates: int = 5
    select: str = "salient"
    max_areas: int = 4
    keep_ratio: float = 0.2
    keep_budget: float = 0.3
    fail_safe: bool = True
    min_contrast: float = 0.0
    max_area_frac: float = 0.7
    min_area_frac: float = 0.01


# ---------------------------------------------------------------------------- step 1d: reduction
@dataclass
class ReductionConfig(Validated):
    """Tolerance margin around each kept box (paper Fig. 16): the sum of the three terms.

    Attributes:
        tolerance_px: a margin in px.
        tolerance_frac: a margin of this share of the box side (the paper's 5 %).
        tolerance_image: a margin of this share of the image diagonal (the default, 1.5 %).
    """

    _group: ClassVar[str] = "reduction"
    _constraints: ClassVar[dict[str, Any]] = {
        "tolerance_px": NON_NEGATIVE, "tolerance_frac": NON_NEGATIVE, "tolerance_image": NON_NEGATIVE,
    }

    tolerance_px: float = 0.0
    tolerance_frac: float = 0.0
    tolerance_image: float = 0.015


# ------------------------------------------------------------------------------------- outputs
@dataclass
class OutputConfig(Validated):
    """Which artefacts a run writes.

    Attributes:
        maps: write the pictures (disparity, segments, kept areas, reduced map, summary; PNG) and
            the reduced map (``reduced.npz``).
        pointcloud: write the point clouds of the full and the reduced map (PLY).
        render: also render the reduced point cloud to PNG.
        checkpoint: write the SOM's weights (``som.safetensors``).
        tensorboard: write TensorBoard logs (training curves, maps, hparams) under ``tb/``.
        voxel_size: voxel down-sampling of the point cloud, in the camera's baseline unit (None = off).
        render_backend: ``"auto"`` (Open3D if it imports, else matplotlib), ``"open3d"``, ``"matplotlib"``.
        member: the ensemble member drawn in the pictures.
    """

    _group: ClassVar[str] = "output"
    _constraints: ClassVar[dict[str, Any]] = {
        "maps": BOOL, "pointcloud": BOOL, "render": BOOL, "voxel_size": Interval(0, None, open_lo=True, optional=True),
        "render_backend": OneOf(("auto", "open3d", "matplotlib")), "checkpoint": BOOL, "tensorboard": BOOL,
        "member": Interval(0, None, integer=True),
    }

    maps: bool = True
    pointcloud: bool = True
    render: bool = True
    voxel_size: float | None = None
    render_backend: str = "auto"
    checkpoint: bool = True
    tensorboard: bool = True
    member: int = 0


@dataclass
class WarmStartConfig(Validated):
    """A disparity sequence (:class:`somtorch.video.SequenceRunner`).

    Attributes:
        warm: each frame's SOM starts from the previous frame's weights (False: every frame cold).
        warm_epochs: batch-map epochs of a warm frame.
        warm_sigma: neighbourhood radius a warm frame starts from (chosen on a synthetic pan over
            the Motorcycle, ``docs/scaling.md``: 1.0 lost the object in 5 of 40 frames, 2.0 in none).
        ground_keep: the ground plane is re-used while its inlier share stays ≥ this × its share
            when fitted.
        ground_every: the ground plane is refitted at least every this many frames.
    """

    _group: ClassVar[str] = "sequence"
    _constraints: ClassVar[dict[str, Any]] = {
        "warm": BOOL, "warm_epochs": POSITIVE_INT, "warm_sigma": POSITIVE,
        "ground_keep": Interval(0, 1, open_lo=True), "ground_every": POSITIVE_INT,
    }

    warm: bool = True
    warm_epochs: int = 2
    warm_sigma: float = 2.0
    ground_keep: float = 0.9
    ground_every: int = 15


# ------------------------------------------------------------------------------------ pipeline
@dataclass
class PipelineConfig(Validated):
    """The whole pipeline: ``method`` (segmenter of step 1b, see :data:`somtorch.segmenters.SEGMENTERS`),
    its groups, ``ensemble`` members (seeds ``seed … seed + ensemble − 1``), the scored
    ``object_id`` (None = the scene's main object(s)) and the torch ``device`` the SOM trains and
    labels the pixels on (``"cpu"``, ``"cuda"``, ``"cuda:1"``, ``"mps"``; the object step runs on
    the CPU)."""

    _constraints: ClassVar[dict[str, Any]] = {
        "method": Choice("somtorch.segmenters:METHODS"), "ensemble": POSITIVE_INT,
        "seed": Interval(0, None, integer=True), "object_id": Interval(1, None, integer=True, optional=True),
    }

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
    object_id: int | None = None
    device: str = "cpu"

    @property
    def runs(self) -> int:
        """Members actually computed: ``ensemble``, or 1 for a deterministic method."""
        from .segmenters import SEGMENTERS

        return 1 if SEGMENTERS[self.method].deterministic else self.ensemble


def with_overrides(cfg: PipelineConfig, overrides: dict[str, Any]) -> PipelineConfig:
    """A copy of ``cfg`` with ``{"group.field": value}`` (or top-level ``"field"``) changed, validated.

    >>> with_overrides(PipelineConfig(), {"objects.merge": 0.5}).objects.merge
    0.5
    """
    from dataclasses import fields, replace

    changes: dict[str, dict[str, Any]] = {}
    top: dict[str, Any] = {}
    for key, value in overrides.items():
        group, _, name = key.rpartition(".")
        target = getattr(cfg, group, None) if group else cfg
        if target is None or name not in {f.name for f in fields(target)}:
            raise ValueError(f"override {key!r}: not a field of the pipeline config")
        if group:
            changes.setdefault(group, {})[name] = value
        else:
            top[name] = value
    return replace(cfg, **top, **{g: replace(getattr(cfg, g), **c) for g, c in changes.items()})
