"""What reading a file will cost, from its header alone, checked before any pixel is decoded.

Every reader of :mod:`somtorch.disparity.io` parses the header of its format here (NPY / NPZ member
header, PNG IHDR and chunks, TIFF first IFD; PFM in :mod:`.pfm`) and calls :func:`check_cost`,
which refuses with a :class:`~somtorch.validation.DataFileError` naming the file:

* more pixels than :data:`MAX_PIXELS` (``SOMTORCH_MAX_PIXELS``);
* a compression ratio (bytes the header says will be decoded / bytes of the file) that no real
  disparity map has: :data:`MAX_RATIO` for disparity maps, deflate's own bound
  :data:`DEFLATE_RATIO` for images and masks (a hand-labelled ``objects.png`` reaches 169:1);
* more bytes than the resource guard's memory budget (:func:`memory_budget`: the default
  ``resources.max_memory_frac`` of the memory available, :func:`somtorch.resources.available_memory`).

:data:`MAX_RATIO` comes from the 70 disparity maps (66 PNG, 4 PFM) of ``../shared/data`` (measured by
``benchmarks/bench_readers.py --ratios``): the most compressible one (Middlebury 2006 ``Wood2/disp1.png``)
is 12.7:1 as its own PNG, 15:1 at its stored uint8 in an NPZ or a deflate TIFF, 45:1 as float32 and
69:1 as float64 (what ``np.zeros`` and most NumPy code write); the median map is 35:1 as float64.
150:1 leaves twice the most compressible real map's ratio; a decompression bomb needs ~1000:1.

A PNG's compressed stream is inflated here once, in 1 MiB steps, and refused as soon as it produces
more than the image its header claims (OpenCV would inflate all of it: 48 s for a 9.7 MB file).
"""

from __future__ import annotations

import math
import os
import struct
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from somtorch.resources import available_memory, fmt_bytes
from somtorch.validation import DataFileError

__all__ = ["DEFLATE_RATIO", "MAX_PIXELS", "MAX_RATIO", "OUT_BYTES_PER_PX", "check_cost", "check_png", "map_shape",
           "memory_budget", "npy_header", "tiff_cost", "tiff_header"]

MAX_PIXELS = int(os.environ.get("SOMTORCH_MAX_PIXELS", 200_000_000))
"""Largest map (H·W, or array elements) a reader accepts (``SOMTORCH_MAX_PIXELS`` overrides it)."""
MAX_RATIO = 150
"""Largest compression ratio of a disparity file (decoded bytes / file bytes; see the module docstring)."""
DEFLATE_RATIO = 1100
"""Largest ratio of any PNG: deflate compresses at most ~1032:1."""
_SLACK = 65536  # headers, chunk framing: a tiny file may claim this many bytes whatever its ratio
OUT_BYTES_PER_PX = 5
"""What a disparity reader returns per pixel: the float32 map and the bool valid mask."""


def memory_budget() -> tuple[int, str]:
    """``(bytes, how)``: the resource guard's budget, ``ResourcesConfig().max_memory_frac`` of the
    memory available (0 when unknown: no memory check)."""
    from somtorch.config import ResourcesConfig

    frac = ResourcesConfig().max_memory_frac
    avail, source = available_memory()
    return int(frac * avail), f"{frac:g} x {fmt_bytes(avail)} available, {source}"


def check_cost(path: Path, what: str, *, pixels: int, decoded: int, held: int, ratio: int | None) -> None:
    """Refuse a file whose header promises too much (see the module docstring).

    Args:
        path: the file (named in the error).
        what: the header's claim, e.g. ``"the PNG header claims 640x480 px"``.
        pixels: H·W (elements of the array).
        decoded: bytes the decoder produces from the file's compressed data.
        held: bytes the read holds at its peak (decoded data and the arrays returned).
        ratio: the largest ``decoded / file size`` accepted; None for uncompressed formats.
    """
    if pixels > MAX_PIXELS:
        raise DataFileError(path, f"{what} ({pixels:,} px); the limit is {MAX_PIXELS:,} px (SOMTORCH_MAX_PIXELS)")
    size = path.stat().st_size
    if ratio is not None and decoded > ratio * size + _SLACK:
        raise DataFileError(path, f"{what}: {decoded:,} bytes from a {size:,}-byte file, a compression ratio of "
                                  f"{decoded / max(size, 1):,.0f}:1 that no real disparity map has (at most "
                                  f"{ratio}:1 accepted): a decompression bomb, or a corrupt file")
    budget, how = memory_budget()
    if budget and held > budget:
        raise DataFileError(path, f"{what}; reading it needs ~{fmt_bytes(held)}, more than the memory budget "
                                  f"{fmt_bytes(budget)} ({how})")


