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
import os
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

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

_NPZ_KEYS = ("disparity", "disp")
_PNG16_SCALE = 1.0 / 256.0  # KITTI / OAK-D convention: d = value / 256


# ------------------------------------------------------------------------------------------ disparity


def read_disparity(
    path: str | Path, *, scale: float | None = None, invalid_value: float | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Read a disparity map and its valid mask, dispatching on the file suffix.

    A pixel is invalid if its value is non-finite, negative (negative disparities are removed, as in
    the paper), equal to ``invalid_value`` (compared with the stored value, before ``scale``), or — for
    PNG, where ``0`` codes "no disparity" — zero.

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
        DataFileError: the file cannot be decoded, is not a 2-D map, or is an 8-bit PNG without ``scale``.

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
    if suffix == ".pfm":
        raw: np.ndarray = read_pfm(path)[0]
    elif suffix == ".png":
        raw = _read_png_disparity(path, scale)
        zero_is_invalid = True
        if scale is None:
            scale = _PNG16_SCALE
    elif suffix == ".npy":
        raw = _load_npy(path)
    elif suffix in (".tif", ".tiff"):
        raw = _read_tiff_disparity(path, scale)
    else:
        raw = _load_npz(path)
    raw = _as_2d_numeric(path, raw)
    values = raw.astype(np.float64) * (1.0 if scale is None else scale)  # (H, W)
    with np.errstate(over="ignore"):  # values beyond float32 become inf there: invalid, not a huge disparity
        valid = np.isfinite(values.astype(np.float32)) & (values >= 0)
    if zero_is_invalid:
        valid &= raw != 0
    if invalid_value is not None:
        valid &= raw != invalid_value
    disparity = np.where(valid, values, 0.0).astype(np.float32)
    return torch.from_numpy(disparity), torch.from_numpy(valid)


def _read_tiff_disparity(path: Path, scale: float | None) -> np.ndarray:
    img = _imread(path)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise DataFileError(path, f"a disparity TIFF must have one channel; got shape {img.shape}")
    if img.size > MAX_PIXELS:
        raise DataFileError(path, f"{img.shape[1]}x{img.shape[0]} px is above the limit of {MAX_PIXELS:,} "
                                  "(SOMTORCH_MAX_PIXELS)")
    if not np.issubdtype(img.dtype, np.floating) and scale is None:
        raise DataFileError(path, f"an integer ({img.dtype}) TIFF has no standard disparity encoding; give "
                                  "data.disparity_scale= on the command line (scale= in read_disparity; "
                                  "stored value * scale = pixels)")
    return img


def _read_png_disparity(path: Path, scale: float | None) -> np.ndarray:
    img = _imread(path)
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


# what numpy and zipfile raise on corrupt, truncated, encrypted or mis-named .npy / .npz files
_NUMPY_READ_ERRORS = (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError,
                      RuntimeError, tokenize.TokenError, SyntaxError, AttributeError, KeyError, MemoryError)


MAX_PIXELS = int(os.environ.get("SOMTORCH_MAX_PIXELS", 200_000_000))
"""Largest map (H·W, or array elements) a reader accepts; checked from the file's header before any
pixel is read (``SOMTORCH_MAX_PIXELS`` overrides it)."""


def _check_npy_header(path: Path, f: Any) -> None:
    """Read the .npy header of the open file ``f`` and refuse shapes beyond :data:`MAX_PIXELS`."""
    fmt = np.lib.format
    try:
        major, _ = fmt.read_magic(f)
        shape, _, dtype = (fmt.read_array_header_1_0(f) if major == 1 else fmt.read_array_header_2_0(f))
    except _NUMPY_READ_ERRORS as e:
        raise DataFileError(path, f"bad .npy header: {type(e).__name__}: {e}") from None
    n = int(np.prod(shape, dtype=np.float64)) if shape else 1
    if n > MAX_PIXELS or n * max(dtype.itemsize, 1) > 8 * MAX_PIXELS:
        raise DataFileError(path, f"the array header claims shape {shape} ({n:,} elements of {dtype}); the "
                                  f"limit is {MAX_PIXELS:,} (SOMTORCH_MAX_PIXELS)")


def _load_npy(path: Path) -> np.ndarray:
    with open(path, "rb") as f:
        if f.read(6) == b"\x93NUMPY":
            f.seek(0)
            _check_npy_header(path, f)
    try:
        a = np.load(path, allow_pickle=False)
    except _NUMPY_READ_ERRORS as e:
        raise DataFileError(path, f"cannot read .npy: {type(e).__name__}: {e}") from None
    if not isinstance(a, np.ndarray):  # an .npz archive under a .npy name
        raise DataFileError(path, "is a zip archive (.npz), not a .npy array; rename it to .npz")
    return a


def _load_npz(path: Path) -> np.ndarray:
    try:
        data = np.load(path, allow_pickle=False)
    except _NUMPY_READ_ERRORS as e:
        raise DataFileError(path, f"cannot read .npz: {type(e).__name__}: {e}") from None
    if isinstance(data, np.ndarray):  # a plain .npy under a .npz name
        return data
    with data:
        try:  # sizes from the zip directory and the member's header, before inflating anything
            for info in data.zip.infolist():
                if info.file_size > 8 * MAX_PIXELS + 4096:
                    raise DataFileError(path, f"member {info.filename!r} inflates to {info.file_size:,} bytes; the "
                                              f"limit is {8 * MAX_PIXELS + 4096:,} (SOMTORCH_MAX_PIXELS)")
        except AttributeError:
            pass
        keys = list(data.files)
        if not keys:
            raise DataFileError(path, "the .npz archive contains no arrays; expected one named "
                                      f"{' or '.join(_NPZ_KEYS)}")
        key = next((k for k in _NPZ_KEYS if k in keys), keys[0] if len(keys) == 1 else None)
        if key is None:
            raise DataFileError(path, f"cannot tell which array is the disparity: keys {keys}; "
                                      f"name it {' or '.join(_NPZ_KEYS)}, or store a single array")
        try:
            with data.zip.open(key + ".npy") as member:
                _check_npy_header(path, member)
        except KeyError:
            pass
        except _NUMPY_READ_ERRORS as e:
            raise DataFileError(path, f"cannot read array {key!r} from the .npz: {type(e).__name__}: {e}") from None
        try:
            arr = data[key]
        except _NUMPY_READ_ERRORS as e:
            raise DataFileError(path, f"cannot read array {key!r} from the .npz: {type(e).__name__}: {e}") from None
        if not isinstance(arr, np.ndarray):
            raise DataFileError(path, f"member {key!r} of the .npz is not an array")
        return arr


def _as_2d_numeric(path: Path, a: np.ndarray) -> np.ndarray:
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim != 2:
        raise DataFileError(path, f"a disparity map must be 2-D (H, W); got shape {a.shape}")
    if a.size == 0:
        raise DataFileError(path, f"the disparity map is empty (shape {a.shape})")
    if a.dtype == np.bool_ or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise DataFileError(path, f"a disparity map must hold real numbers; got dtype {a.dtype}")
    return a


# ----------------------------------------------------------------------------------- images and masks


def _check_png_header(path: Path) -> None:
    """Refuse a PNG whose IHDR claims more than :data:`MAX_PIXELS` before OpenCV decodes it."""
    with open(path, "rb") as f:
        head = f.read(26)
        size = os.fstat(f.fileno()).st_size
    if not head.startswith(b"\x89PNG\r\n\x1a\n"):
        return  # not a PNG: OpenCV decides
    if len(head) < 26 or head[12:16] != b"IHDR":
        raise DataFileError(path, "truncated or corrupt PNG: no IHDR chunk")
    w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if w == 0 or h == 0 or w * h > MAX_PIXELS:
        raise DataFileError(path, f"the PNG header claims {w}x{h} px; the limit is {MAX_PIXELS:,} px "
                                  "(SOMTORCH_MAX_PIXELS)")
    channels = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}.get(head[25])
    if channels is None or head[24] not in (1, 2, 4, 8, 16):
        raise DataFileError(path, f"corrupt PNG header: bit depth {head[24]}, colour type {head[25]}")
    raw = h * ((w * channels * head[24] + 7) // 8 + 1)  # bytes of the filtered image data
    if raw > 1100 * size + 65536:  # deflate compresses at most ~1032:1
        raise DataFileError(path, f"a {size:,}-byte PNG cannot hold the {w}x{h} image its header claims "
                                  "(truncated or corrupt)")
    _check_png_chunks(path)


def _check_png_chunks(path: Path) -> None:
    """Walk the chunks and verify their CRCs: a corrupt PNG is refused here, in microseconds, rather
    than inside the decoder (which can take seconds on some corruptions)."""
    data = path.read_bytes()
    pos, n = 8, len(data)
    while pos < n:
        if pos + 12 > n:
            raise DataFileError(path, f"truncated PNG: chunk header at byte {pos}")
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if length > 2**31 - 1 or end > n:
            raise DataFileError(path, f"truncated or corrupt PNG: chunk {kind!r} at byte {pos} claims {length:,} bytes")
        if zlib.crc32(data[pos + 4:pos + 8 + length]) != int.from_bytes(data[end - 4:end], "big"):
            raise DataFileError(path, f"corrupt PNG: CRC mismatch in chunk {kind!r} at byte {pos}")
        if kind == b"IEND":
            return
        pos = end
    raise DataFileError(path, "truncated PNG: no IEND chunk")


def _imread(path: Path) -> np.ndarray:
    _check_png_header(path)
    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error as e:
        raise DataFileError(path, f"OpenCV cannot decode this image: {str(e).strip().splitlines()[-1]}") from None
    if img is None:
        raise DataFileError(path, "OpenCV cannot decode this file as an image (corrupt, empty or not an "
                                  "image format)")
    return img


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
