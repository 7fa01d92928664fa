"""3-D reconstruction of a (reduced) disparity map: depth, pinhole unprojection, point clouds.

Paper step 1d. Conventions: the camera frame of the reference (left) camera — ``x`` to the right,
``y`` down, ``z`` forward along the optical axis — and pixel ``(y, x)`` = (row, column) with integer
pixel centres, as in :func:`kornia.geometry.depth.depth_to_3d_v2`. Lengths (depth, points) come out
in the unit of ``baseline``: pass metres to get metres (Middlebury calibration files give mm).

A disparity map is a float tensor plus a boolean ``valid`` mask; values at invalid pixels are never
read. Only the PLY functions (:mod:`somtorch.geometry.ply`) and :meth:`PointCloud.to_open3d` import
Open3D, lazily.

Example:
    >>> d = torch.full((4, 6), 10.0)
    >>> cloud = disparity_to_point_cloud(d, torch.ones(4, 6, dtype=torch.bool),
    ...                                  focal_px=100.0, cx=2.5, cy=1.5, baseline=0.2)
    >>> len(cloud), round(float(cloud.points[:, 2].mean()), 6)
    (24, 2.0)
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import torch
from kornia.geometry.depth import depth_to_3d_v2

from somtorch._optional import import_open3d
from somtorch.validation import check_positive, check_tensor

__all__ = [
    "PointCloud",
    "depth_to_points",
    "disparity_to_depth",
    "disparity_to_point_cloud",
    "intrinsics_matrix",
]


# --------------------------------------------------------------------------------------------------
# input checks (public functions call these once; private helpers trust their callers)


def _check_number(name: str, value: Any) -> float:
    if isinstance(value, torch.Tensor) and value.numel() == 1:
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number; got {value!r}")
    return float(value)


def _check_map_pair(name: str, x: torch.Tensor, valid: Any, *, ndim: tuple[int, ...],
                    mask_name: str = "valid") -> None:
    """Check a float map ``x`` and its boolean mask ``valid`` (called ``mask_name`` in the messages) of
    the same shape; ``x`` finite where the mask is set."""
    check_tensor(name, x, ndim=ndim, floating=True)
    check_tensor(mask_name, valid, ndim=ndim, dtype=torch.bool)
    if valid.shape != x.shape:
        raise ValueError(f"{mask_name} must have the shape of {name}: {name} has shape {tuple(x.shape)}, "
                         f"{mask_name} has shape {tuple(valid.shape)}")
    if valid.device != x.device:
        raise ValueError(f"{mask_name} is on {valid.device} but {name} is on {x.device}; move one with .to(...)")
    bad = valid & ~torch.isfinite(x)
    if bool(bad.any()):
        first = tuple(int(i) for i in bad.nonzero()[0])
        where, fix = (("marked valid", "mark such pixels invalid in `valid`") if mask_name == "valid" else
                      (f"of {mask_name}", f"leave such pixels out of `{mask_name}`"))
        raise ValueError(f"{name} is NaN or inf at {int(bad.sum())} pixel(s) {where}, first at {first}; {fix}")


def _check_mask(name: str, mask: Any, hw: tuple[int, int], ref: str) -> torch.Tensor:
    check_tensor(name, mask, ndim=2, dtype=torch.bool)
    if tuple(mask.shape) != hw:
        raise ValueError(f"{name} must have the spatial size of {ref}: {ref} is {hw}, {name} has shape "
                         f"{tuple(mask.shape)}")
    return mask


def _image_colors(image: Any, hw: tuple[int, int], dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Validate an image and return it as float colours in [0, 1]. Shape: (3, H, W) (grey → 3 copies)."""
    check_tensor("image", image, ndim=(2, 3))
    if image.ndim == 3 and image.shape[0] not in (1, 3):
        fix = " (channels-last? use image.permute(2, 0, 1))" if image.shape[-1] in (1, 3) else ""
        raise ValueError(f"image must have shape (3, H, W), (1, H, W) or (H, W); "
                         f"got {tuple(image.shape)}{fix}")
    if tuple(image.shape[-2:]) != hw:
        raise ValueError(f"image must have the spatial size of the disparity map: disparity is {hw}, "
                         f"image has shape {tuple(image.shape)}")
    if image.dtype == torch.uint8:
        colors = image.to(device=device, dtype=dtype) / 255.0
    elif image.is_floating_point():
        lo, hi = float(image.min()), float(image.max())
        if not (0.0 <= lo and hi <= 1.0):  # also false for NaN
            raise ValueError(f"a float image must hold values in [0, 1]; got range [{lo}, {hi}] "
                             "(for 0..255 data pass a uint8 tensor or divide by 255)")
        colors = image.to(device=device, dtype=dtype)
    else:
        raise TypeError(f"image must be uint8 (0..255) or floating point (0..1); got dtype {image.dtype}")
    colors = colors.reshape(-1, *hw)  # (1|3, H, W)
    return colors.expand(3, *hw)


