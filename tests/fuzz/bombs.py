"""Small files that inflate hugely (the reproducers of issue 34), written at test time.

Each builder streams its compressed data, so building a bomb never holds what it inflates to.
``benchmarks/bench_readers.py`` builds the issue's sizes with the same functions.
"""

from __future__ import annotations

import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

_STEP = 1 << 24  # bytes of zeros compressed at a time


def _deflate_zeros(n: int, level: int = 9) -> bytes:
    """zlib stream of ``n`` zero bytes."""
    comp, out, zeros = zlib.compressobj(level), [], bytes(min(n, _STEP))
    for start in range(0, n, _STEP):
        out.append(comp.compress(zeros[:min(_STEP, n - start)]))
    out.append(comp.flush())
    return b"".join(out)


def npz_zeros(path: Path, h: int, w: int, dtype: str = "<f8") -> Path:
    """An ``.npz`` whose ``disparity`` member is an ``(h, w)`` array of zeros (np.savez_compressed's layout)."""
    header = {"descr": dtype, "fortran_order": False, "shape": (h, w)}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z, z.open("disparity.npy", "w", force_zip64=True) as m:
        np.lib.format.write_array_header_2_0(m, header)
        zeros, n = bytes(_STEP), h * w * np.dtype(dtype).itemsize
        for start in range(0, n, _STEP):
            m.write(zeros[:min(_STEP, n - start)])
    return path


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png16(path: Path, h: int, w: int, *, inflated: int | None = None) -> Path:
    """A 16-bit grey PNG of zeros claiming ``h`` x ``w`` px; its compressed stream inflates to
    ``inflated`` bytes (default: exactly what the header needs; more: a stream that runs on)."""
    need = h * (2 * w + 1)
    ihdr = struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)
    data = _deflate_zeros(need if inflated is None else inflated)
    parts = [b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", ihdr)]
    parts += [_chunk(b"IDAT", data[i:i + (1 << 20)]) for i in range(0, len(data), 1 << 20)]
    path.write_bytes(b"".join(parts + [_chunk(b"IEND", b"")]))
    return path


def tiff_striped(path: Path, h: int, w: int, rows_per_strip: int = 64) -> Path:
    """A float32 deflate TIFF claiming ``h`` x ``w`` px whose strips all point at one compressed
    strip of zeros: a few kB that decode to ``4 h w`` bytes."""
    strips = -(-h // rows_per_strip)
    blob = _deflate_zeros(rows_per_strip * w * 4)
    entries = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 32), (259, 3, 1, 8), (262, 3, 1, 1),
               (273, 4, strips, None), (277, 3, 1, 1), (278, 4, 1, rows_per_strip), (279, 4, strips, None),
               (284, 3, 1, 1), (339, 3, 1, 3)]
    ifd_at = 8
    arrays_at = ifd_at + 2 + 12 * len(entries) + 4
    offsets_at, counts_at = arrays_at, arrays_at + 4 * strips
    blob_at = counts_at + 4 * strips
    ifd = struct.pack("<H", len(entries))
    for tag, kind, count, value in entries:
        if value is None:
            value = offsets_at if tag == 273 else counts_at
        ifd += struct.pack("<HHI", tag, kind, count) + (struct.pack("<I", value) if kind == 4
                                                       else struct.pack("<HH", value, 0))
    body = (b"II*\x00" + struct.pack("<I", ifd_at) + ifd + b"\x00\x00\x00\x00"
            + struct.pack(f"<{strips}I", *([blob_at] * strips)) + struct.pack(f"<{strips}I", *([len(blob)] * strips))
            + blob)
    path.write_bytes(body)
    return path
