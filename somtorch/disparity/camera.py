"""The rectified stereo camera of a scene and the per-data-set calibration readers.

:class:`Camera` holds the left view's pinhole parameters and the stereo baseline
(``Z = baseline * focal_px / (d + doffs)``). :func:`read_middlebury_camera` reads a Middlebury/ETH3D
``calib.txt``; the private ``_<layout>_camera(folder, hw)`` loaders give
:func:`~somtorch.disparity.scene.load_scene` the camera of each known folder layout, checking the
calibration's image size against the disparity's and raising
:class:`~somtorch.validation.DataFileError` naming the file.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from somtorch.disparity.io import parse_middlebury_calib, read_json
from somtorch.validation import DataFileError, check_choice, check_positive, check_tensor

__all__ = ["Camera", "read_middlebury_camera"]

log = logging.getLogger(__name__)

_BASELINE_UNITS = {"m": 1.0, "mm": 1e-3, "unit": None}  # unit -> metres per unit (None: not metric)


@dataclass(frozen=True)
class Camera:
    """Rectified stereo camera of the left view: ``Z = baseline * focal_px / (d + doffs)``.

    Attributes:
        focal_px: focal length in pixels (``fx = fy``).
        cx: principal point column, pixels.
        cy: principal point row, pixels.
        baseline: distance between the optical centres, in ``baseline_unit``.
        baseline_unit: ``"m"``, ``"mm"`` or ``"unit"`` (synthetic scenes whose units are not metric).
        doffs: disparity offset ``cx_right - cx_left`` in pixels (Middlebury convention).
        approximate: True where the calibration is a typical value, not this scene's (KITTI demo).
    """

    focal_px: float
    cx: float
    cy: float
    baseline: float
    baseline_unit: str = "m"
    doffs: float = 0.0
    approximate: bool = False

    def __post_init__(self) -> None:
        check_positive("focal_px", self.focal_px)
        check_positive("baseline", self.baseline)
        for name in ("cx", "cy", "doffs"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"Camera.{name} must be a finite number; got {value!r}")
        check_choice("baseline_unit", self.baseline_unit, _BASELINE_UNITS)
        for name in ("focal_px", "cx", "cy", "baseline", "doffs"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def baseline_m(self) -> float | None:
        """Baseline in metres, or None for non-metric (``"unit"``) cameras."""
        to_m = _BASELINE_UNITS[self.baseline_unit]
        return None if to_m is None else self.baseline * to_m

    def depth(self, disparity: torch.Tensor) -> torch.Tensor:
        """Depth ``baseline * focal_px / (d + doffs)`` in the unit of ``baseline``.

        Only meaningful at valid pixels; where ``d + doffs <= 0`` the result is ``+inf``.

        Shape:
            - disparity: any shape, floating point.
            - Output: same shape, dtype and device.

        Example:
            >>> Camera(focal_px=100.0, cx=0.0, cy=0.0, baseline=0.5).depth(torch.tensor([10.0, 0.0]))
            tensor([5., inf])
        """
        check_tensor("disparity", disparity, floating=True, nonempty=False)
        den = disparity + self.doffs
        return torch.where(den > 0, (self.baseline * self.focal_px) / den, torch.full_like(den, math.inf))

    def intrinsics(self, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
                   ) -> torch.Tensor:
        """Pinhole matrix ``K`` of the left view.

        Shape:
            - Output: :math:`(3, 3)`.
        """
        return torch.tensor([[self.focal_px, 0.0, self.cx], [0.0, self.focal_px, self.cy], [0.0, 0.0, 1.0]],
                            dtype=dtype, device=device)

    def scaled(self, factor: float) -> Camera:
        """The camera for images resized by ``factor``: ``focal_px``, ``cx``, ``cy``, ``doffs`` times it.

        Plain multiplication, as Middlebury and scikit-image scale their calibrations.
        """
        check_positive("factor", factor)
        return replace(self, focal_px=self.focal_px * factor, cx=self.cx * factor, cy=self.cy * factor,
                       doffs=self.doffs * factor)


# -------------------------------------------------------------------------------------- calibrations


def read_middlebury_camera(path: str | Path) -> Camera:
    """:class:`Camera` from a Middlebury/ETH3D ``calib.txt`` (baseline in mm); ``doffs`` from the file,
    else ``cam1.cx - cam0.cx``, else 0."""
    calib = parse_middlebury_calib(path)
    missing = [k for k in ("cam0", "baseline") if k not in calib]
    if missing:
        raise DataFileError(path, f"calibration lacks {missing}; found keys {sorted(calib)}")
    for key in ("cam0", "cam1"):
        m = calib.get(key)
        if key in calib and not (isinstance(m, np.ndarray) and m.shape == (3, 3)):
            raise DataFileError(path, f"field {key!r} must be a 3x3 matrix like [f 0 cx; 0 f cy; 0 0 1]; got {m!r}")
    k0 = calib["cam0"]
    doffs = calib.get("doffs", float(calib["cam1"][0, 2] - k0[0, 2]) if "cam1" in calib else 0.0)
    return _camera(path, focal_px=float(k0[0, 0]), cx=float(k0[0, 2]), cy=float(k0[1, 2]),
                   baseline=calib["baseline"], baseline_unit="mm", doffs=doffs)


def _camera(path: Path | str, **kwargs: Any) -> Camera:
    try:
        return Camera(**kwargs)
    except (TypeError, ValueError) as e:
        raise DataFileError(path, f"invalid calibration: {e}") from None


def _check_calib_size(path: Path, calib_hw: tuple[Any, Any], hw: tuple[int, int]) -> None:
    if tuple(calib_hw) != hw:
        raise DataFileError(path, f"calibration is for {calib_hw[0]}x{calib_hw[1]} (HxW) but the disparity "
                                  f"is {hw[0]}x{hw[1]}")


def _middlebury_camera(folder: Path, hw: tuple[int, int]) -> tuple[Camera | None, str | None]:
    path = folder / "calib.txt"
    if not path.is_file():
        return None, None
    calib = parse_middlebury_calib(path)
    _check_calib_size(path, (calib.get("height", hw[0]), calib.get("width", hw[1])), hw)
    return read_middlebury_camera(path), str(path)


def _kitti_camera(folder: Path, hw: tuple[int, int]) -> tuple[Camera | None, str | None]:
    # typical rectified KITTI colour camera (P2/P3 of the raw calibration); the devkit demo ships none
    cam = Camera(focal_px=721.5, cx=hw[1] / 2, cy=hw[0] / 2, baseline=0.54, baseline_unit="m",
                 approximate=True)
    return cam, "KITTI typical values (approximate)"


def _sceneflow_camera(folder: Path, hw: tuple[int, int]) -> tuple[Camera | None, str | None]:
    if hw != (540, 960):
        log.warning("%s: the SceneFlow camera constants are for 540x960 (HxW); this scene is %dx%d",
                    folder, *hw)
    cam = Camera(focal_px=1050.0, cx=479.5, cy=269.5, baseline=1.0, baseline_unit="unit")
    return cam, "FlyingThings3D constants"


def _oakd_camera(folder: Path, hw: tuple[int, int]) -> tuple[Camera | None, str | None]:
    path = folder / "stereodemo_calibration.json"
    if not path.is_file():
        return None, None
    calib = read_json(path)
    missing = [k for k in ("width", "height", "fx", "cx0", "cx1", "cy", "baseline_meters") if k not in calib]
    if missing:
        raise DataFileError(path, f"calibration lacks {missing}; found keys {sorted(calib)}")
    bad = [k for k in ("width", "height", "fx", "cx0", "cx1", "cy", "baseline_meters")
           if isinstance(calib[k], bool) or not isinstance(calib[k], int | float)]
    if bad:
        raise DataFileError(path, f"calibration field(s) {bad} must be numbers; got "
                                  f"{ {k: calib[k] for k in bad} }")
    _check_calib_size(path, (calib["height"], calib["width"]), hw)
    cam = _camera(path, focal_px=calib["fx"], cx=calib["cx0"], cy=calib["cy"],
                  baseline=calib["baseline_meters"], baseline_unit="m", doffs=calib["cx1"] - calib["cx0"])
    return cam, str(path)
