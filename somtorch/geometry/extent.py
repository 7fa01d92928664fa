"""Where a kept object is in 3-D and how large it is: its pixels unprojected through the camera, read
robustly (paper step 1d, per kept area).

A robotics user of the reduced map asks first where each kept thing is and how big: its centre,
its extent along the camera's axes, and — where the pipeline cut a ground plane — how far it rises
above it. :func:`object_extent` reads them from an object's pixels; the extremes are percentiles
(:data:`ROBUST_PERCENTILES`, the frame of :func:`~somtorch.geometry.render.render_point_cloud`), so a
few stray matches at an occluding edge do not stretch them. :func:`disparity_plane_3d` turns a
plane of disparity space (``d = a·x + b·y + c``, the ground fit's) into the 3-D plane it is: under a
pinhole camera a 3-D plane is a plane in (x, y, d) and back.

Conventions are :mod:`somtorch.geometry.pointcloud`'s: the left camera's frame (x right, y down, z
forward), pixel (y, x) = (row, column) with integer pixel centres, lengths in the unit of
``baseline``. Takes plain tensors and numbers (no dependency on the pipeline's objects).

Example:
    >>> d = torch.full((4, 6), 10.0)
    >>> ext = object_extent(d, torch.ones(4, 6, dtype=torch.bool), focal_px=100.0, cx=2.5, cy=1.5,
    ...                     baseline=0.2)
    >>> ext.points, ext.centroid[2]
    (24, 2.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from somtorch.geometry.pointcloud import _check_map_pair, _check_number, disparity_to_depth
from somtorch.validation import check_positive

__all__ = ["ROBUST_PERCENTILES", "ObjectExtent", "disparity_plane_3d", "object_extent"]

#: The percentiles an extent is read between (and a point-cloud view is framed on): the 2 % of the
#: points at either end of each axis — stereo mismatches at an occluding edge, a speck — are not the
#: object's extent.
ROBUST_PERCENTILES = (2.0, 98.0)


@dataclass(frozen=True)
class ObjectExtent:
    """An object's place and size in the left camera's frame, in the unit of the baseline.

    Attributes:
        points: the object's pixels with a finite depth that were read.
        centroid: the median (x, y, z) of its points.
        low: each axis' lower percentile (:data:`ROBUST_PERCENTILES`) ...
        high: ... and upper one: the object's box along the camera's axes.
        height: how far it rises above the plane passed to :func:`object_extent` (the upper
            percentile of its points' distances from it, towards the camera); None without a plane.
    """

    points: int
    centroid: tuple[float, float, float]
    low: tuple[float, float, float]
    high: tuple[float, float, float]
    height: float | None = None

    @property
    def size(self) -> tuple[float, float, float]:
        """The box's side along x, y and z (``high − low``)."""
        return tuple(h - lo for lo, h in zip(self.low, self.high, strict=True))  # type: ignore[return-value]

    def as_dict(self) -> dict:
        """The extent as JSON-ready data (for ``metrics.json``)."""
        return {"points": self.points, "centroid_xyz": list(self.centroid), "low_xyz": list(self.low),
                "high_xyz": list(self.high), "size_xyz": list(self.size), "height_above_plane": self.height}


def disparity_plane_3d(coef: tuple[float, float, float], *, focal_px: float, cx: float, cy: float,
                       baseline: float, doffs: float = 0.0) -> tuple[tuple[float, float, float], float]:
    """The 3-D plane ``n · P = k`` (``|n| = 1``, ``k > 0``: the camera lies on the side that ``k − n · P``
    counts positive) of the disparity-space plane ``d = a·x + b·y + c``, ``coef`` = (a, b, c).

    With ``d + doffs = f·B / Z``, ``x = f·X / Z + cx`` and ``y = f·Y / Z + cy``, the plane multiplied by
    ``Z`` reads ``a·f·X + b·f·Y + (a·cx + b·cy + c + doffs)·Z = f·B``: exact, no fit.

    Raises:
        ValueError: a plane of constant disparity ``−doffs`` (at infinity: no 3-D plane), or a
            non-finite coefficient.

    Example:
        >>> n, k = disparity_plane_3d((0.0, 0.0, 10.0), focal_px=100.0, cx=0.0, cy=0.0, baseline=0.2)
        >>> [round(v, 6) for v in n], round(k, 6)  # a wall facing the camera, 2 units away
        ([0.0, 0.0, 1.0], 2.0)
    """
    a, b, c = (_check_number(name, v) for name, v in zip("abc", coef, strict=True))
    check_positive("focal_px", focal_px)
    check_positive("baseline", baseline)
    cx, cy, doffs = _check_number("cx", cx), _check_number("cy", cy), _check_number("doffs", doffs)
    n = (a * focal_px, b * focal_px, a * cx + b * cy + c + doffs)
    norm = math.sqrt(sum(v * v for v in n))
    if norm == 0.0:
        raise ValueError(f"the plane d = {a}·x + {b}·y + {c} is at infinity (d + doffs = 0 everywhere): "
                         "it is no plane in 3-D")
    return (n[0] / norm, n[1] / norm, n[2] / norm), focal_px * baseline / norm


def object_extent(disparity: torch.Tensor, mask: torch.Tensor, *, focal_px: float, cx: float, cy: float,
                  baseline: float, doffs: float = 0.0, plane: tuple[float, float, float] | None = None,
                  percentiles: tuple[float, float] = ROBUST_PERCENTILES) -> ObjectExtent | None:
    """The place and size of the object whose pixels are ``mask`` (see :class:`ObjectExtent`).

    Args:
        disparity: disparity in px.
        mask: the object's pixels (invalid ones among them must be left out by the caller; pixels with
            ``d + doffs <= 0`` are left out here).
        focal_px, cx, cy, baseline, doffs: the camera (:func:`~somtorch.geometry.disparity_to_depth`).
        plane: a plane of disparity space (a, b, c), the ground fit's, to measure the height above;
            None: no height.
        percentiles: the lower and upper percentile the extent is read between.

    Returns:
        the extent in float64, or None where the mask holds no pixel with a finite depth.

    Shape:
        ``disparity``, ``mask``: :math:`(H, W)`.
    """
    _check_map_pair("disparity", disparity, mask, ndim=(2,), mask_name="mask")
    lo_p, hi_p = (_check_number("percentiles", p) for p in percentiles)
    if not 0.0 <= lo_p <= hi_p <= 100.0:
        raise ValueError(f"percentiles must satisfy 0 <= low <= high <= 100; got {percentiles!r}")
    depth, ok = disparity_to_depth(disparity.double(), mask, focal_px=focal_px, baseline=baseline, doffs=doffs)
    ys, xs = ok.nonzero(as_tuple=True)
    if ys.numel() == 0:
        return None
    z = depth[ys, xs]
    pts = torch.stack([(xs.double() - cx) * z / focal_px, (ys.double() - cy) * z / focal_px, z], 1)  # (P, 3)
    q = torch.tensor([lo_p / 100.0, 0.5, hi_p / 100.0], dtype=torch.float64)
    low, mid, high = (tuple(float(v) for v in row) for row in torch.quantile(pts, q, dim=0))
    height = None
    if plane is not None:
        n, k = disparity_plane_3d(plane, focal_px=focal_px, cx=cx, cy=cy, baseline=baseline, doffs=doffs)
        above = k - pts @ torch.tensor(n, dtype=torch.float64)  # (P,) towards the camera
        height = float(torch.quantile(above, hi_p / 100.0))
    return ObjectExtent(int(ys.numel()), mid, low, high, height)
