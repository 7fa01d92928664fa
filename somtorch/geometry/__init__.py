"""Geometry and point clouds (paper step 1d): disparity → depth → 3-D points, PLY files, PNG views.

Takes plain tensors and numbers (no dependency on the disparity readers). Importing this package
does not import Open3D; the functions that need it import it on first use.
"""

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
    "PointCloud",
    "depth_to_points",
    "disparity_to_depth",
    "disparity_to_point_cloud",
    "intrinsics_matrix",
    "open3d_rendering_available",
    "read_ply",
    "render_point_cloud",
    "start_open3d_probe",
    "write_ply",
]
