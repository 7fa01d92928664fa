"""Loading a :class:`~somtorch.disparity.scene.Scene` from an embedded name, a data-set folder or
a single disparity file (:func:`load_scene`; the layouts of ``../shared/data/README.md``).

Files are validated against each other (sizes, ids) before a Scene is built; every problem
raises :class:`~somtorch.validation.DataFileError` naming the file.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from somtorch.disparity.camera import (
    Camera,
    _kitti_camera,
    _middlebury_camera,
    _oakd_camera,
    _sceneflow_camera,
)
from somtorch.disparity.io import DISPARITY_SUFFIXES, read_disparity, read_image, read_json, read_mask
from somtorch.disparity.scene import ObjectInfo, Scene, _infer_object_info, _object_ids, scene_from_arrays
from somtorch.validation import DataFileError, require_file

__all__ = ["EMBEDDED_SCENES", "load_scene"]
log = logging.getLogger("somtorch.disparity.scene")

EMBEDDED_SCENES: tuple[str, ...] = ("motorcycle",)


@dataclass(frozen=True)
class _Layout:
    name: str
    disparities: tuple[str, ...]  # candidates, first present wins
    image: str
    camera: Callable[[Path, tuple[int, int]], tuple[Camera | None, str | None]]
    scale: float | None = None  # stored value x scale = px, where the layout fixes it (8-bit PNG)


def _no_camera(folder: Path, hw: tuple[int, int]) -> tuple[Camera | None, str | None]:
    return None, None


_LAYOUTS = (
    _Layout("middlebury", ("disp0GT.pfm", "disp0.pfm"), "im0.png", _middlebury_camera),  # also ETH3D
    _Layout("kitti", ("disp_gt.png",), "image.png", _kitti_camera),
    _Layout("sceneflow", ("disparity_left.pfm",), "left_cleanpass.png", _sceneflow_camera),
    _Layout("oakd", ("disp_sgbm.png",), "left.png", _oakd_camera),
    # Middlebury 2005/2006 at third size (uint8 / 3) and 2003 at quarter size (uint8 / 4): no
    # calibration is published for these sets
    _Layout("middlebury2005", ("disp1.png",), "view1.png", _no_camera, 1 / 3),
    _Layout("middlebury2003", ("disp2.png",), "im2.png", _no_camera, 1 / 4),
)

# full-resolution Middlebury 2014 "Motorcycle-perfect" calib.txt (2964x2000), the source of skimage's copy
_MOTORCYCLE_FULL_WIDTH = 2964
_MOTORCYCLE_FULL = Camera(focal_px=3979.911, cx=1244.772, cy=1019.507, baseline=193.001, baseline_unit="mm",
                          doffs=124.343)


def load_scene(spec: str | Path, *, disparity_file: str | Path | None = None,
               disparity_scale: float | None = None) -> Scene:
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
      - ``middlebury2005`` (2005/2006 third size): ``disp1.png`` (uint8 / 3 px), ``view1.png``, no
        camera; ``middlebury2003`` (Teddy, quarter size): ``disp2.png`` (uint8 / 4 px), ``im2.png``;

      plus ``objects.png`` + ``objects.json`` when present (:class:`ObjectInfo` from the json's
      ``objects`` list). ``disparity_file`` (relative to the folder, or absolute) overrides the
      disparity, e.g. ``"disp_est.png"`` for the KITTI estimate, and ``disparity_scale`` its
      encoding (stored value × scale = px), e.g. ``0.25`` for the 8-bit ``disp2.png`` of the
      Middlebury 2001 scenes (``1/8``); the 2003 and 2005/2006 layouts set theirs.
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
        return _load_folder(path, disparity_file, disparity_scale)
    if disparity_file is not None:
        raise ValueError(f"disparity_file applies to folders; {path} is a file")
    disparity, valid = read_disparity(path, scale=disparity_scale)
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


def _load_folder(folder: Path, disparity_file: str | Path | None, disparity_scale: float | None = None) -> Scene:
    layout, disp_path = _detect_layout(folder, disparity_file)
    if disparity_scale is None and layout is not None and disparity_file is None:
        disparity_scale = layout.scale
    disparity, valid = read_disparity(disp_path, scale=disparity_scale)
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



KITTI_DISPARITIES = ("disp_occ_0", "disp_noc_0", "disp_occ_1", "disp_noc_1")


def load_kitti_frame(root: str | Path, frame: str | int, *, disparity: str = "disp_occ_0") -> Scene:
    """A frame of the official KITTI 2015 layout, as its users have it::

        training/image_2/000046_10.png      left colour image
        training/disp_occ_0/000046_10.png   LiDAR disparity (uint16 / 256, 0 = none)
        training/calib_cam_to_cam/000046.txt  (or a per-frame calib/000046.txt with P2 / P3)

    ``root`` is the ``training`` (or ``testing``) folder; ``frame`` its number (46 or ``"000046"``);
    ``disparity`` one of :data:`KITTI_DISPARITIES` (``disp_occ_0``: all pixels, ``disp_noc_0``:
    non-occluded only). The camera comes from the frame's calibration file when there is one.

    Raises:
        FileNotFoundError: the root or the frame's disparity file does not exist.
        DataFileError: a file cannot be read or the sizes disagree (naming the file).
    """
    from .camera import read_calibration

    root = Path(root).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"KITTI root not found: {root} (the 'training' folder of KITTI 2015)")
    if disparity not in KITTI_DISPARITIES:
        raise ValueError(f"disparity must be one of {KITTI_DISPARITIES}; got {disparity!r}")
    name = f"{int(frame):06d}" if str(frame).isdigit() else str(frame)
    disp_path = require_file(root / disparity / f"{name}_10.png", f"KITTI {disparity} file")
    disp, valid = read_disparity(disp_path)
    _require_some_valid(disp_path, valid)
    hw = (int(disp.shape[0]), int(disp.shape[1]))
    source = {"layout": "kitti2015", "disparity": str(disp_path)}
    image = camera = None
    img_path = root / "image_2" / f"{name}_10.png"
    if img_path.is_file():
        image = read_image(img_path)
        _require_size(img_path, "image", (image.shape[1], image.shape[2]), hw, disp_path)
        source["image"] = str(img_path)
    for calib in (root / "calib_cam_to_cam" / f"{name}.txt", root / "calib" / f"{name}.txt"):
        if calib.is_file():
            camera = read_calibration(calib)
            source["camera"] = str(calib)
            break
    return Scene(name=f"kitti_{name}", disparity=disp, valid=valid, image=image, camera=camera, source=source)