# --------------------------------------------------------------------------------------------------
# the point cloud


@dataclass(eq=False)
class PointCloud:
    """A set of 3-D points with optional colours and the pixel each point came from.

    Attributes:
        points: float coordinates in the camera frame.
        colors: float RGB in [0, 1], or ``None``.
        pixels: ``(y, x)`` pixel of each point (``torch.long``), or ``None`` when unknown (after
            :meth:`voxel_downsample`, or for clouds from Open3D / PLY files without pixel columns).

    Shape:
        - points: :math:`(P, 3)`
        - colors: :math:`(P, 3)`
        - pixels: :math:`(P, 2)`
    """

    points: torch.Tensor
    colors: torch.Tensor | None = None
    pixels: torch.Tensor | None = None

    def __post_init__(self) -> None:
        check_tensor("points", self.points, ndim=2, last_dim=3, floating=True, nonempty=False)
        n = self.points.shape[0]
        for name in ("colors", "pixels"):
            other = getattr(self, name)
            if isinstance(other, torch.Tensor) and other.device != self.points.device:
                raise ValueError(f"{name} is on {other.device} but points is on {self.points.device}; "
                                 "move them to one device with .to(...)")
        if self.colors is not None:
            check_tensor("colors", self.colors, ndim=2, last_dim=3, floating=True, nonempty=False)
            if self.colors.shape[0] != n:
                raise ValueError(f"colors must have one row per point: points has shape "
                                 f"{tuple(self.points.shape)}, colors has shape {tuple(self.colors.shape)}")
        if self.pixels is not None:
            check_tensor("pixels", self.pixels, ndim=2, last_dim=2, dtype=torch.long, nonempty=False)
            if self.pixels.shape[0] != n:
                raise ValueError(f"pixels must have one row per point: points has shape "
                                 f"{tuple(self.points.shape)}, pixels has shape {tuple(self.pixels.shape)}")

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes of points and colours stored as float32 (the size that matters for reduction ratios)."""
        return len(self) * 3 * 4 * (2 if self.colors is not None else 1)

    def _select(self, keep: torch.Tensor) -> PointCloud:
        return PointCloud(self.points[keep],
                          None if self.colors is None else self.colors[keep],
                          None if self.pixels is None else self.pixels[keep])

    def voxel_downsample(self, voxel_size: float) -> PointCloud:
        """Replace the points in each cubic voxel by their mean (colours likewise); deterministic.

        The voxel grid is anchored at ``points.min(0) - voxel_size / 2``, as in Open3D's
        ``voxel_down_sample``, so both give the same points (up to order and float rounding). Output
        order is the lexicographic order of the voxel indices. ``pixels`` becomes ``None``: a mean
        point has no single pixel (crop first, then downsample).

        Args:
            voxel_size: edge length of a voxel, in the unit of the points.

        Shape:
            - output points: :math:`(V, 3)` with :math:`V \\le P` occupied voxels.
        """
        check_positive("voxel_size", voxel_size)
        if len(self) == 0:
            return PointCloud(self.points.clone(), None if self.colors is None else self.colors.clone())
        origin = self.points.detach().amin(dim=0) - voxel_size / 2
        cell = torch.floor((self.points.detach() - origin) / voxel_size).long()  # (P, 3)
        _, inverse, counts = torch.unique(cell, dim=0, return_inverse=True, return_counts=True)  # (P,), (V,)
        denom = counts.unsqueeze(1).to(self.points.dtype)  # (V, 1)

        def mean(x: torch.Tensor) -> torch.Tensor:
            return x.new_zeros(counts.shape[0], x.shape[1]).index_add(0, inverse, x) / denom  # (V, 3)

        return PointCloud(mean(self.points), None if self.colors is None else mean(self.colors))

    def crop(self, mask: torch.Tensor) -> PointCloud:
        """Keep the points whose source pixel is ``True`` in ``mask``.

        Shape:
            - mask: :math:`(H, W)` bool, the size of the map the cloud was built from.
        """
        if self.pixels is None:
            raise ValueError("crop needs the source pixel of every point, but this cloud has pixels=None "
                             "(voxel-downsampled or read without pixel columns); "
                             "crop before voxel_downsample")
        check_tensor("mask", mask, ndim=2, dtype=torch.bool, nonempty=False)
        if len(self) == 0:
            return self._select(torch.zeros(0, dtype=torch.bool, device=self.points.device))
        ymax, xmax = (int(v) for v in self.pixels.amax(dim=0))
        if ymax >= mask.shape[0] or xmax >= mask.shape[1]:
            raise ValueError(f"mask has shape {tuple(mask.shape)} but the cloud has points from pixel up to "
                             f"(y={ymax}, x={xmax}); pass a mask of the disparity map's size")
        mask = mask.to(self.pixels.device)
        return self._select(mask[self.pixels[:, 0], self.pixels[:, 1]])

    def to_open3d(self) -> Any:
        """Return an ``open3d.geometry.PointCloud`` (legacy API; float64 points, colours if any)."""
        o3d = import_open3d()
        pcd = o3d.geometry.PointCloud()
        pcd.points = o3d.utility.Vector3dVector(self.points.detach().cpu().double().numpy())
        if self.colors is not None:
            pcd.colors = o3d.utility.Vector3dVector(self.colors.detach().cpu().double().numpy())
        return pcd

    @classmethod
    def from_open3d(cls, pcd: Any, *, dtype: torch.dtype = torch.float32) -> PointCloud:
        """Build a cloud from an Open3D point cloud (legacy ``geometry`` or tensor ``t.geometry`` API).

        ``pixels`` are taken from the tensor attributes ``pixel_y``/``pixel_x`` when present (as
        :func:`~somtorch.geometry.ply.write_ply` stores them), otherwise ``None``.
        """
        o3d = import_open3d()
        if isinstance(pcd, o3d.geometry.PointCloud):
            import numpy as np

            points = torch.from_numpy(np.asarray(pcd.points)).to(dtype)
            colors = torch.from_numpy(np.asarray(pcd.colors)).to(dtype) if pcd.has_colors() else None
            return cls(points.reshape(-1, 3), colors)
        if isinstance(pcd, o3d.t.geometry.PointCloud):
            return _from_tensor_cloud(pcd, dtype)
        raise TypeError(f"pcd must be an open3d.geometry.PointCloud or open3d.t.geometry.PointCloud; "
                        f"got {type(pcd).__name__}")


def _from_tensor_cloud(pcd: Any, dtype: torch.dtype) -> PointCloud:
    attrs = set(pcd.point)
    if "positions" not in attrs:
        return PointCloud(torch.zeros(0, 3, dtype=dtype))
    points = torch.from_numpy(pcd.point.positions.numpy()).to(dtype).reshape(-1, 3)
    colors = None
    if "colors" in attrs:
        raw = torch.from_numpy(pcd.point.colors.numpy()).reshape(-1, 3)
        colors = raw.to(dtype) / 255.0 if raw.dtype == torch.uint8 else raw.to(dtype)
    pixels = None
    if {"pixel_y", "pixel_x"} <= attrs:
        pixels = torch.cat([torch.from_numpy(pcd.point.pixel_y.numpy()).reshape(-1, 1),
                            torch.from_numpy(pcd.point.pixel_x.numpy()).reshape(-1, 1)], dim=1).long()
    return PointCloud(points, colors, pixels)


# --------------------------------------------------------------------------------------------------
# disparity → depth → points


def disparity_to_depth(disparity: torch.Tensor, valid: torch.Tensor, *, focal_px: float, baseline: float,
                       doffs: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth of each pixel from a rectified stereo pair: ``Z = baseline · focal_px / (d + doffs)``.

    ``doffs`` is the x-difference of the two principal points (Middlebury's ``doffs``; 0 for a
    standard rectified pair). Pixels with ``d + doffs <= 0`` (at or beyond infinity) become invalid.
    Differentiable in ``disparity`` at valid pixels; gradients at invalid pixels are zero.

    Args:
        disparity: disparity in pixels (any value at invalid pixels).
        valid: ``True`` where the disparity is known.
        focal_px: focal length in pixels.
        baseline: distance between the camera centres; depth comes out in its unit.
        doffs: disparity offset in pixels.

    Returns:
        ``(depth, valid)``: depth (0 at invalid pixels — read it only where ``valid``) and the updated mask.

    Shape:
        - disparity, valid: :math:`(H, W)` or :math:`(B, H, W)`
        - depth, valid (output): same as the input

    Example:
        >>> depth, ok = disparity_to_depth(torch.tensor([[10.0, 0.0]]), torch.tensor([[True, True]]),
        ...                                focal_px=100.0, baseline=0.5)
        >>> depth.tolist(), ok.tolist()
        ([[5.0, 0.0]], [[True, False]])
    """
    _check_map_pair("disparity", disparity, valid, ndim=(2, 3))
    check_positive("focal_px", focal_px)
    check_positive("baseline", baseline)
    doffs = _check_number("doffs", doffs)
    denom = disparity + doffs
    valid = valid & (denom > 0)
    safe = torch.where(valid, denom, torch.ones_like(denom))  # no 1/0 in forward or backward
    depth = torch.where(valid, (baseline * focal_px) / safe, torch.zeros_like(denom))
    return depth, valid


