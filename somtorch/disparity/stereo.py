"""Disparity from a rectified stereo pair with OpenCV's semi-global block matching (StereoSGBM).

:class:`SGBMParams` holds the matcher's hyper-parameters under OpenCV's own names, so a stored
``sgbm_params.json`` (as next to the OAK-D scenes in ``../shared/data``) loads with
:meth:`SGBMParams.from_dict`. :func:`compute_disparity` returns a float disparity plus a valid mask,
never OpenCV's fixed-point codes.
"""

from __future__ import annotations

import dataclasses
import logging
import numbers
from collections.abc import Mapping
from pathlib import Path
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import torch

from somtorch.disparity.scene import Camera, Scene, scene_from_arrays
from somtorch.validation import DataFileError, check_choice

__all__ = ["SGBM_MODES", "SGBMParams", "compute_disparity", "scene_from_stereo"]

log = logging.getLogger(__name__)

SGBM_MODES: dict[str, int] = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "hh": cv2.StereoSGBM_MODE_HH,
    "sgbm_3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh4": cv2.StereoSGBM_MODE_HH4,
}
"""Mode names accepted by :class:`SGBMParams` and the OpenCV constants they stand for."""

_FIXED_POINT = 16  # StereoSGBM returns disparity * 16 as int16


@dataclass(frozen=True)
class SGBMParams:
    """StereoSGBM hyper-parameters (OpenCV names; defaults reproduce the shipped OAK-D maps).

    Attributes:
        minDisparity: smallest disparity searched, pixels.
        numDisparities: number of disparities searched; a positive multiple of 16.
        blockSize: matched block size; odd, >= 1.
        P1: smoothness penalty for disparity changes of 1; None = ``8 * channels * blockSize**2``.
        P2: penalty for larger changes (> P1); None = ``32 * channels * blockSize**2``.
        disp12MaxDiff: maximum left-right check difference in pixels; negative disables the check.
        uniquenessRatio: margin in percent by which the best cost must win.
        speckleWindowSize: largest speckle region removed (0 disables speckle filtering).
        speckleRange: maximum disparity variation inside a connected component (OpenCV multiplies by 16).
        mode: one of :data:`SGBM_MODES` (``"sgbm_3way"``, ``"sgbm"``, ``"hh"``, ``"hh4"``).
    """

    minDisparity: int = 0
    numDisparities: int = 128
    blockSize: int = 5
    P1: int | None = 200
    P2: int | None = 800
    disp12MaxDiff: int = 1
    uniquenessRatio: int = 10
    speckleWindowSize: int = 100
    speckleRange: int = 2
    mode: str = "sgbm_3way"

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "mode" or (f.name in ("P1", "P2") and value is None):
                continue
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise TypeError(f"SGBMParams.{f.name} must be an int; got {type(value).__name__} {value!r}")
        for f in dataclasses.fields(self):  # OpenCV takes C ints: larger values overflow inside it
            value = getattr(self, f.name)
            if isinstance(value, numbers.Integral) and not -(2**31) <= value < 2**31:
                raise ValueError(f"SGBMParams.{f.name}={value} does not fit a 32-bit int")
        if self.numDisparities <= 0 or self.numDisparities % 16:
            raise ValueError(f"SGBMParams.numDisparities must be a positive multiple of 16; got "
                             f"{self.numDisparities} (try {max(16, (self.numDisparities + 15) // 16 * 16)})")
        if self.blockSize < 1 or self.blockSize % 2 == 0:
            raise ValueError(f"SGBMParams.blockSize must be odd and >= 1; got {self.blockSize}")
        for name in ("P1", "P2", "uniquenessRatio", "speckleWindowSize", "speckleRange"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise ValueError(f"SGBMParams.{name} must be >= 0; got {value}")
        if self.P1 is not None and self.P2 is not None and self.P2 <= self.P1:
            raise ValueError(f"SGBMParams.P2 must be larger than P1; got P1={self.P1}, P2={self.P2}")
        check_choice("SGBMParams.mode", self.mode, SGBM_MODES)

    @classmethod
    def from_dict(cls, params: Mapping[str, Any]) -> SGBMParams:
        """Build from a mapping such as a loaded ``sgbm_params.json``.

        ``mode`` may be a name or OpenCV's integer constant (``2`` = ``"sgbm_3way"``).
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(params) - names)
        if unknown:
            raise ValueError(f"unknown SGBM parameter(s) {unknown}; known: {sorted(names)}")
        kwargs = dict(params)
        mode = kwargs.get("mode")
        if isinstance(mode, numbers.Integral) and not isinstance(mode, bool):
            by_code = {code: name for name, code in SGBM_MODES.items()}
            if mode not in by_code:
                raise ValueError(f"unknown OpenCV StereoSGBM mode code {mode}; known: {by_code}")
            kwargs["mode"] = by_code[int(mode)]
        return cls(**kwargs)

    def create_matcher(self, channels: int = 1) -> cv2.StereoSGBM:
        """The OpenCV matcher, with default P1/P2 resolved for ``channels`` image channels."""
        area = channels * self.blockSize**2
        return cv2.StereoSGBM_create(
            minDisparity=self.minDisparity, numDisparities=self.numDisparities, blockSize=self.blockSize,
            P1=8 * area if self.P1 is None else self.P1, P2=32 * area if self.P2 is None else self.P2,
            disp12MaxDiff=self.disp12MaxDiff, uniquenessRatio=self.uniquenessRatio,
            speckleWindowSize=self.speckleWindowSize, speckleRange=self.speckleRange,
            mode=SGBM_MODES[self.mode])


def _to_hwc_uint8(name: str, image: torch.Tensor | np.ndarray) -> np.ndarray:
    """uint8 ``(H, W)`` or ``(H, W, C)`` array for OpenCV; tensors are channels-first."""
    if isinstance(image, torch.Tensor):
        a = image.detach().cpu().numpy()
        if a.ndim == 3:
            a = a.transpose(1, 2, 0)  # (C, H, W) -> (H, W, C)
    elif isinstance(image, np.ndarray):
        a = image
    else:
        raise TypeError(f"{name} must be a torch.Tensor or numpy.ndarray; got {type(image).__name__}")
    if a.dtype != np.uint8:
        raise TypeError(f"{name} must be uint8 (StereoSGBM matches 8-bit images); got dtype {a.dtype}")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or a.size == 0:
        raise ValueError(f"{name} must be a grey or 3-channel image: tensor (H, W)/(3, H, W) or array "
                         f"(H, W)/(H, W, 3); got shape {tuple(image.shape)}")
    return np.ascontiguousarray(a)


def compute_disparity(
    left: torch.Tensor | np.ndarray,
    right: torch.Tensor | np.ndarray,
    params: SGBMParams | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Disparity of the left view of a rectified pair with OpenCV StereoSGBM.

    Colour images are matched as colour (the cost sums over channels, so channel order does not
    matter). A pixel is invalid where OpenCV returns its "no match" code (below ``minDisparity``) or
    a disparity ``<= 0``; there ``disparity`` is ``0.0`` and meaningless.

    Args:
        left: uint8 left image; a tensor ``(3, H, W)``/``(H, W)`` or a numpy array ``(H, W, 3)``/``(H, W)``.
        right: uint8 right image, same shape as ``left``.
        params: matcher settings; default :class:`SGBMParams()`.

    Returns:
        ``(disparity, valid)``: float32 pixels (OpenCV's fixed point divided by 16) and a bool mask.

    Raises:
        TypeError: not uint8 tensors/arrays.
        ValueError: unsupported shape, or ``left`` and ``right`` differ in shape.

    Shape:
        - left, right: tensors :math:`(3, H, W)` / :math:`(H, W)`; arrays :math:`(H, W, 3)` / :math:`(H, W)`.
        - disparity, valid: :math:`(H, W)`.
    """
    params = SGBMParams() if params is None else params
    if not isinstance(params, SGBMParams):
        raise TypeError(f"params must be an SGBMParams; got {type(params).__name__} "
                        "(build one with SGBMParams.from_dict)")
    lt, rt = _to_hwc_uint8("left", left), _to_hwc_uint8("right", right)
    if lt.shape != rt.shape:
        raise ValueError(f"left and right must have the same shape; got left {tuple(left.shape)}, "
                         f"right {tuple(right.shape)}")
    if lt.shape[1] <= params.minDisparity + params.numDisparities:
        raise ValueError(f"the images are {lt.shape[1]} px wide but minDisparity + numDisparities = "
                         f"{params.minDisparity + params.numDisparities}: no pixel can be matched (OpenCV would "
                         "fail to allocate); lower numDisparities below the image width")
    if params.blockSize > min(lt.shape[:2]):
        raise ValueError(f"SGBMParams.blockSize={params.blockSize} is larger than the images "
                         f"({lt.shape[0]}x{lt.shape[1]}); use a smaller odd block size")
    channels = 1 if lt.ndim == 2 else lt.shape[2]
    raw = params.create_matcher(channels).compute(lt, rt)  # (H, W) int16, disparity * 16
    valid = (raw >= params.minDisparity * _FIXED_POINT) & (raw > 0)
    disparity = np.where(valid, raw.astype(np.float32) / _FIXED_POINT, np.float32(0.0))
    return torch.from_numpy(disparity), torch.from_numpy(valid)


def scene_from_stereo(
    left: torch.Tensor | np.ndarray,
    right: torch.Tensor | np.ndarray,
    params: SGBMParams | None = None,
    camera: Camera | None = None,
    *,
    name: str = "stereo",
) -> Scene:
    """A :class:`Scene` whose disparity is computed from a stereo pair by :func:`compute_disparity`.

    The left image (grey replicated to RGB) becomes :attr:`Scene.image`.

    Raises:
        ValueError: as :func:`compute_disparity`, or if no pixel could be matched.

    Shape:
        - left, right: as :func:`compute_disparity`.
    """
    params = SGBMParams() if params is None else params
    disparity, valid = compute_disparity(left, right, params)
    image = _to_hwc_uint8("left", left)
    return scene_from_arrays(disparity, valid, image=image, camera=camera, name=name,
                             source={"disparity": f"StereoSGBM {dataclasses.asdict(params)}",
                                     "image": "left image of the pair", "layout": "stereo"})


def load_stereo_pair(left: str | Path, right: str | Path, params: SGBMParams | None = None,
                     camera: Camera | None = None, *, name: str | None = None) -> Scene:
    """Read a rectified pair from its two files and compute the :class:`Scene` (every error names
    the file it is about: an unreadable image, two sizes that do not match, an image too narrow
    for the disparity range).

    Raises:
        DataFileError: the files cannot be used as a pair.
        FileNotFoundError: a file is missing.
    """
    from .io import read_image

    params = SGBMParams() if params is None else params
    lt, rt = read_image(left), read_image(right)
    if tuple(lt.shape) != tuple(rt.shape):
        raise DataFileError(right, f"is {rt.shape[-1]}x{rt.shape[-2]} px ({rt.shape[0]} channel(s)) but the left "
                                   f"image {left} is {lt.shape[-1]}x{lt.shape[-2]} ({lt.shape[0]}): a rectified "
                                   "pair has one size")
    try:
        return scene_from_stereo(lt, rt, params, camera, name=name or Path(left).stem)
    except ValueError as e:
        raise DataFileError(left, f"with {Path(right).name}: {e}") from None
