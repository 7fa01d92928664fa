"""Configuration of the ground plane and of paper step 1c, the object areas (see
:mod:`somtorch.config`; the tuned constants and how each was chosen: ``docs/tuned_constants.md``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from . import options
from .constraints import FRACTION, NON_NEGATIVE, POSITIVE, POSITIVE_INT, Choice, Interval, Validated


# ---------------------------------------------------------------------------------- ground plane
@dataclass
class GroundConfig(Validated):
    """The support surface (floor, road, table top), found by RANSAC in (x, y, d) and verified
    before removal.

    Verification (``rule``): ``"none"`` — no ground handling (the paper's pipeline);
    ``"position"`` — where a forward camera sees its floor (``min_slope_frac``, tilt in x ≤ tilt in
    y; RANSAC on the lower image half); ``"support"`` — by what the plane supports, at any camera
    pitch (``support_frac`` of the pixels on it, or of the view's rim with nothing behind it; RANSAC
    on the whole map);
    ``"either"`` — a plane passing either (RANSAC on the lower half). Every rule needs
    ``min_inlier_frac``; the position rule also ``max_below_frac`` (nothing substantial behind the
    plane), which a support-verified plane need not pass: a table top holding most of the view
    has the floor beyond its edges behind it.

    Attributes:
        rule: ``"none"``, ``"position"``, ``"support"`` or ``"either"`` (above).
        tol_frac: inlier band half-width as a fraction of the map's disparity range (1st–99th
            percentile) …
        tol_px: … but at least this many px …
        noise_band: … and at least this many times the map's per-pixel disparity error: its noise
            (:func:`~somtorch.tasks.ground.noise_sigma`: ≤ 0.14 px on every stereo and GT map of the
            corpus, so the band there is the two above; a dense sensor's floor with 0.5 px of noise
            left a third of its pixels as speckle outside a 0.5 px band) and its rounding (a map
            stored in steps of q px, :func:`~somtorch.tasks.ground.quantum`, adds q²/12 to the
            variance: 2/√12 ≈ 0.58 px on an integer map, whose floor is a flight of terraces up to
            0.5 px off the plane); dropped where it exceeds half the map's 1–99 % disparity range (a
            map of noise, no surface). A support plane (not one the position rule alone verifies)
            takes this many times the spread of its own pixels about it where that is wider and
            resolved (:func:`~somtorch.tasks.support_surface.own_band`: an error correlated across
            pixels, a dense sensor's filtered map, which neighbour differences do not see). 0 = off.
        min_inlier_frac: a plane needs this share of the valid pixels.
        min_slope_frac: ``b · H`` (disparity gained from top to bottom) must be at least this share
            of the disparity range: a floor spans it, from its horizon to the nearest thing in view;
            a seat, a bed, a table top or a slanted wall spans a part (docs/tuned_constants.md).
            Position rule (with tilt in x ≤ tilt in y).
        support_frac: support rule: the plane holds at least this share of the valid pixels (a
            floor or table top filling the view; a forward camera's floor holds 14–40 %, the
            far-room slab of oakd_pov_controllers 55 %: docs/method.md) — or at least this share of
            the view's rim (:func:`~somtorch.tasks.ground.view_rim`) while passing the behind test
            of ``max_below_frac``: a floor seen from above surrounds what it supports, however much
            of the view the things on it fill, while a back wall above a floor or a room's floor
            below its walls holds about half of the rim (figures: docs/method.md).
        max_below_frac: position rule: a floor hides what lies beneath it, so at most this share of
            the valid pixels where the plane is in view (plane disparity > band) may lie *behind* it
            (disparity below the band); a ramp, a lattice or a plane through the objects fails
            (1 = no check). A plane the support rule verifies by its pixel share is exempt
            (docs/tuned_constants.md); one it verifies by the rim is not.
        iterations: RANSAC hypotheses.
        sample: pixels drawn for RANSAC and for the tests (estimated on a sample for every
            hypothesis: the best plane that passes them is found, not the best plane refused).
    """

    _group: ClassVar[str] = "ground"
    _constraints: ClassVar[dict[str, Any]] = {
        "rule": Choice(options.GROUND_RULES), "tol_frac": NON_NEGATIVE, "tol_px": NON_NEGATIVE,
        "noise_band": NON_NEGATIVE, "min_inlier_frac": Interval(0, 1, open_lo=True),
        "min_slope_frac": NON_NEGATIVE, "max_below_frac": FRACTION, "iterations": POSITIVE_INT,
        "sample": POSITIVE_INT, "support_frac": Interval(0, 1, open_lo=True),
    }

    rule: str = "either"
    tol_frac: float = 0.02
    tol_px: float = 0.5
    min_inlier_frac: float = 0.08
    min_slope_frac: float = 1.0
    max_below_frac: float = 0.1
    iterations: int = 400
    sample: int = 5000
    support_frac: float = 0.6
    noise_band: float = 2.0


# ------------------------------------------------------------------------------ step 1c: objects
#: Depth continuity across a pixel pair: ``|Δd| ≤ max(CONTINUITY_STEP_PX, CONTINUITY_STEP_FRAC · d)``
#: (``d`` the pair's mean), the step rule of issue 31's ``plane_components`` baseline (not tuned here).
CONTINUITY_STEP_PX = 1.0
CONTINUITY_STEP_FRAC = 0.05
#: A common boundary of two segments is continuous when at least this share of its pixel pairs is
#: (most of it: a definition, not a tuned value; the protocol found 0.5 and 0.8 alike, session 14).
CONTINUOUS_SHARE = 0.5


@dataclass
class AreaConfig(Validated):
    """Object-area recognition (paper step 1c), see :mod:`somtorch.tasks.objects` and
    :mod:`somtorch.tasks.refine`.

    The defaults are the ``salient`` rule; ``conf/objects/paper.yaml`` holds the paper's literal rule
    (``rule="paper"``, ``similarity=0.1``, no refinement).

    The rule:
        rule: ``"salient"``: neurons link where their segments share a boundary in the image (at
            least ``min_boundary``), the spread is the 5th–95th percentile of the map's disparity,
            the areas in front of their surroundings are ranked by contrast ×
            ``area_frac ** size_power``, the contrast read as the geometric mean of the area's own
            and that of the area as ``merge`` grows it (what the refinement keeps of it; session
            31, no field) (on a map whose support plane was verified and cut, the
            areas standing on it or above it, by size × nearness: ``area_frac ×`` mean disparity)
            and up to ``max_areas`` are kept; when
            no candidate passes the checks below, the whole map is kept (flagged ``no_object``).
            ``"paper"``: the paper read literally: neurons adjacent on the SOM grid (one step along
            a row or a column), the spread is the full range d_max − d_min, the nearest area (largest
            mean disparity) is kept, always.

    Linking — which neurons form one area:
        similarity: two linked neurons are similar if their reference disparities differ by less
            than ``similarity ×`` the map's disparity spread.
        min_boundary: two segments touch if their common boundary is at least this share of the
            shorter of their two perimeters (``salient`` rule).

    On a map whose ground plane the support test verified (it holds most of the view: what is left
    stands on it), two touching segments also link where their common boundary is continuous in
    depth (``CONTINUOUS_SHARE`` of its pixel pairs step by ``|Δd| ≤ max(CONTINUITY_STEP_PX,
    CONTINUITY_STEP_FRAC · d)``), if both stand above the ground plane's clutter band (mean ``|d −
    plane|`` > ``ground_clutter ×`` the band: left-over floor chains everything) and each lies in
    one image island of the segmented pixels (its island holding ``box_coverage`` of its pixels: a
    segment straddling two objects chains them). A staircase, a ramp or an arm is continuous at
    every segment boundary while its segments' mean disparities differ step by step (``salient``
    rule only; no field: see ``docs/tuned_constants.md``).

    Selection — which areas are kept (``salient`` rule):
        size_power: weight of the area's size in the ranking (0 = contrast alone; not used on a
            support-verified map, ranked by size × nearness).
        max_areas: how many areas are kept at most.
        keep_budget: a further area is kept only if the union of the kept boxes, each with the
            reduction's margins (what the reduced map keeps), then holds at most this share of the
            valid pixels (the data-reduction budget: every salient area that fits is kept, one that
            would make the reduction too small is skipped; the first area is always kept). 1 = no
            budget.

    Refinement — from a selected area to its kept box:
        merge: join the image-adjacent segments whose mean disparity is within ``merge ×`` the
            area's contrast of its own (0 = off).
        min_purity: the kept box must hold at least this share of its own pixels, of the valid
            pixels inside it, else the next candidate is tried (0 = off).
        min_solidity: the area's segments must keep at least ``min_solidity ×`` the map's own
            share of pixels through an opening with a square of ``solidity_size ×`` the shorter
            image side, else the next candidate is tried (0 = off).
        solidity_size: side of that square as a share of the shorter image side.
        map_stride: the whole object step reads every n-th pixel of the label map in y and x
            (1 = all; 2 = a quarter of them, about 3× faster): the refinement and the solidity read
            every pixel of that map, boxes are mapped back to full size and the reduction is
            computed on the full map.
        box_coverage: the box covers the area's largest image-connected pieces up to this share of
            its pixels (1 = all).
        box_quantile: the box spans the ``q … 1 − q`` quantiles of the kept pixels' coordinates.
        ground_clutter: pieces lying within ``ground_clutter ×`` the ground plane's inlier band
            are left out of the box (0 = off).

    Under the ``salient`` rule, image-connected pieces of an area without a solid 3 × 3 block (on
    the refinement grid) are left out of its box as well: specks and sparse speckle bands at the
    object's disparity stop stretching it; and an area whose pixels lie in several regions that the
    cut ground or an invalid gap wider than the solidity square separates is split into them (each
    holding more than ``1 − box_coverage`` of its pixels): each part is refined, checked and kept on
    its own, within the budget, and the parts count as one of the ``max_areas`` (one SOM neuron's
    segment may cover two objects standing apart on the floor, or an object and an SGBM streak
    beyond a band of missing pixels). No field for either; the ``paper`` rule does neither.
    """

    _group: ClassVar[str] = "objects"
    _constraints: ClassVar[dict[str, Any]] = {
        "rule": Choice(options.OBJECT_RULES), "similarity": POSITIVE, "min_boundary": NON_NEGATIVE,
        "size_power": NON_NEGATIVE, "map_stride": POSITIVE_INT,
        "box_coverage": Interval(0, 1, open_lo=True), "box_quantile": Interval(0, 0.5, open_hi=True),
        "ground_clutter": NON_NEGATIVE, "merge": NON_NEGATIVE, "min_purity": FRACTION,
        "min_solidity": FRACTION, "solidity_size": Interval(0, 0.5, open_lo=True),
        "max_areas": POSITIVE_INT, "keep_budget": Interval(0, 1, open_lo=True),
    }

    rule: str = "salient"
    similarity: float = 0.05
    min_boundary: float = 0.1
    size_power: float = 0.25
    map_stride: int = 2
    box_coverage: float = 0.99
    box_quantile: float = 0.001
    ground_clutter: float = 3.0
    merge: float = 0.75
    min_purity: float = 0.15
    min_solidity: float = 0.25
    solidity_size: float = 0.02
    max_areas: int = 4
    keep_budget: float = 0.35