def intrinsics_matrix(focal_px: float, cx: float, cy: float, fy_px: float | None = None, *,
                      dtype: torch.dtype = torch.float32,
                      device: torch.device | str | None = None) -> torch.Tensor:
    """Pinhole camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (``fy = fx`` unless given).

    Shape:
        - output: :math:`(3, 3)`

    Example:
        >>> intrinsics_matrix(100.0, 3.0, 2.0).tolist()
        [[100.0, 0.0, 3.0], [0.0, 100.0, 2.0], [0.0, 0.0, 1.0]]
    """
    check_positive("focal_px", focal_px)
    fy = focal_px if fy_px is None else fy_px
    check_positive("fy_px", fy)
    cx, cy = _check_number("cx", cx), _check_number("cy", cy)
    return torch.tensor([[float(focal_px), 0.0, cx], [0.0, float(fy), cy], [0.0, 0.0, 1.0]],
                        dtype=dtype, device=device)


def depth_to_points(depth: torch.Tensor, valid: torch.Tensor, K: torch.Tensor, *,
                    image: torch.Tensor | None = None) -> PointCloud:
    """Unproject the valid pixels of a depth map through a pinhole camera (kornia ``depth_to_3d_v2``).

    Point of pixel ``(y, x)``: ``((x - cx) Z / fx, (y - cy) Z / fy, Z)``. Points are in row-major
    pixel order; ``cloud.pixels`` says which pixel each came from. Device and dtype follow ``depth``.

    Args:
        depth: z-depth per pixel (any value at invalid pixels).
        valid: ``True`` where the depth is known.
        K: camera matrix, see :func:`intrinsics_matrix`.
        image: colours: ``uint8`` in 0..255 or float in [0, 1]; grey images are repeated to RGB.

    Shape:
        - depth, valid: :math:`(H, W)` (one cloud per map; loop over a batch)
        - K: :math:`(3, 3)`
        - image: :math:`(3, H, W)`, :math:`(1, H, W)` or :math:`(H, W)`
        - output: a :class:`PointCloud` of :math:`P` = ``valid.sum()`` points
    """
    _check_map_pair("depth", depth, valid, ndim=(2,))
    check_tensor("K", K, ndim=2, floating=True, finite=True)
    if tuple(K.shape) != (3, 3):
        raise ValueError(f"K must be a (3, 3) camera matrix; got shape {tuple(K.shape)} "
                         "(see intrinsics_matrix)")
    hw = (int(depth.shape[0]), int(depth.shape[1]))
    colors = None if image is None else _image_colors(image, hw, depth.dtype, depth.device)  # (3, H, W)
    K = K.to(device=depth.device, dtype=depth.dtype)
    xyz = depth_to_3d_v2(depth, K.unsqueeze(0))[0]  # (H, W, 3)
    return PointCloud(points=xyz[valid],  # (P, 3)
                      colors=None if colors is None else colors[:, valid].T,  # (P, 3)
                      pixels=valid.nonzero())  # (P, 2), same row-major order as boolean indexing


