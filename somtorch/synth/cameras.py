"""Stereo cameras of the generator, by name (:data:`CAMERAS`), and their pose in the world.

World frame: X right, Y forward, Z up, the ground at ``Z = 0``. The left camera sits at
``(x, y, height)``, yawed about Z and pitched down by ``pitch`` (0 = horizontal, 90° = straight
down); its frame is OpenCV's (x right, y down, z forward). The right camera is the left one moved by
``baseline_m`` along its x axis: a rectified pair, ``d = f·B/Z``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from somtorch.disparity.camera import Camera
from somtorch.validation import check_choice

__all__ = ["CAMERAS", "Pose", "SynthCamera", "get_camera"]


@dataclass(frozen=True)
class SynthCamera:
    """A rectified stereo rig and the depth window its scenes are scaled to.

    Attributes:
        name: registry name.
        width, height: image size, pixels.
        focal_px: focal length, pixels (square pixels, ``cx, cy`` at the image centre).
        baseline_m: stereo baseline, metres.
        near_m, far_m: the depth range scenes are scaled into (a family's natural range is
            multiplied by one factor so its near end is not nearer than ``near_m``).
        max_ndisp: largest SGBM disparity range; a draw whose GT exceeds it is re-drawn.
    """

    name: str
    width: int
    height: int
    focal_px: float
    baseline_m: float
    near_m: float
    far_m: float
    max_ndisp: int

    def camera(self, scale: float = 1.0) -> Camera:
        """The :class:`~somtorch.disparity.camera.Camera` of images resized by ``scale``."""
        w, h = self.size(scale)
        f = self.focal_px * w / self.width
        return Camera(focal_px=f, cx=(w - 1) / 2, cy=(h - 1) / 2, baseline=self.baseline_m * 1000.0,
                      baseline_unit="mm")

    def size(self, scale: float = 1.0) -> tuple[int, int]:
        """``(width, height)`` at ``scale`` (rounded, at least 16 px)."""
        return max(16, round(self.width * scale)), max(16, round(self.height * scale))


CAMERAS: dict[str, SynthCamera] = {
    "kitti": SynthCamera("kitti", 1242, 375, 721.0, 0.54, near_m=3.0, far_m=60.0, max_ndisp=192),
    "oakd": SynthCamera("oakd", 640, 480, 451.0, 0.075, near_m=0.3, far_m=5.0, max_ndisp=160),
    # Middlebury 2014 at quarter size ("Q", like Motorcycle_Q): 741x497, f ~ 1000 px, B ~ 0.19 m
    "middlebury": SynthCamera("middlebury", 741, 497, 1000.0, 0.19, near_m=1.0, far_m=8.0, max_ndisp=256),
}
"""The cameras by name: KITTI colour pair, Luxonis OAK-D (640x480), Middlebury 2014 quarter size."""


def get_camera(name: str) -> SynthCamera:
    """The registered camera ``name`` (the error lists the valid names)."""
    check_choice("camera", name, CAMERAS)
    return CAMERAS[name]


@dataclass(frozen=True)
class Pose:
    """Left camera pose: position (metres), pitch down and yaw (degrees)."""

    x: float
    y: float
    height_m: float
    pitch_deg: float
    yaw_deg: float = 0.0

    def rotation(self) -> np.ndarray:
        """Camera-to-world rotation, columns = camera x (right), y (down), z (forward) in the world."""
        p, y = math.radians(self.pitch_deg), math.radians(self.yaw_deg)
        fwd = np.array([math.sin(y) * math.cos(p), math.cos(y) * math.cos(p), -math.sin(p)])
        right = np.array([math.cos(y), -math.sin(y), 0.0])
        down = np.array([fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                         fwd[0] * right[1] - fwd[1] * right[0]])  # fwd x right (np.cross is slow)
        return np.stack([right, down, fwd], axis=1)

    def centre(self) -> np.ndarray:
        """The camera centre ``(x, y, height_m)`` in world metres."""
        return np.array([self.x, self.y, self.height_m])
