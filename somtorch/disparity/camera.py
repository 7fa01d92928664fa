"""The rectified stereo camera of a scene and the per-data-set calibration readers.

:class:`Camera` holds the left view's pinhole parameters and the stereo baseline
(``Z = baseline * focal_px / (d + doffs)``). :func:`read_middlebury_camera` reads a Middlebury/ETH3D
``calib.txt``; the private ``_<layout>_camera(folder, hw)`` loaders give
:func:`~somtorch.disparity.loading.load_scene` the camera of each known folder layout, checking the
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
from somtorch.validation import DataFileError, check_choice, check_positive, check_tensor, require_file

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
    return _oakd_from(path, read_json(path), hw)


def _oakd_from(path: Path, calib: dict, hw: tuple[int, int]) -> tuple[Camera, str]:
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


def _kitti_calib_file(path: Path) -> Camera:
    """KITTI ``calib_cam_to_cam.txt`` (``P_rect_02`` / ``P_rect_03``, the colour pair) or a per-frame
    ``calib/000000.txt`` (``P2`` / ``P3``): f, cx, cy of the left and the baseline in metres."""
    rows: dict[str, np.ndarray] = {}
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines()[:200]:
        if ":" not in line:
            continue
        key, _, rest = line.partition(":")
        try:
            values = np.array([float(v) for v in rest.split()], dtype=np.float64)
        except ValueError:
            continue
        if values.size == 12 and np.isfinite(values).all():
            rows[key.strip()] = values.reshape(3, 4)
    pair = next(((a, b) for a, b in (("P_rect_02", "P_rect_03"), ("P2", "P3")) if a in rows and b in rows), None)
    if pair is None:
        raise DataFileError(path, "a KITTI calibration needs P_rect_02 and P_rect_03 (calib_cam_to_cam.txt) or "
                                  f"P2 and P3 (per-frame calib); found {sorted(rows)}")
    p2, p3 = rows[pair[0]], rows[pair[1]]
    if p2[0, 0] <= 0 or p3[0, 0] <= 0:
        raise DataFileError(path, f"{pair[0]} / {pair[1]} have a focal length <= 0")
    baseline = (p2[0, 3] / p2[0, 0]) - (p3[0, 3] / p3[0, 0])  # metres: P[0,3] = -f * t_x
    return _camera(path, focal_px=float(p2[0, 0]), cx=float(p2[0, 2]), cy=float(p2[1, 2]),
                   baseline=float(baseline), baseline_unit="m", doffs=float(p3[0, 2] - p2[0, 2]))


def read_calibration(path: str | Path, hw: tuple[int, int] | None = None) -> Camera:
    """The :class:`Camera` of a calibration file in any of the formats its users have: an OAK-D /
    stereodemo ``stereodemo_calibration.json``, a Middlebury / ETH3D ``calib.txt`` (``cam0=[...]``),
    or a KITTI ``calib_cam_to_cam.txt`` / per-frame ``calib/*.txt``. ``hw``: the image size, checked
    where the file states one.

    Raises:
        DataFileError: not one of these formats, or a field is missing or malformed (named).
        FileNotFoundError: no such file.
    """
    p = require_file(path, "calibration file")
    head = p.read_bytes()[:4096].decode("utf-8", errors="replace")
    if head.lstrip().startswith("{"):
        calib = read_json(p)
        if "fx" not in calib and "baseline_meters" not in calib:
            raise DataFileError(p, "a JSON calibration must be in the stereodemo format (fx, cx0, cx1, cy, "
                                   f"baseline_meters, width, height); found keys {sorted(calib)[:10]}")
        if hw is None:
            hw = (calib.get("height"), calib.get("width"))
        return _oakd_from(p, calib, hw)[0]
    if "cam0" in head:
        if hw is not None:
            calib = parse_middlebury_calib(p)
            _check_calib_size(p, (calib.get("height", hw[0]), calib.get("width", hw[1])), hw)
        return read_middlebury_camera(p)
    if "P_rect_02" in head or "P2:" in head:
        return _kitti_calib_file(p)
    raise DataFileError(p, "not a calibration this reads: expected stereodemo JSON (fx, baseline_meters ...), "
                           "Middlebury calib.txt (cam0=[...], baseline=) or KITTI (P_rect_02/P_rect_03 or P2/P3)")
