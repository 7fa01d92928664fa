"""Object labels drawn as polygons: a small JSON file rasterised to an instance map.

The format is the one ``objects.json`` of ``../shared/data`` records (``polygons`` in left-image
pixels, ``[x, y]`` = column, row), so that labels of one's own can be kept in a repository beside
the code instead of beside the data::

    {"size_hw": [480, 640],
     "objects": [{"id": 1, "name": "chair", "main": true,
                  "polygons": [[[437, 205], [455, 195], ...]],
                  "exclude": [[[...]]]}]}

``exclude`` (optional) are polygons cut out of the object (see-through gaps). An object's polygons
are united (overlapping pieces do not cancel), and so are its exclusions. Where two objects'
polygons overlap, the lower id wins (objects are painted from the highest id down, so the main
object, id 1 by convention, is drawn last: label it around what occludes it, not through it).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from somtorch.disparity.io import read_json
from somtorch.disparity.scene import ObjectInfo
from somtorch.validation import DataFileError

__all__ = ["read_polygon_labels"]

_MAX_VERTICES = 100_000


def read_polygon_labels(path: str | Path, hw: tuple[int, int]) -> tuple[torch.Tensor, list[ObjectInfo]]:
    """The int64 instance map ``(H, W)`` and the :class:`ObjectInfo` list of a polygon label file.

    Raises:
        DataFileError: naming the file and the field when the document does not fit ``hw`` or is
            malformed (ids not unique or < 1, a polygon with < 3 vertices or outside the image).
    """
    doc = read_json(path)
    h, w = hw
    if "size_hw" in doc and (not isinstance(doc["size_hw"], list) or list(doc["size_hw"]) != [h, w]):
        raise DataFileError(path, f"size_hw {doc['size_hw']} does not match the map's {[h, w]}")
    objects = doc.get("objects")
    if not isinstance(objects, list) or not objects:
        raise DataFileError(path, "field 'objects' must be a non-empty list")
    out = np.zeros((h, w), dtype=np.int32)
    info: list[ObjectInfo] = []
    masks: list[tuple[int, np.ndarray]] = []
    for k, o in enumerate(objects):
        where = f"objects[{k}]"
        if not isinstance(o, dict):
            raise DataFileError(path, f"{where} must be an object")
        oid = o.get("id")
        if not isinstance(oid, int) or isinstance(oid, bool) or not 1 <= oid < 2 ** 31:
            raise DataFileError(path, f"{where}.id must be an integer in [1, 2^31); got {str(oid)[:40]}")
        if oid in {i.id for i in info}:
            raise DataFileError(path, f"{where}.id {oid} is used twice")
        name = o.get("name", f"object_{oid}")
        if not isinstance(name, str):
            raise DataFileError(path, f"{where}.name must be a string")
        mask = np.zeros((h, w), dtype=np.uint8)
        # one fillPoly per polygon: a single call with several polygons fills by parity, so two
        # overlapping pieces of one object would cancel where they overlap
        for poly in _polygons(o.get("polygons"), path, f"{where}.polygons", h, w):
            cv2.fillPoly(mask, [poly], 1)
        if o.get("exclude"):
            for poly in _polygons(o["exclude"], path, f"{where}.exclude", h, w):
                cv2.fillPoly(mask, [poly], 0)
        if not mask.any():
            raise DataFileError(path, f"{where} ({name}) covers no pixel")
        masks.append((oid, mask.astype(bool)))
        info.append(ObjectInfo(id=oid, name=name, main=bool(o.get("main", False))))
    for oid, mask in sorted(masks, key=lambda t: -t[0]):
        out[mask] = oid
    present = set(np.unique(out).tolist()) - {0}
    lost = [i.name for i in info if i.id not in present]
    if lost:
        raise DataFileError(path, f"objects {lost} are wholly covered by objects of lower id")
    return torch.from_numpy(out.astype(np.int64)), info


def _polygons(value: object, path: str | Path, where: str, h: int, w: int) -> list[np.ndarray]:
    if not isinstance(value, list) or not value:
        raise DataFileError(path, f"{where} must be a non-empty list of polygons")
    polys = []
    for j, poly in enumerate(value):
        try:
            a = np.asarray(poly, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise DataFileError(path, f"{where}[{j}]: not a list of [x, y] numbers ({e})") from None
        if a.ndim != 2 or a.shape[1] != 2 or not 3 <= len(a) <= _MAX_VERTICES:
            raise DataFileError(path, f"{where}[{j}] must be 3..{_MAX_VERTICES} [x, y] vertices; got shape {a.shape}")
        if not np.isfinite(a).all() or a[:, 0].min() < 0 or a[:, 1].min() < 0 \
                or a[:, 0].max() > w - 1 or a[:, 1].max() > h - 1:
            raise DataFileError(path, f"{where}[{j}] has a vertex outside the {w}x{h} image")
        polys.append(np.round(a).astype(np.int32))
    return polys
