"""PFM (portable float map) files: tolerant reader and atomic writer.

Rows are stored bottom-to-top; only the sign of the scale is meaningful (endianness): its magnitude
is returned but never applied (Middlebury's Motorcycle_Q says -1/255 yet stores pixels). Every
error is a :class:`~somtorch.validation.DataFileError` naming the file.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import numpy as np
import torch

from somtorch.atomic import write_bytes
from somtorch.disparity.headers import OUT_BYTES_PER_PX, check_cost
from somtorch.validation import DataFileError, require_file

__all__ = ["read_pfm", "write_pfm"]
log = logging.getLogger("somtorch.disparity.io")
_WHITESPACE = re.compile(rb"\s+")
_HEADER_BYTES = 4096  # the three header lines are read from at most this many first bytes
_CHUNK_BYTES = 4 << 20  # rows are read and flipped this many bytes at a time


def read_pfm(path: str | Path, *, channel: int | None = None) -> tuple[np.ndarray, float]:
    """Read a PFM file into a top-to-bottom float32 array.

    The header is parsed tolerantly: its three fields (``Pf``/``PF``, ``width height``, ``scale``) are
    split on any whitespace, so Freiburg's trailing spaces and ``\\r\\n`` line ends are accepted. The
    sign of ``scale`` gives the byte order (negative = little-endian); its magnitude is returned but
    NOT applied, because in the data sets we use the stored floats already are pixels.

    Colour files (``PF``, 3 channels) are rejected unless ``channel`` picks one: a 3-channel PFM is
    usually not a disparity map (Freiburg optical-flow files are ``PF``), so taking a channel silently
    would hide a wrong file.

    Args:
        path: the ``.pfm`` file.
        channel: for colour (``PF``) files only, the channel (0, 1 or 2) to return.

    Returns:
        ``(array, scale)``: the float32 values (native byte order, rows top-to-bottom, ``inf``/``nan``
        kept as stored) and the header scale.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        DataFileError: bad header, non-positive size, truncated data, or a colour file without
            ``channel``.

    Shape:
        - Output array: :math:`(H, W)`.
    """
    path = require_file(path, "PFM file")
    with open(path, "rb") as f:
        kind, width, height, scale, offset = _parse_pfm_header(path, f.read(_HEADER_BYTES))
        n_channels = 3 if kind == "PF" else 1
        if n_channels == 1 and channel not in (None, 0):
            raise DataFileError(path, f"channel={channel} requested but the file is single-channel (Pf)")
        if n_channels == 3:
            if channel is None:
                raise DataFileError(path, "colour PFM (PF, 3 channels) is not a single-channel disparity map "
                                          "(Freiburg optical flow is stored this way); pass channel=0, 1 or 2 "
                                          "to read one channel")
            if channel not in (0, 1, 2):
                raise DataFileError(path, f"channel must be 0, 1 or 2 for a colour PFM; got {channel!r}")
        expected = width * height * n_channels * 4
        available = os.fstat(f.fileno()).st_size - offset
        if available < expected:
            raise DataFileError(path, f"truncated PFM data: {width}x{height}x{n_channels} float32 needs "
                                      f"{expected} bytes after the header, found {available}")
        # the map, then read_disparity's float32 map and valid mask beside it
        check_cost(path, f"the PFM header claims {width}x{height} px", pixels=width * height,
                   decoded=expected, held=width * height * (4 + OUT_BYTES_PER_PX), ratio=None)
        if available > expected:
            log.warning("%s: %d extra bytes after the PFM data ignored", path, available - expected)
        dtype = np.dtype("<f4") if scale < 0 else np.dtype(">f4")
        out = np.empty((height, width), np.float32)
        rows = max(1, _CHUNK_BYTES // (width * n_channels * 4))
        f.seek(offset)
        for done in range(0, height, rows):  # stored bottom row first: file rows fill `out` from its end
            k = min(rows, height - done)
            block = np.frombuffer(f.read(k * width * n_channels * 4), dtype=dtype).reshape(k, width, n_channels)
            out[height - done - k:height - done] = block[::-1, :, channel or 0]
    return out, scale


def _parse_pfm_header(path: Path, raw: bytes) -> tuple[str, int, int, float, int]:
    """Return ``(kind, width, height, scale, data_offset)``; the header is the first three lines."""
    tokens: list[bytes] = []
    offset = 0
    for _ in range(3):
        end = raw.find(b"\n", offset)
        if end < 0:
            raise DataFileError(path, "bad PFM header: expected 3 header lines ('Pf' or 'PF', "
                                      "'width height', 'scale'), the file ends before them")
        tokens.extend(t for t in _WHITESPACE.split(raw[offset:end]) if t)
        offset = end + 1
        if len(tokens) >= 4:
            break
    if len(tokens) != 4:
        shown = b" ".join(tokens)[:60]
        raise DataFileError(path, f"bad PFM header: expected 'Pf|PF', width, height, scale; got {shown!r}")
    kind = tokens[0].decode("ascii", errors="replace")
    if kind not in ("Pf", "PF"):
        raise DataFileError(path, f"bad PFM header: magic must be 'Pf' (grey) or 'PF' (colour); got {kind!r}")
    try:
        width, height = int(tokens[1]), int(tokens[2])
        scale = float(tokens[3])
    except ValueError:
        raise DataFileError(path, "bad PFM header: width/height must be integers and scale a number; got "
                                  f"{b' '.join(tokens[1:]).decode('ascii', errors='replace')!r}") from None
    if width <= 0 or height <= 0:
        raise DataFileError(path, f"bad PFM header: image size must be positive; got width={width}, "
                                  f"height={height}")
    if not np.isfinite(scale) or scale == 0:
        raise DataFileError(path, f"bad PFM header: scale must be a non-zero number (its sign is the byte "
                                  f"order); got {scale}")
    if abs(scale) != 1.0:
        log.debug("%s: PFM scale %g; only its sign (byte order) is used", path, scale)
    return kind, width, height, scale, offset


def write_pfm(path: str | Path, array: np.ndarray | torch.Tensor, *, little_endian: bool = True) -> Path:
    """Write a float array as PFM (rows bottom-to-top, scale ``-1`` or ``+1``), atomically.

    Written through :func:`somtorch.atomic.write_bytes` (temporary file in the same folder, then
    ``os.replace``), so readers never see a half-written file; missing folders are created.

    Args:
        path: destination ``.pfm`` file.
        array: ``(H, W)`` for ``Pf`` or ``(H, W, 3)`` for ``PF``; cast to float32 (``inf``/``nan`` kept).
        little_endian: byte order; scale ``-1.0`` if True, ``+1.0`` (big-endian) otherwise.

    Returns:
        The path written.

    Shape:
        - array: :math:`(H, W)` or :math:`(H, W, 3)`.

    Example:
        >>> import tempfile, numpy as np
        >>> f = Path(tempfile.mkdtemp()) / "d.pfm"
        >>> _ = write_pfm(f, np.arange(6, dtype=np.float32).reshape(2, 3))
        >>> read_pfm(f)[0].tolist()
        [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]
    """
    a = array.detach().cpu().numpy() if isinstance(array, torch.Tensor) else np.asarray(array)
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or a.size == 0:
        raise ValueError(f"array must be a non-empty (H, W) or (H, W, 3) array; got shape {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise TypeError(f"array must be numeric; got dtype {a.dtype}")
    kind = "PF" if a.ndim == 3 else "Pf"
    height, width = a.shape[:2]
    body = np.ascontiguousarray(a[::-1], dtype="<f4" if little_endian else ">f4").tobytes()  # bottom row 1st
    header = f"{kind}\n{width} {height}\n{-1.0 if little_endian else 1.0}\n".encode("ascii")
    return write_bytes(path, header + body)
