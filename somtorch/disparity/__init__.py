"""Disparity data: readers for the real formats, one scene description, stereo matching.

Knows nothing of SOMs or experiments. A disparity map here is always a float tensor plus a boolean
valid mask; format-specific "no value" codes (``inf``, ``0``) end in :mod:`somtorch.disparity.io`.

Example:
    >>> from somtorch.disparity import load_scene
    >>> scene = load_scene("motorcycle")
    >>> (scene.height, scene.width), scene.camera.baseline_unit
    ((500, 741), 'mm')
"""

from somtorch.disparity.io import (
    DISPARITY_SUFFIXES,
    read_disparity,
    read_image,
    read_mask,
    read_pfm,
    write_pfm,
)
from somtorch.disparity.camera import Camera, read_middlebury_camera
from somtorch.disparity.io import parse_middlebury_calib
from somtorch.disparity.loading import EMBEDDED_SCENES, load_scene
from somtorch.disparity.scene import ObjectInfo, Scene, scene_from_arrays
from somtorch.disparity.stereo import SGBM_MODES, SGBMParams, compute_disparity, scene_from_stereo

__all__ = [
    "DISPARITY_SUFFIXES",
    "EMBEDDED_SCENES",
    "SGBM_MODES",
    "Camera",
    "ObjectInfo",
    "SGBMParams",
    "Scene",
    "compute_disparity",
    "load_scene",
    "parse_middlebury_calib",
    "read_disparity",
    "read_image",
    "read_mask",
    "read_middlebury_camera",
    "read_pfm",
    "scene_from_arrays",
    "scene_from_stereo",
    "write_pfm",
]