def disparity_to_point_cloud(disparity: torch.Tensor, valid: torch.Tensor, *, focal_px: float, cx: float,
                             cy: float, baseline: float, doffs: float = 0.0,
                             image: torch.Tensor | None = None, mask: torch.Tensor | None = None,
                             voxel_size: float | None = None) -> PointCloud:
    """Disparity map → coloured point cloud in one call (depth, unprojection, crop, downsampling).

    Args:
        disparity, valid, focal_px, baseline, doffs: see :func:`disparity_to_depth`.
        cx, cy: principal point in pixels.
        image: colours, see :func:`depth_to_points`.
        mask: keep only these pixels (e.g. one segmented object).
        voxel_size: if given, :meth:`PointCloud.voxel_downsample` the result (``pixels`` becomes ``None``).

    Shape:
        - disparity, valid, mask: :math:`(H, W)`
        - image: :math:`(3, H, W)`
    """
    check_tensor("disparity", disparity, ndim=2, floating=True)
    if mask is not None:
        _check_mask("mask", mask, (int(disparity.shape[0]), int(disparity.shape[1])), "disparity")
    if voxel_size is not None:
        check_positive("voxel_size", voxel_size)
    depth, valid = disparity_to_depth(disparity, valid, focal_px=focal_px, baseline=baseline, doffs=doffs)
    if mask is not None:
        valid = valid & mask.to(valid.device)
    K = intrinsics_matrix(focal_px, cx, cy, dtype=depth.dtype, device=depth.device)
    cloud = depth_to_points(depth, valid, K, image=image)
    return cloud if voxel_size is None else cloud.voxel_downsample(voxel_size)
