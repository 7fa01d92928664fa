"""One scene description (disparity + valid mask, left image, instance map, camera) for every data set.

The readers that build scenes from files live one layer up, in :mod:`somtorch.disparity.loading`
(:func:`~somtorch.disparity.loading.load_scene`, also exported by :mod:`somtorch.disparity`): an
embedded scene name (``"motorcycle"``), a folder in one of the known layouts, or a single disparity
file, validated against each other before a :class:`Scene` is built.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from somtorch.disparity.camera import Camera, read_middlebury_camera
from somtorch.disparity.io import parse_middlebury_calib
from somtorch.validation import check_tensor

__all__ = [
    "Camera",
    "ObjectInfo",
    "Scene",
    "parse_middlebury_calib",
    "read_middlebury_camera",
    "scene_from_arrays",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ObjectInfo:
    """One labelled object of an instance map: its id (``>= 1``), name, and whether it is the main one."""

    id: int
    name: str
    main: bool = False


@dataclass(eq=False)
class Scene:
    """A disparity map with its valid mask and, where known, left image, objects and camera.

    Values of ``disparity`` at invalid pixels are ``0.0`` and meaningless: use ``valid``.

    Attributes:
        name: scene name (folder name, file stem or embedded name).
        disparity: float32 disparity of the left view, pixels.
        valid: True where ``disparity`` holds a value.
        image: left image, RGB uint8, or None.
        objects: int64 instance map (0 = background, ``ObjectInfo.id`` elsewhere), or None.
        object_info: one entry per object id.
        camera: the stereo camera, or None.
        source: where each part came from (``"disparity"``, ``"image"``, ``"layout"``, ...).

    Shape:
        - disparity, valid, objects: :math:`(H, W)`.
        - image: :math:`(3, H, W)`.
    """

    name: str
    disparity: torch.Tensor
    valid: torch.Tensor
    image: torch.Tensor | None = None
    objects: torch.Tensor | None = None
    object_info: list[ObjectInfo] = field(default_factory=list)
    camera: Camera | None = None
    source: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_tensor("disparity", self.disparity, ndim=2, dtype=torch.float32)
        h, w = self.disparity.shape
        check_tensor("valid", self.valid, ndim=2, dtype=torch.bool)
        _check_size("valid", tuple(self.valid.shape), (h, w))
        if self.image is not None:
            check_tensor("image", self.image, ndim=3, dtype=torch.uint8)
            _check_size("image", tuple(self.image.shape), (3, h, w))
        ids = {o.id for o in self.object_info}
        if len(ids) != len(self.object_info):
            raise ValueError(f"object_info has duplicate ids: {[o.id for o in self.object_info]}")
        if self.objects is not None:
            check_tensor("objects", self.objects, ndim=2, dtype=torch.int64)
            _check_size("objects", tuple(self.objects.shape), (h, w))
            present = _object_ids(self.objects)
            if min(present, default=1) < 0 or not present <= ids:
                raise ValueError(f"objects holds ids {sorted(present - ids)} that object_info does not "
                                 "describe (ids must be >= 1, 0 = background)")

    @property
    def height(self) -> int:
        """Image height ``H`` in pixels."""
        return int(self.disparity.shape[0])

    @property
    def width(self) -> int:
        """Image width ``W`` in pixels."""
        return int(self.disparity.shape[1])

    @property
    def n_valid(self) -> int:
        """Number of pixels with a disparity."""
        return int(self.valid.sum())

    def object_mask(self, object_id: int) -> torch.Tensor:
        """Bool mask of one object's pixels, shape :math:`(H, W)` (valid disparity or not)."""
        if self.objects is None:
            raise ValueError(f"scene {self.name!r} has no instance map")
        if object_id not in {o.id for o in self.object_info}:
            raise ValueError(f"scene {self.name!r} has no object {object_id}; ids: "
                             f"{[o.id for o in self.object_info]}")
        return self.objects == object_id

    @property
    def main_object_mask(self) -> torch.Tensor | None:
        """Bool :math:`(H, W)` mask of the objects flagged ``main``, or None if there is none."""
        main = [o.id for o in self.object_info if o.main]
        if self.objects is None or not main:
            return None
        return torch.isin(self.objects, torch.tensor(main, dtype=torch.int64))

    def scored_mask(self, object_id: int | None = None) -> torch.Tensor | None:
        """The mask a run is scored against: object ``object_id``'s (:meth:`object_mask`), or the
        main objects' (:attr:`main_object_mask`) where it is None."""
        return self.main_object_mask if object_id is None else self.object_mask(object_id)

    def __repr__(self) -> str:
        parts = [f"{self.height}x{self.width}", f"valid {self.n_valid / self.valid.numel():.1%}",
                 "image" if self.image is not None else "no image", f"{len(self.object_info)} object(s)",
                 f"camera f={self.camera.focal_px:.1f}px" if self.camera is not None else "no camera"]
        return f"Scene({self.name!r}, {', '.join(parts)})"


