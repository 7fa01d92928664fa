"""``.npy`` and ``.npz`` disparity files read as a stream: the header first, then the data in
chunks of :data:`CHUNK_ITEMS` values, so a reader never holds the stored array beside the map it returns.

An ``.npz`` member is inflated only as far as its ``.npy`` header says it reaches: a stream that
runs on is never read past that. Every problem is a :class:`~somtorch.validation.DataFileError`
naming the file.
"""

from __future__ import annotations

import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np

from somtorch.disparity.headers import MAX_RATIO, OUT_BYTES_PER_PX, check_cost, map_shape, npy_header
from somtorch.validation import DataFileError

__all__ = ["CHUNK_ITEMS", "Stream", "NPZ_KEYS", "read_npy", "read_npz"]

CHUNK_ITEMS = 1 << 19
"""Values converted at a time (their float64 temporaries: 4 MiB each)."""
NPZ_KEYS = ("disparity", "disp")

# what numpy and zipfile raise on corrupt, truncated, encrypted or mis-named .npy / .npz files
READ_ERRORS = (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError,
               RuntimeError, tokenize.TokenError, SyntaxError, AttributeError, KeyError, MemoryError)


class Stream(NamedTuple):
    """A stored array read in chunks: its ``(H, W)``, dtype, storage order and the 1-D chunks
    (storage order, ``dtype``; whole rows, or whole columns when ``fortran``) in turn."""

    shape: tuple[int, int]
    dtype: np.dtype
    fortran: bool
    chunks: Iterator[np.ndarray]


def _stream(path: Path, f: IO[bytes], what: str, ratio: int | None, close: list[Any]) -> Stream:
    """The header of the ``.npy`` data in ``f``, checked (shape, dtype, cost), and its chunks."""
    shape, dtype, fortran = npy_header(path, f)
    hw = map_shape(path, shape, dtype)
    n, item = hw[0] * hw[1], max(dtype.itemsize, 1)
    check_cost(path, f"{what} claims shape {shape} ({dtype})", pixels=n, decoded=n * item,
               held=n * OUT_BYTES_PER_PX + CHUNK_ITEMS * 32, ratio=ratio)

    def chunks() -> Iterator[np.ndarray]:
        try:
            line = hw[0] if fortran else hw[1]  # chunks of whole rows (columns when stored column-major)
            step = max(1, CHUNK_ITEMS // line) * line
            for start in range(0, n, step):
                k = min(step, n - start)
                data = f.read(k * item)
                if len(data) < k * item:
                    raise DataFileError(path, f"truncated {what}: shape {shape} of {dtype} needs {n * item:,} "
                                              f"bytes, the data ends after {start * item + len(data):,}")
                yield np.frombuffer(data, dtype=dtype)
        except DataFileError:
            raise
        except READ_ERRORS as e:
            raise DataFileError(path, f"cannot read {what}: {type(e).__name__}: {e}") from None
        finally:
            for c in reversed(close):
                c.close()

    return Stream(hw, dtype, fortran, chunks())


def read_npy(path: Path) -> Stream:
    """A ``.npy`` file as a :class:`Stream` (a zip archive under this name: DataFileError)."""
    f = open(path, "rb")  # noqa: SIM115 - closed when the chunks are read, or below
    try:
        magic = f.read(6)
        if magic == b"\x93NUMPY":
            f.seek(0)
            return _stream(path, f, "the .npy header", None, [f])
        if magic.startswith(b"PK"):
            raise DataFileError(path, "is a zip archive (.npz), not a .npy array; rename it to .npz")
    except BaseException:
        f.close()
        raise
    f.close()
    try:
        np.load(path, allow_pickle=False)  # neither .npy nor zip: numpy's own error
    except READ_ERRORS as e:
        raise DataFileError(path, f"cannot read .npy: {type(e).__name__}: {e}") from None
    raise DataFileError(path, "cannot read .npy: not a NumPy array file")


def read_npz(path: Path) -> Stream:
    """The disparity member of an ``.npz`` archive (a plain ``.npy`` under this name too) as a
    :class:`Stream`; its compression ratio is checked against :data:`MAX_RATIO`."""
    with open(path, "rb") as f:
        magic = f.read(6)
    if magic == b"\x93NUMPY":
        return read_npy(path)
    try:
        archive = zipfile.ZipFile(path)
    except READ_ERRORS as e:
        raise DataFileError(path, f"cannot read .npz: {type(e).__name__}: {e}") from None
    try:
        names = {(n[:-4] if n.endswith(".npy") else n): n for n in archive.namelist()}
        if not names:
            raise DataFileError(path, "the .npz archive contains no arrays; expected one named "
                                      f"{' or '.join(NPZ_KEYS)}")
        key = next((k for k in NPZ_KEYS if k in names), next(iter(names)) if len(names) == 1 else None)
        if key is None:
            raise DataFileError(path, f"cannot tell which array is the disparity: keys {list(names)}; "
                                      f"name it {' or '.join(NPZ_KEYS)}, or store a single array")
        try:
            member = archive.open(names[key])
        except READ_ERRORS as e:
            raise DataFileError(path, f"cannot read array {key!r} from the .npz: {type(e).__name__}: {e}") from None
        try:
            return _stream(path, member, f"array {key!r} of the .npz", MAX_RATIO, [archive, member])
        except BaseException:
            member.close()
            raise
    except BaseException:
        archive.close()
        raise
