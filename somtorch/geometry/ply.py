"""PLY files of point clouds: :func:`write_ply` (atomic) and :func:`read_ply` (checked), via Open3D.

Open3D is imported lazily, on the first call. Besides ``x y z`` and ``red green blue``, the files
carry each point's source pixel as ``pixel_y pixel_x`` columns, which :func:`read_ply` restores.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import torch

from somtorch._optional import import_open3d
from somtorch.geometry.pointcloud import PointCloud, _from_tensor_cloud
from somtorch.validation import DataFileError, require_file

__all__ = ["read_ply", "write_ply"]


@contextlib.contextmanager
def _atomic_output(path: Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` (same suffix); on success move it onto ``path``.

    On any failure — in the writer or in the final ``os.replace`` — the temporary file is removed and
    ``path`` is left as it was. The result gets ``path``'s old permissions, or 0644 for a new file.
    """
    parent = path.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {parent} does not exist (create it first)")
    fd, name = tempfile.mkstemp(suffix=path.suffix, prefix=f".{path.stem}.", dir=parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        mode = path.stat().st_mode & 0o777 if path.is_file() else 0o644
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_ply(cloud: PointCloud, path: str | os.PathLike[str], *, binary: bool = True,
              comment: str | None = None) -> Path:
    """Write a cloud to a PLY file with Open3D, atomically (a temporary file, then ``os.replace``).

    Columns: ``x y z`` as float32, ``red green blue`` as uchar (the PLY convention every viewer reads;
    colours are rounded to 1/255), and ``pixel_y pixel_x`` as int when the cloud has pixels
    (viewers ignore them; :func:`read_ply` restores them). Binary files keep float32 exactly; ASCII
    files hold what Open3D prints, 6 significant digits (relative error up to 5e-6).

    ``comment``: a line written into the header as ``comment …`` (e.g. the units of x y z).

    Returns:
        The path written.
    """
    if comment is not None and ("\n" in comment or "\r" in comment):
        raise ValueError("a PLY comment must be one line")
    if not isinstance(cloud, PointCloud):
        raise TypeError(f"cloud must be a PointCloud; got {type(cloud).__name__}")
    if len(cloud) == 0:
        raise ValueError("cloud is empty; a PLY file needs at least one point (Open3D refuses empty clouds)")
    path = Path(path).expanduser()
    if path.suffix.lower() != ".ply":
        raise ValueError(f"path must end in .ply; got {path}")
    o3d = import_open3d()
    t = o3d.t.geometry.PointCloud()
    t.point.positions = o3d.core.Tensor(cloud.points.detach().cpu().float().contiguous().numpy())
    if cloud.colors is not None:
        rgb = (cloud.colors.detach().cpu().clamp(0, 1) * 255).round().to(torch.uint8)
        t.point.colors = o3d.core.Tensor(rgb.contiguous().numpy())
    if cloud.pixels is not None:
        pix = cloud.pixels.detach().cpu().to(torch.int32)
        t.point.pixel_y = o3d.core.Tensor(pix[:, :1].contiguous().numpy())
        t.point.pixel_x = o3d.core.Tensor(pix[:, 1:].contiguous().numpy())
    with _atomic_output(path) as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), t, write_ascii=not binary):
            raise OSError(f"Open3D could not write the PLY file {path} (see its warning above)")
        if comment is not None:
            _add_comment(Path(tmp), comment)
    return path


def _add_comment(path: Path, comment: str) -> None:
    """Insert ``comment …`` after the ``format`` line of a PLY header (the body is untouched)."""
    data = path.read_bytes()
    start = data.find(b"\nformat ")
    end = data.find(b"\n", start + 1)
    if start < 0 or end < 0:
        raise OSError(f"{path}: no 'format' line in the PLY header Open3D wrote")
    path.write_bytes(data[:end + 1] + b"comment " + comment.encode("ascii", "replace") + b"\n" + data[end + 1:])


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
              "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
              "double": 8, "float64": 8}


def _check_ply_body(path: Path) -> None:
    """Parse the PLY header and check that the vertex data is all there (Open3D does not say)."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise DataFileError(path, "not a PLY file (the first line is not 'ply')")
        fmt, elements = None, []  # elements: [name, count, stride or None]
        for _ in range(10_000):
            line = f.readline()
            if not line:
                raise DataFileError(path, "PLY header has no 'end_header' line; the file is truncated")
            words = line.decode("ascii", "replace").split()
            if not words:
                continue
            if words[0] == "end_header":
                break
            if words[0] == "format" and len(words) >= 2:
                fmt = words[1]
            elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
                elements.append([words[1], int(words[2]), 0])
            elif words[0] == "property" and elements:
                size = _PLY_SIZES.get(words[1]) if len(words) == 3 else None  # "property list ..." → None
                elements[-1][2] = None if size is None or elements[-1][2] is None else elements[-1][2] + size
        else:
            raise DataFileError(path, "PLY header is longer than 10000 lines; not a point cloud file")
        header_bytes = f.tell()
        if not elements or elements[0][0] != "vertex":
            raise DataFileError(path, "PLY file has no 'element vertex' (as its first element); "
                                      "no points to read")
        _, n, stride = elements[0]
        if fmt in ("binary_little_endian", "binary_big_endian") and stride is not None:
            have = path.stat().st_size - header_bytes
            if have < n * stride:
                raise DataFileError(path, f"truncated: the header declares {n} vertices of {stride} bytes "
                                          f"({n * stride} bytes) but only {have} bytes follow it")
        elif fmt == "ascii":
            rows = sum(1 for line in f if line.strip())
            if rows < n:
                raise DataFileError(path, f"truncated: the header declares {n} vertices but only {rows} data "
                                          "lines follow it")
        elif fmt is None:
            raise DataFileError(path, "PLY header has no 'format' line")


def read_ply(path: str | os.PathLike[str], *, dtype: torch.dtype = torch.float32) -> PointCloud:
    """Read a PLY point cloud (points, colours if present, pixels if written by :func:`write_ply`).

    Raises:
        FileNotFoundError: no file at ``path``.
        DataFileError: not a PLY file, no vertices, or truncated.
    """
    p = require_file(path, "PLY file")
    _check_ply_body(p)
    o3d = import_open3d()
    pcd = o3d.t.io.read_point_cloud(str(p), format="ply")
    cloud = _from_tensor_cloud(pcd, dtype)
    if len(cloud) == 0:
        raise DataFileError(p, "Open3D read no points from this file (see its warning above)")
    return cloud
