"""One scene description (disparity + valid mask, left image, instance map, camera) for every data set.

:func:`load_scene` is the single entry point: an embedded scene name (``"motorcycle"``), a folder in
one of the known layouts (Middlebury/ETH3D, KITTI devkit, SceneFlow, OAK-D; see
``../shared/data/README.md``), or a single disparity file. Files are validated against each other
(sizes, ids) before a :class:`Scene` is built; every problem raises
:class:`~somtorch.validation.DataFileError` naming the file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from somtorch.disparity.camera import (
    Camera,
    _kitti_camera,
    _middlebury_camera,
    _oakd_camera,
    _sceneflow_camera,
    read_middlebury_camera,
)
from somtorch.disparity.io import (
    DISPARITY_SUFFIXES,
    parse_middlebury_calib,
    read_disparity,
    read_image,
    read_json,
    read_mask,
)
from somtorch.validation import DataFileError, check_tensor, require_file

__all__ = [
    "EMBEDDED_SCENES",
    "Camera",
    "ObjectInfo",
    "Scene",
    "load_scene",
    "parse_middlebury_calib",
    "read_middlebury_camera",
    "scene_from_arrays",
]

log = logging.getLogger(__name__)

EMBEDDED_SCENES: tuple[str, ...] = ("motorcycle",)
"""Scene names :func:`load_scene` serves without any file."""


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
        return int(self.disparity.shape[0])

    @property
    def width(self) -> int:
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


# ------------------------------------------------------------------------------------------ load_scene


@dataclass(frozen=True)
class _Layout:
    name: str
    disparities: tuple[str, ...]  # candidates, first present wins
    image: str
    camera: Callable[[Path, tuple[int, int]], tuple[Camera | None, str | None]]


_LAYOUTS = (
    _Layout("middlebury", ("disp0GT.pfm", "disp0.pfm"), "im0.png", _middlebury_camera),  # also ETH3D
    _Layout("kitti", ("disp_gt.png",), "image.png", _kitti_camera),
    _Layout("sceneflow", ("disparity_left.pfm",), "left_cleanpass.png", _sceneflow_camera),
    _Layout("oakd", ("disp_sgbm.png",), "left.png", _oakd_camera),
)

# full-resolution Middlebury 2014 "Motorcycle-perfect" calib.txt (2964x2000), the source of skimage's copy
_MOTORCYCLE_FULL_WIDTH = 2964
_MOTORCYCLE_FULL = Camera(focal_px=3979.911, cx=1244.772, cy=1019.507, baseline=193.001, baseline_unit="mm",
                          doffs=124.343)


def load_scene(spec: str | Path, *, disparity_file: str | Path | None = None) -> Scene:
    """Load a scene from an embedded name, a data-set folder or a single disparity file.

    ``spec`` is one of:

    * ``"motorcycle"`` (a ``str``; embedded names win over a same-named relative folder, pass a
      ``Path`` to force the folder): ``skimage.data.stereo_motorcycle()``, 500x741, GT ``inf`` = no GT.
      scikit-image ships Middlebury 2014 "Motorcycle-perfect" (2964x2000) down-sampled 4x, so its
      camera is that full-resolution calib (f=3979.911, cx=1244.772, cy=1019.507, doffs=124.343,
      baseline=193.001 mm) times ``width / 2964`` = 0.25: f=994.978, cx=311.193, cy=254.877,
      doffs=31.086, exactly what skimage documents. ``Motorcycle_Q/calib.txt`` (f=999.421,
      cx=294.182, doffs=32.778) belongs to the MiddEval3 re-rectification (full-res f=3997.684,
      2964x1988), another image geometry whose GT is ~2.4 px larger at the same pixels; it is not
      used. Depths of the two scenes, each with its own camera, differ by ~5 % (median, measured).
    * a folder; the layout is detected from the first disparity file present:

      - ``middlebury`` (also ETH3D): ``disp0GT.pfm`` or ``disp0.pfm``, ``im0.png``, ``calib.txt`` (mm);
      - ``kitti``: ``disp_gt.png``, ``image.png``; camera f=721.5 px, baseline 0.54 m, cx=W/2, cy=H/2,
        ``approximate=True`` (the devkit demo ships no calibration);
      - ``sceneflow``: ``disparity_left.pfm``, ``left_cleanpass.png``; f=1050, cx=479.5, cy=269.5,
        baseline 1 (``"unit"``);
      - ``oakd``: ``disp_sgbm.png``, ``left.png``, ``stereodemo_calibration.json``;

      plus ``objects.png`` + ``objects.json`` when present (:class:`ObjectInfo` from the json's
      ``objects`` list). ``disparity_file`` (relative to the folder, or absolute) overrides the
      disparity, e.g. ``"disp_est.png"`` for the KITTI estimate.
    * a ``.pfm``/``.png``/``.npy``/``.npz`` file: disparity only, no image or camera.

    Raises:
        FileNotFoundError: ``spec`` (or ``disparity_file``) does not exist.
        DataFileError: an unrecognised folder (the message lists the files looked for), sizes that
            disagree (naming the file and both sizes), undescribed object ids, an unreadable file, or
            no valid disparity.

    Shape:
        - See :class:`Scene`.
    """
    if isinstance(spec, str) and spec in EMBEDDED_SCENES:
        if disparity_file is not None:
            raise ValueError(f"disparity_file applies to folders, not to the embedded scene {spec!r}")
        return _load_motorcycle()
    path = Path(spec).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"scene not found: {path} (expected a folder, a "
                                f"{'/'.join(DISPARITY_SUFFIXES)} file, or an embedded scene name "
                                f"{list(EMBEDDED_SCENES)})")
    if path.is_dir():
        return _load_folder(path, disparity_file)
    if disparity_file is not None:
        raise ValueError(f"disparity_file applies to folders; {path} is a file")
    disparity, valid = read_disparity(path)
    _require_some_valid(path, valid)
    return Scene(name=path.stem, disparity=disparity, valid=valid,
                 source={"layout": "file", "disparity": str(path)})


def _load_motorcycle() -> Scene:
    from skimage import data  # lazy: scikit-image is only needed for this scene

    left, _right, disp = data.stereo_motorcycle()
    camera = _MOTORCYCLE_FULL.scaled(disp.shape[1] / _MOTORCYCLE_FULL_WIDTH)
    return scene_from_arrays(np.asarray(disp, dtype=np.float32), image=left, camera=camera, name="motorcycle",
                             source={"layout": "embedded", "disparity": "skimage.data.stereo_motorcycle()",
                                     "camera": "Middlebury 2014 Motorcycle-perfect calib x width/2964"})


def _detect_layout(folder: Path, disparity_file: str | Path | None) -> tuple[_Layout | None, Path]:
    """The folder's layout (None for a bare ``disparity_file``) and the disparity file to read."""
    for layout in _LAYOUTS:
        found = next((folder / n for n in layout.disparities if (folder / n).is_file()), None)
        if found is not None:
            break
    else:  # no known disparity file: an explicit one still tells the layout by its image
        layout = next((lay for lay in _LAYOUTS if (folder / lay.image).is_file()), None)
    if disparity_file is not None:
        return layout, require_file(folder / Path(disparity_file).expanduser(), "disparity file")
    if found is None:
        looked = "; ".join(f"{lay.name}: {' or '.join(lay.disparities)}" for lay in _LAYOUTS)
        raise DataFileError(folder, f"no recognisable disparity file; looked for {looked} (pass "
                                    "disparity_file= to name one)")
    return layout, found