def _object_ids(objects: torch.Tensor) -> set[int]:
    """Ids present in an instance map, background 0 excluded (numpy: torch.unique is slow on CPU)."""
    a = objects.detach().cpu().numpy().ravel()
    small = a.size > 0 and a.min() >= 0 and a.max() < 65536
    return set((np.flatnonzero(np.bincount(a)) if small else np.unique(a)).tolist()) - {0}


def _check_size(name: str, got: tuple[int, ...], expected: tuple[int, ...]) -> None:
    if got != expected:
        raise ValueError(f"{name} must have shape {expected} to match the disparity; got {got}")


# --------------------------------------------------------------------------------------- from arrays


def scene_from_arrays(
    disparity: torch.Tensor | np.ndarray,
    valid: torch.Tensor | np.ndarray | None = None,
    image: torch.Tensor | np.ndarray | None = None,
    objects: torch.Tensor | np.ndarray | None = None,
    camera: Camera | None = None,
    *,
    name: str = "arrays",
    object_info: list[ObjectInfo] | None = None,
    source: dict[str, str] | None = None,
) -> Scene:
    """Build a :class:`Scene` from in-memory arrays.

    Non-finite and negative disparities are always invalid (``valid`` is narrowed, with a warning, if
    it claims them). Without ``object_info``, objects are named ``object_<id>`` and id 1 is the main one
    (the convention of the shared data).

    Args:
        disparity: real-valued disparity map, pixels.
        valid: bool mask; default: finite and ``>= 0``.
        image: uint8 left image: a tensor ``(3, H, W)``/``(H, W)`` or an array ``(H, W, 3|4)``/``(H, W)``
            (numpy follows the OpenCV/scikit-image channels-last layout; RGB order assumed).
        objects: integer instance map, 0 = background.
        camera: the stereo camera.
        name: scene name.
        object_info: descriptions of the ids in ``objects``.
        source: provenance strings stored in :attr:`Scene.source`.

    Raises:
        ValueError: shapes disagree, wrong dtypes, or no valid disparity.

    Shape:
        - disparity, valid, objects: :math:`(H, W)`; image see above.
    """
    d = _to_tensor("disparity", disparity)
    if d.ndim != 2 or d.numel() == 0 or d.dtype == torch.bool or d.is_complex():
        raise ValueError(f"disparity must be a non-empty real (H, W) array; got shape {tuple(d.shape)}, "
                         f"dtype {d.dtype}")
    d = d.to(torch.float32)
    ok = torch.isfinite(d) & (d >= 0)
    if valid is None:
        v = ok
    else:
        v = _to_tensor("valid", valid)
        if v.dtype != torch.bool:
            raise TypeError(f"valid must be a bool mask; got dtype {v.dtype}")
        _check_size("valid", tuple(v.shape), tuple(d.shape))
        dropped = int((v & ~ok).sum())
        if dropped:
            log.warning("scene %r: %d pixel(s) marked valid hold non-finite or negative disparity; "
                        "made invalid", name, dropped)
        v = v & ok
    if not bool(v.any()):
        raise ValueError(f"scene {name!r}: no valid disparity (all {d.numel()} pixels invalid)")
    d = torch.where(v, d, torch.zeros((), dtype=torch.float32))
    img = None if image is None else _image_to_chw(image)
    obj = None
    if objects is not None:
        obj = _to_tensor("objects", objects)
        if obj.dtype == torch.bool or obj.is_floating_point() or obj.is_complex():
            raise TypeError(f"objects must be an integer id map; got dtype {obj.dtype}")
        obj = obj.to(torch.int64)
        if object_info is None:
            object_info = _infer_object_info(obj)
    return Scene(name=name, disparity=d, valid=v, image=img, objects=obj, object_info=list(object_info or []),
                 camera=camera, source=dict(source or {}))


def _to_tensor(name: str, x: Any) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu()
    if isinstance(x, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(x))
    raise TypeError(f"{name} must be a torch.Tensor or numpy.ndarray; got {type(x).__name__}")


def _image_to_chw(image: torch.Tensor | np.ndarray) -> torch.Tensor:
    """uint8 image -> (3, H, W); tensors are channels-first, numpy arrays channels-last."""
    t = _to_tensor("image", image)
    if t.dtype != torch.uint8:
        raise TypeError(f"image must be uint8; got dtype {t.dtype}")
    if t.ndim == 3 and isinstance(image, np.ndarray):
        t = t.permute(2, 0, 1)  # (H, W, C) -> (C, H, W)
    if t.ndim == 2:
        t = t.unsqueeze(0)
    if t.ndim != 3 or t.shape[0] not in (1, 3, 4):
        raise ValueError(f"image must be (3, H, W) or (H, W) for tensors, (H, W, 3|4) or (H, W) for numpy; "
                         f"got shape {tuple(image.shape)}")
    return t[:3].expand(3, -1, -1).contiguous() if t.shape[0] == 1 else t[:3].contiguous()


def _infer_object_info(objects: torch.Tensor) -> list[ObjectInfo]:
    ids = sorted(_object_ids(objects))
    return [ObjectInfo(id=i, name=f"object_{i}", main=i == 1) for i in ids]