def map_shape(path: Path, shape: tuple[int, ...], dtype: np.dtype) -> tuple[int, int]:
    """``(H, W)`` of an array of ``shape`` and ``dtype`` that is a disparity map: 2-D (or
    ``(H, W, 1)``), not empty, real numbers; else DataFileError."""
    if any(s < 0 for s in shape):
        raise DataFileError(path, f"the header claims a negative size: shape {shape}")
    if len(shape) == 3 and shape[2] == 1:
        shape = shape[:2]
    if len(shape) != 2:
        raise DataFileError(path, f"a disparity map must be 2-D (H, W); got shape {shape}")
    if 0 in shape:
        raise DataFileError(path, f"the disparity map is empty (shape {shape})")
    if dtype == np.bool_ or not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
        raise DataFileError(path, f"a disparity map must hold real numbers; got dtype {dtype}")
    return int(shape[0]), int(shape[1])


# ------------------------------------------------------------------------------------------------ npy


class NpyHeader(NamedTuple):
    shape: tuple[int, ...]
    dtype: np.dtype
    fortran: bool


def npy_header(path: Path, f: Any) -> NpyHeader:
    """The header of the ``.npy`` stream ``f`` (left at the first data byte); bad header -> DataFileError."""
    fmt = np.lib.format
    try:
        major, _ = fmt.read_magic(f)
        shape, fortran, dtype = (fmt.read_array_header_1_0(f) if major == 1 else fmt.read_array_header_2_0(f))
    except (ValueError, OSError, EOFError, zlib.error, zipfile.BadZipFile, SyntaxError, tokenize.TokenError,
            TypeError, RuntimeError, KeyError, MemoryError, AttributeError, NotImplementedError) as e:
        raise DataFileError(path, f"bad .npy header: {type(e).__name__}: {e}") from None
    return NpyHeader(tuple(int(s) for s in shape), dtype, bool(fortran))


# ------------------------------------------------------------------------------------------------ png

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))


