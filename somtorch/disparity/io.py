"""Readers and writers for disparity maps, images and instance masks in their real on-disk formats.

Everything format-specific ends here: a reader returns a float disparity map plus a boolean valid mask,
never a magic ``0`` or ``inf`` for "no disparity". Values at invalid pixels are set to ``0.0`` and are
meaningless; consumers must use ``valid``.

Formats (see ``../shared/data/README.md``):

* ``.pfm``: float32, rows stored bottom-to-top, header scale sign = endianness (its magnitude is
  ignored: Middlebury ``Motorcycle_Q`` writes ``-1/255`` but its floats already are pixels);
  ``inf``/``nan`` = no disparity. Read by :func:`read_pfm`, never by ``cv2.imread`` (it rejects the
  Freiburg header and divides by the scale magnitude).
* ``.png`` 16-bit (KITTI, OAK-D): ``d = value / 256``, ``0`` = no disparity.
* ``.npy`` / ``.npz``: a 2-D numeric array (key ``disparity``, ``disp`` or the only array).
* ``.tif`` / ``.tiff``: a single-channel float (32/64-bit) map in pixels, as many stereo tools write
  them (non-finite and negative values = no disparity); 16-bit integer TIFFs need ``scale``.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from somtorch.disparity.headers import (
    DEFLATE_RATIO,
    MAX_RATIO,
    OUT_BYTES_PER_PX,
    check_png,
    map_shape,
    tiff_cost,
    tiff_header,
)
from somtorch.disparity.npyfile import CHUNK_ITEMS, Stream, read_npy, read_npz
from somtorch.disparity.pfm import read_pfm, write_pfm
from somtorch.validation import DataFileError, require_file

__all__ = [
    "DISPARITY_SUFFIXES",
    "parse_middlebury_calib",
    "read_disparity",
    "read_image",
    "read_json",
    "read_mask",
    "read_pfm",
    "write_pfm",
]

log = logging.getLogger(__name__)

DISPARITY_SUFFIXES: tuple[str, ...] = (".pfm", ".png", ".npy", ".npz", ".tif", ".tiff")
"""File suffixes :func:`read_disparity` understands."""

_PNG16_SCALE = 1.0 / 256.0  # KITTI / OAK-D convention: d = value / 256


# ------------------------------------------------------------------------------------------ disparity


def read_disparity(
    path: str | Path, *, scale: float | None = None, invalid_value: float | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Read a disparity map and its valid mask, dispatching on the file suffix.

    A pixel is invalid if its value is non-finite, negative (negative disparities are removed, as in
    the paper), equal to ``invalid_value`` (compared with the stored value, before ``scale``), or — for
    PNG, where ``0`` codes "no disparity" — zero.

    The header is checked before any pixel is decoded (:mod:`somtorch.disparity.headers`: the pixel
    limit, a compression ratio real maps have, the memory budget); ``.npy`` / ``.npz`` / ``.pfm``
    data is converted as it is read, so the read holds at most about twice the arrays it returns.

    Args:
        path: ``.pfm``, ``.png`` (single channel), ``.npy``, ``.npz`` or float ``.tif`` / ``.tiff`` file.
        scale: multiplier from stored values to pixels. Default: ``1/256`` for 16-bit PNG (KITTI,
            OAK-D), ``1`` otherwise. 8-bit PNG has no standard encoding and needs an explicit ``scale``.
        invalid_value: an extra stored value that codes "no disparity" (e.g. ``-1`` in some ``.npy``).

    Returns:
        ``(disparity, valid)``: float32 pixels (``0.0`` at invalid pixels — meaningless, use ``valid``)
        and a bool mask.

    Raises:
        ValueError: unknown suffix (the message lists the supported ones).
        FileNotFoundError: ``path`` does not exist.
        DataFileError: the file cannot be decoded, is not a 2-D map, is an 8-bit PNG without ``scale``,
            or its header promises more pixels, memory or compression than a real map has.

    Shape:
        - disparity: :math:`(H, W)`, float32.
        - valid: :math:`(H, W)`, bool.
    """
    path = Path(path).expanduser()
    suffix = path.suffix.lower()
    if suffix not in DISPARITY_SUFFIXES:
        raise ValueError(f"{path}: unknown disparity file suffix {path.suffix!r}; supported: "
                         f"{', '.join(DISPARITY_SUFFIXES)}")
    if scale is not None and (isinstance(scale, bool) or not np.isfinite(scale) or scale <= 0):
        raise ValueError(f"scale must be a finite number > 0 (stored value * scale = pixels); got {scale!r}")
    path = require_file(path, "disparity file")
    zero_is_invalid = False
    source: np.ndarray | Stream
    if suffix == ".pfm":
        source = read_pfm(path)[0]
    elif suffix == ".png":
        source = _read_png_disparity(path, scale)
        zero_is_invalid = True
        if scale is None:
            scale = _PNG16_SCALE
    elif suffix == ".npy":
        source = read_npy(path)
    elif suffix in (".tif", ".tiff"):
        source = _read_tiff_disparity(path, scale)
    else:
        source = read_npz(path)
    out = None
    if isinstance(source, np.ndarray):
        if source.dtype == np.float32 and source.flags.c_contiguous and source.flags.writeable and source.ndim == 2:
            out = source  # a decoded float32 map is ours: converted in place, chunk by chunk
        source = _array_stream(path, source)
    return _to_map(source, 1.0 if scale is None else scale, zero_is_invalid, invalid_value, out)


