"""Geometry and point clouds (paper step 1d): disparity → depth → 3-D points, object extents, PLY
files, PNG views.

Takes plain tensors and numbers (no dependency on the disparity readers). Importing this package
does not import Open3D; the functions that need it import it on first use.
"""

from somtorch.geometry.extent import ROBUST_PERCENTILES, ObjectExtent, disparity_plane_3d, object_extent
from somtorch.geometry.ply import read_ply, write_ply
from somtorch.geometry.pointcloud import (
    PointCloud,
    depth_to_points,
    disparity_to_depth,
    disparity_to_point_cloud,
    intrinsics_matrix,
)
from somtorch.geometry.render import open3d_rendering_available, render_point_cloud, start_open3d_probe

__all__ = [
    "ROBUST_PERCENTILES",
    "ObjectExtent",
    "PointCloud",
    "depth_to_points",
    "disparity_to_depth",
    "disparity_plane_3d",
    "disparity_to_point_cloud",
    "intrinsics_matrix",
    "object_extent",
    "open3d_rendering_available",
    "read_ply",
    "render_point_cloud",
    "start_open3d_probe",
    "write_ply",
]