def _load_folder(folder: Path, disparity_file: str | Path | None) -> Scene:
    layout, disp_path = _detect_layout(folder, disparity_file)
    disparity, valid = read_disparity(disp_path)
    _require_some_valid(disp_path, valid)
    hw = (disparity.shape[0], disparity.shape[1])
    source = {"layout": layout.name if layout else "disparity_only", "disparity": str(disp_path)}
    image = camera = None
    if layout is not None:
        if (folder / layout.image).is_file():
            image = read_image(folder / layout.image)
            _require_size(folder / layout.image, "image", (image.shape[1], image.shape[2]), hw, disp_path)
            source["image"] = str(folder / layout.image)
        camera, camera_source = layout.camera(folder, hw)
        if camera is not None:
            source["camera"] = camera_source
    objects, object_info = _load_objects(folder, hw, disp_path, source)
    return Scene(name=folder.name, disparity=disparity, valid=valid, image=image, objects=objects,
                 object_info=object_info, camera=camera, source=source)


def _load_objects(folder: Path, hw: tuple[int, int], disp_path: Path, source: dict[str, str]
                  ) -> tuple[torch.Tensor | None, list[ObjectInfo]]:
    png, js = folder / "objects.png", folder / "objects.json"
    if not png.is_file():
        if js.is_file():
            log.warning("%s ignored: there is no objects.png next to it", js)
        return None, []
    objects = read_mask(png)
    _require_size(png, "instance map", (objects.shape[0], objects.shape[1]), hw, disp_path)
    source["objects"] = str(png)
    if not js.is_file():
        log.warning("%s: no objects.json; objects named object_<id>, id 1 taken as main", folder)
        return objects, _infer_object_info(objects)
    info = _read_object_info(js)
    unknown = sorted(_object_ids(objects) - {o.id for o in info})
    if unknown:
        raise DataFileError(png, f"holds object id(s) {unknown} that {js.name} does not describe")
    source["object_info"] = str(js)
    return objects, info


def _read_object_info(path: Path) -> list[ObjectInfo]:
    entries = read_json(path).get("objects")
    if not isinstance(entries, list):
        raise DataFileError(path, "expected an 'objects' list of {id, name, main} entries")
    info = []
    for i, e in enumerate(entries):
        if not (isinstance(e, dict) and type(e.get("id")) is int and e["id"] >= 1
                and isinstance(e.get("name"), str) and isinstance(e.get("main", False), bool)):
            raise DataFileError(path, f"objects[{i}] needs an int 'id' >= 1, a str 'name' and a bool 'main'; "
                                      f"got {str(e)[:80]}")
        info.append(ObjectInfo(id=e["id"], name=e["name"], main=e.get("main", False)))
    if len({o.id for o in info}) != len(info):
        raise DataFileError(path, f"duplicate object ids {[o.id for o in info]}")
    return info


def _require_size(path: Path, what: str, got: tuple[int, int], hw: tuple[int, int], ref: Path) -> None:
    if tuple(got) != hw:
        raise DataFileError(path, f"{what} size {got[0]}x{got[1]} (HxW) does not match the disparity "
                                  f"{hw[0]}x{hw[1]} from {ref.name}")


def _require_some_valid(path: Path, valid: torch.Tensor) -> None:
    if not bool(valid.any()):
        raise DataFileError(path, f"no valid disparity: all {valid.numel()} pixels are invalid "
                                  "(non-finite, negative, or the format's 'no value' code)")

