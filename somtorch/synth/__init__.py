"""Procedural stereo scenes with exact ground truth: ``generate_frame(family, seed, camera)``.

Scenes are built from primitives (planes, boxes, cylinders, spheres, cones) by one of the
:data:`FAMILIES` (stairs, garden, road, room, tabletop, hands, fence, clutter), ray-cast from both
cameras of a rectified stereo rig (:data:`CAMERAS`: kitti, oakd, middlebury) with analytic
intersections, textured procedurally at the 3-D hit point and shaded. Each frame carries the GT
disparity of the left view, an instance map, both images and the SGBM disparity of the pair.

Labels: every object a robot would avoid or keep has an id >= 1; support surfaces (ground, road,
lawn, floor, walls, table tops, kerbs) are 0. In ``stairs`` the staircase is the object. Objects
with fewer than :func:`min_pixels` visible pixels are dropped.

**The main object** is the labelled object with the most visible pixels in the left view (ties: the
nearer, by median depth); ids are numbered by visible pixel count, so the main object is id 1.

Frames are written in the Middlebury layout :func:`somtorch.disparity.load_scene` reads
(:func:`write_frame`): ``load_scene(folder)`` is the GT version, ``load_scene(folder,
disparity_file="disp_sgbm.pfm")`` the SGBM version. See ``docs/synth.md``.

This package may use :mod:`somtorch.disparity`; nothing in ``somtorch.core`` or
``somtorch.disparity`` imports it.
"""

from somtorch.synth.cameras import CAMERAS, SynthCamera, get_camera
from somtorch.synth.families import FAMILIES
from somtorch.synth.frame import Frame, generate_frame, min_pixels
from somtorch.synth.store import cache_root, dataset_dir, ensure_frame, frame_dir, load_frame, write_frame

__all__ = ["CAMERAS", "FAMILIES", "Frame", "SynthCamera", "cache_root", "dataset_dir", "ensure_frame", "frame_dir",
           "generate_frame", "get_camera", "load_frame", "min_pixels", "write_frame"]
