"""Where a run's disparity comes from and where it writes (``data.*``, ``paths.*``): plain
dataclasses without torch or Hydra, so ``--help`` lists them at once. ``experiments.schema`` adds
the StereoSGBM settings (``data.sgbm.*``) and registers the tree with Hydra."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

MISSING = "???"  # OmegaConf's mandatory value: a conf/data option must set it


@dataclass
class DataSource:
    """Where the disparity comes from.

    ``source``: ``"motorcycle"`` (the embedded Middlebury scene of scikit-image), a scene folder
    (every layout of ../shared/data) or a disparity file (PFM, 16-bit PNG, NPY, NPZ). With ``left``
    and ``right`` set instead, the disparity is computed with OpenCV StereoSGBM (``data.sgbm.*``).
    Every ``conf/data`` option sets ``source``, ``left`` and ``right`` (null where unused), so a
    missing mandatory value (``???``) fails at composition.

    Attributes:
        source: the embedded scene's name ("motorcycle"), a scene folder or a disparity file (PFM, 16-bit PNG, NPY/NPZ, TIFF); null for a stereo pair.
        disparity_file: the disparity file inside a scene folder when it holds several (null = the folder's usual one).
        disparity_scale: stored value x scale = pixels (null = the format's own: 1/256 for 16-bit PNG, 1 otherwise; needed for 8-bit PNG and integer TIFF; 0.25 for Middlebury 2003 disp2.png).
        left: left image of a rectified stereo pair (disparity by StereoSGBM); null for a disparity input.
        right: right image of the pair.
        name: the scene's name in output folders and tables (null = from the source).
        focal_px: camera focal length in px (point clouds need a camera; null = the scene's own or no cloud).
        baseline: stereo baseline, in baseline_unit.
        baseline_unit: unit of baseline ("m" or "mm"), carried into the PLY header.
        cx: principal point x in px (null = the image centre).
        cy: principal point y in px (null = the image centre).
        doffs: x-difference of the principal points in px (Middlebury's doffs).
        calibration: one calibration file (stereodemo JSON, Middlebury/ETH3D calib.txt, KITTI calib_cam_to_cam.txt); replaces the folder's own camera.
        frame: the frame number in the official KITTI 2015 layout (source = its training folder).
        family: a generated frame (data=synthetic, somtorch.synth): stairs, garden, road, room, tabletop, hands, fence or clutter.
        camera: the generated frame's camera: oakd, kitti or middlebury.
        seed: the generated frame's seed.
        version: the generated frame's disparity: gt or sgbm.
    """

    source: Optional[str] = MISSING
    disparity_file: Optional[str] = None
    disparity_scale: Optional[float] = None
    left: Optional[str] = MISSING
    right: Optional[str] = MISSING
    name: Optional[str] = None
    focal_px: Optional[float] = None
    baseline: Optional[float] = None
    baseline_unit: str = "m"
    cx: Optional[float] = None
    cy: Optional[float] = None
    doffs: float = 0.0
    calibration: Optional[str] = None
    frame: Optional[str] = None
    family: Optional[str] = None
    camera: Optional[str] = None
    seed: Optional[int] = None
    version: Optional[str] = None


@dataclass
class PathsConfig:
    """All paths in one place (relative paths resolve against the directory the command starts in).

    Attributes:
        data_dir: the shared data folder (../shared/data; env SOMTORCH_DATA).
        output_dir: where runs and studies write (outputs; env SOMTORCH_OUTPUT).
    """

    data_dir: str = "../shared/data"
    output_dir: str = "outputs"