def check_png(path: Path, *, ratio: int, bytes_per_px: int) -> bool:
    """Check a PNG before OpenCV decodes it: IHDR (size, depth, colour type), the cost
    (:func:`check_cost`), every chunk's length and CRC, and that the image data inflates to exactly
    what IHDR claims (inflated once, in 1 MiB steps, stopped as soon as it runs past that).

    ``bytes_per_px``: what the caller holds per pixel beside the decoded image. Returns False for a
    file that is not a PNG (left to OpenCV).
    """
    data = path.read_bytes()
    if not data.startswith(_PNG_SIGNATURE):
        return False
    if len(data) < 33 or data[12:16] != b"IHDR":
        raise DataFileError(path, "truncated or corrupt PNG: no IHDR chunk")
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    depth, colour, interlace = data[24], data[25], data[28]
    channels = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}.get(colour)
    if w == 0 or h == 0:
        raise DataFileError(path, f"the PNG header claims {w}x{h} px")
    if channels is None or depth not in (1, 2, 4, 8, 16) or interlace > 1:
        raise DataFileError(path, f"corrupt PNG header: bit depth {depth}, colour type {colour}, interlace {interlace}")
    bits = channels * depth
    passes = _ADAM7 if interlace else ((0, 0, 1, 1),)
    raw = 0  # bytes of the filtered image data: a filter byte and the packed samples of every row
    for x0, y0, dx, dy in passes:
        pw, ph = -(-(w - x0) // dx), -(-(h - y0) // dy)
        if pw > 0 and ph > 0:
            raw += ph * ((pw * bits + 7) // 8 + 1)
    decoded = w * h * channels * (2 if depth == 16 else 1)  # OpenCV unpacks low depths to 8 bits
    check_cost(path, f"the PNG header claims {w}x{h} px", pixels=w * h, decoded=raw,
               held=decoded + w * h * bytes_per_px, ratio=ratio)
    idat = _png_chunks(path, data)
    inflater, produced = zlib.decompressobj(), 0
    try:
        for chunk in idat:
            while chunk and not inflater.eof:
                produced += len(inflater.decompress(chunk, 1 << 20))
                if produced > raw:
                    raise DataFileError(path, f"the PNG's compressed image data runs past the {w}x{h} image its "
                                              f"header claims ({raw:,} bytes; stopped after {produced:,})")
                chunk = inflater.unconsumed_tail
    except zlib.error as e:
        raise DataFileError(path, f"corrupt PNG: the compressed image data cannot be inflated ({e})") from None
    return True


def _png_chunks(path: Path, data: bytes) -> list[memoryview]:
    """Walk the chunks and verify their CRCs (a corrupt PNG is refused here, in microseconds, rather
    than inside the decoder, which can take seconds on some corruptions); the IDAT payloads."""
    pos, n, idat, view = 8, len(data), [], memoryview(data)
    while pos < n:
        if pos + 12 > n:
            raise DataFileError(path, f"truncated PNG: chunk header at byte {pos}")
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if length > 2**31 - 1 or end > n:
            raise DataFileError(path, f"truncated or corrupt PNG: chunk {kind!r} at byte {pos} claims {length:,} bytes")
        if zlib.crc32(view[pos + 4:pos + 8 + length]) != int.from_bytes(data[end - 4:end], "big"):
            raise DataFileError(path, f"corrupt PNG: CRC mismatch in chunk {kind!r} at byte {pos}")
        if kind == b"IDAT":
            idat.append(view[pos + 8:pos + 8 + length])
        elif kind == b"IEND":
            return idat
        pos = end
    raise DataFileError(path, "truncated PNG: no IEND chunk")


# ----------------------------------------------------------------------------------------------- tiff

# TIFF field types -> bytes per value; the tags read from the first IFD
_TIFF_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4, 16: 8, 17: 8, 18: 8}
_TIFF_INTS = {1: "B", 3: "H", 4: "I", 6: "b", 8: "h", 9: "i", 13: "I", 16: "Q", 17: "q", 18: "Q"}
_WIDTH, _HEIGHT, _BITS, _SAMPLES, _FORMAT = 256, 257, 258, 277, 339
_MAX_ENTRIES = 4096


class TiffHeader(NamedTuple):
    width: int
    height: int
    samples: int  # per pixel
    bits: int  # per sample (the largest, if they differ)
    sample_format: int  # 1 unsigned, 2 signed, 3 IEEE float


def tiff_header(path: Path) -> TiffHeader:
    """Size and sample layout from the first IFD of a classic or BigTIFF file (the page OpenCV reads)."""
    with open(path, "rb") as f:
        head = f.read(16)
        order = {b"II": "<", b"MM": ">"}.get(head[:2])
        magic = struct.unpack(order + "H", head[2:4])[0] if order and len(head) >= 8 else None
        if magic not in (42, 43):
            raise DataFileError(path, "not a TIFF file: it does not start with 'II*\\0', 'MM\\0*' or a BigTIFF header")
        big = magic == 43
        if big and len(head) < 16:
            raise DataFileError(path, "truncated BigTIFF header")
        ifd = struct.unpack(order + ("Q" if big else "I"), head[8:16] if big else head[4:8])[0]
        f.seek(ifd)
        count_raw = f.read(8 if big else 2)
        if len(count_raw) < (8 if big else 2):
            raise DataFileError(path, f"truncated TIFF: the first IFD at byte {ifd} is past the end of the file")
        entries = struct.unpack(order + ("Q" if big else "H"), count_raw)[0]
        if not 0 < entries <= _MAX_ENTRIES:
            raise DataFileError(path, f"corrupt TIFF: the first IFD claims {entries:,} entries")
        size = 20 if big else 12
        table = f.read(entries * size)
        if len(table) < entries * size:
            raise DataFileError(path, "truncated TIFF: the first IFD ends past the end of the file")
        tags: dict[int, list[int]] = {}
        for i in range(entries):
            e = table[i * size:(i + 1) * size]
            tag, kind = struct.unpack(order + "HH", e[:4])
            count = struct.unpack(order + ("Q" if big else "I"), e[4:12] if big else e[4:8])[0]
            if tag not in (_WIDTH, _HEIGHT, _BITS, _SAMPLES, _FORMAT) or kind not in _TIFF_INTS:
                continue
            inline = e[12:] if big else e[8:]
            nbytes = count * _TIFF_SIZES[kind]
            if count == 0 or count > 64:
                raise DataFileError(path, f"corrupt TIFF: tag {tag} has {count:,} values")
            if nbytes > len(inline):
                f.seek(struct.unpack(order + ("Q" if big else "I"), inline)[0])
                inline = f.read(nbytes)
                if len(inline) < nbytes:
                    raise DataFileError(path, f"truncated TIFF: the values of tag {tag} are past the end of the file")
            tags[tag] = list(struct.unpack(f"{order}{count}{_TIFF_INTS[kind]}", inline[:nbytes]))
    if _WIDTH not in tags or _HEIGHT not in tags:
        raise DataFileError(path, "corrupt TIFF: no image width or length in the first IFD")
    bits = tags.get(_BITS, [1])
    return TiffHeader(tags[_WIDTH][0], tags[_HEIGHT][0], tags.get(_SAMPLES, [1])[0], max(bits),
                      tags.get(_FORMAT, [1])[0])


def tiff_cost(path: Path, header: TiffHeader, *, bytes_per_px: int) -> None:
    """:func:`check_cost` of a TIFF from its header (a disparity TIFF: :data:`MAX_RATIO`)."""
    w, h, spp, bits = header.width, header.height, header.samples, header.bits
    if w <= 0 or h <= 0 or not 0 < spp <= 64 or not 0 < bits <= 64:
        raise DataFileError(path, f"corrupt TIFF header: {w}x{h} px, {spp} sample(s) of {bits} bits")
    decoded = w * h * spp * max(1, math.ceil(bits / 8))
    check_cost(path, f"the TIFF header claims {w}x{h} px of {spp} x {bits}-bit samples", pixels=w * h,
               decoded=decoded, held=decoded + w * h * bytes_per_px, ratio=MAX_RATIO)