def _array_stream(path: Path, a: np.ndarray) -> Stream:
    """A decoded array as a :class:`Stream` of flat chunks (views, no copy)."""
    h, w = map_shape(path, a.shape, a.dtype)
    flat = np.ascontiguousarray(a).reshape(-1)
    step = max(1, CHUNK_ITEMS // w) * w  # whole rows
    return Stream((h, w), a.dtype, False, (flat[i:i + step] for i in range(0, flat.size, step)))


def _to_map(src: Stream, scale: float, zero_is_invalid: bool, invalid_value: float | None,
            out: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Stored values -> (float32 pixels, valid), one chunk at a time (into ``out`` if given: the
    float32 array the chunks are views of, each chunk read before it is overwritten)."""
    disparity = np.empty(src.shape, np.float32) if out is None else out
    valid = np.empty(src.shape, np.bool_)
    # (lines, line length) views: rows, or columns for an array stored column-major
    d_lines, v_lines = (disparity.T, valid.T) if src.fortran else (disparity, valid)
    line, start = d_lines.shape[1], 0
    for raw in src.chunks:
        values = raw.astype(np.float64) * scale
        with np.errstate(over="ignore"):  # values beyond float32 become inf there: invalid, not a huge disparity
            ok = np.isfinite(values.astype(np.float32)) & (values >= 0)
        if zero_is_invalid:
            ok &= raw != 0
        if invalid_value is not None:
            ok &= raw != invalid_value
        end = start + raw.size // line
        d_lines[start:end] = np.where(ok, values, 0.0).reshape(-1, line)
        v_lines[start:end] = ok.reshape(-1, line)
        start = end
    return torch.from_numpy(disparity), torch.from_numpy(valid)


def _read_tiff_disparity(path: Path, scale: float | None) -> np.ndarray:
    header = tiff_header(path)
    if header.samples != 1:
        raise DataFileError(path, f"a disparity TIFF must have one channel; its header claims {header.samples}")
    tiff_cost(path, header, bytes_per_px=OUT_BYTES_PER_PX)
    img = _decode(path)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise DataFileError(path, f"a disparity TIFF must have one channel; got shape {img.shape}")
    if not np.issubdtype(img.dtype, np.floating) and scale is None:
        raise DataFileError(path, f"an integer ({img.dtype}) TIFF has no standard disparity encoding; give "
                                  "data.disparity_scale= on the command line (scale= in read_disparity; "
                                  "stored value * scale = pixels)")
    return img


def _read_png_disparity(path: Path, scale: float | None) -> np.ndarray:
    if not check_png(path, ratio=MAX_RATIO, bytes_per_px=OUT_BYTES_PER_PX):
        raise DataFileError(path, "cannot decode it as a PNG: it does not start with the PNG signature")
    img = _decode(path)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise DataFileError(path, f"a disparity PNG must have one channel; got shape {img.shape} "
                                  "(a colour PNG is a visualisation, not a disparity map)")
    if img.dtype == np.uint8 and scale is None:
        raise DataFileError(path, "8-bit PNG has no standard disparity encoding (KITTI and OAK-D store "
                                  "uint16 with d = value / 256); it is usually a visualisation whose scale "
                                  "is lost. If it really holds disparities, give the scale explicitly: "
                                  "data.disparity_scale=1.0 on the command line for integer pixels "
                                  "(scale=1.0 in read_disparity)")
    if img.dtype not in (np.uint8, np.uint16):
        raise DataFileError(path, f"unsupported PNG sample type {img.dtype}; expected uint16 (or uint8 "
                                  "with an explicit scale)")
    return img


# ----------------------------------------------------------------------------------- images and masks


def _decode(path: Path) -> np.ndarray:
    """OpenCV's decode of an image whose header was checked; its errors as DataFileError."""
    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error as e:
        raise DataFileError(path, f"OpenCV cannot decode this image: {str(e).strip().splitlines()[-1]}") from None
    except OSError as e:  # OpenCV 5's TIFF decoder raises some libtiff failures as a bare errno
        raise DataFileError(path, f"OpenCV cannot decode this image: {e.strerror or e}") from None
    if img is None:
        raise DataFileError(path, "OpenCV cannot decode this file as an image (corrupt, empty or not an "
                                  "image format)")
    return img


def _imread(path: Path) -> np.ndarray:
    """An image or mask: a PNG's header and stream are checked first (deflate's ratio; an int64
    copy of a mask per pixel held beside it), any other format is OpenCV's to decode."""
    check_png(path, ratio=DEFLATE_RATIO, bytes_per_px=8)
    return _decode(path)


def read_image(path: str | Path) -> torch.Tensor:
    """Read an image as RGB uint8, channels first.

    Grey images are replicated to 3 channels, an alpha channel is dropped, OpenCV's BGR order is turned
    into RGB, and 16-bit images are reduced to 8 bits (``value // 257``).

    Args:
        path: any image file OpenCV decodes (PNG, JPEG, ...).

    Returns:
        The image as a uint8 tensor.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        DataFileError: the file cannot be decoded or has an unsupported channel count or dtype.

    Shape:
        - Output: :math:`(3, H, W)`.
    """
    path = require_file(path, "image file")
    img = _imread(path)
    if img.dtype == np.uint16:
        img = (img // 257).astype(np.uint8)
    if img.dtype != np.uint8:
        raise DataFileError(path, f"unsupported image sample type {img.dtype}; expected uint8 or uint16")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]  # BGR -> RGB
    elif img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, 2::-1]  # BGRA -> RGB, alpha dropped
    else:
        raise DataFileError(path, f"unsupported image layout {img.shape}; expected grey, RGB or RGBA")
    return torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1)))  # (3, H, W)


def read_mask(path: str | Path) -> torch.Tensor:
    """Read an instance map (``0`` = background, ``1..n`` = object id).

    Args:
        path: a single-channel integer image (uint8 or uint16 PNG). A 3-channel file is accepted only
            if its channels are identical.

    Returns:
        The ids as an int64 tensor.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        DataFileError: the file cannot be decoded, has differing colour channels or a non-integer type.

    Shape:
        - Output: :math:`(H, W)`.
    """
    path = require_file(path, "mask file")
    img = _imread(path)
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[:, :, :3]
        if not all(np.array_equal(img[:, :, 0], img[:, :, c]) for c in range(1, img.shape[2])):
            raise DataFileError(path, f"an instance map must have one channel; got shape {img.shape} with "
                                      "differing channels (a colour overlay, not an id map?)")
        img = img[:, :, 0]
    if not np.issubdtype(img.dtype, np.integer):
        raise DataFileError(path, f"an instance map must hold integer ids; got dtype {img.dtype}")
    return torch.from_numpy(img.astype(np.int64))


# ------------------------------------------------------------------------------- calibration and json


def read_json(path: str | Path) -> dict[str, Any]:
    """Read a file holding one JSON object (``objects.json``, a calibration); bad JSON -> DataFileError."""
    path = require_file(path, "JSON file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataFileError(path, f"invalid JSON: {e}") from None
    except RecursionError:
        raise DataFileError(path, "invalid JSON: nested too deeply") from None
    except ValueError as e:  # e.g. integers of more than 4300 digits
        raise DataFileError(path, f"invalid JSON: {e}") from None
    if not isinstance(doc, dict):
        raise DataFileError(path, f"expected a JSON object at the top level; got {type(doc).__name__}")
    return doc


def parse_middlebury_calib(path: str | Path) -> dict[str, Any]:
    """Parse a Middlebury-format ``calib.txt`` (also used by ETH3D).

    Returns:
        ``key -> value``: matrices (``cam0=[f 0 cx; 0 f cy; 0 0 1]``) as float64 arrays of shape
        :math:`(3, 3)`, integers as ``int``, other numbers as ``float``, anything else as ``str``.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        DataFileError: a line is not ``key=value`` or a matrix is malformed.
    """
    path = require_file(path, "calibration file")
    out: dict[str, Any] = {}
    for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, value = line.partition("=")
        if not sep or not key.strip():
            raise DataFileError(path, f"line {n}: expected 'key=value'; got {line.strip()[:60]!r}")
        value = value.strip()
        if value.startswith("["):
            try:
                rows = [[float(x) for x in r.split()] for r in value.strip("[]").split(";")]
                out[key.strip()] = np.array(rows, dtype=np.float64)
            except ValueError:
                raise DataFileError(path, f"line {n}: malformed matrix {value[:60]!r}") from None
            if out[key.strip()].shape != (3, 3):
                raise DataFileError(path, f"line {n}: matrix {key.strip()} must be 3x3; got {value[:60]!r}")
            continue
        for cast in (int, float, str):
            try:
                out[key.strip()] = cast(value)
                break
            except ValueError:
                pass
    return out
