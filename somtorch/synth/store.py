"""Synthetic frames on disk: the Middlebury layout :func:`~somtorch.disparity.load_scene` reads.

Cache layout (root: ``$SOMTORCH_CORPUS``, else ``$SOMTORCH_CACHE/corpus``, else ``~/.cache/somtorch/corpus``)::

    <root>/<family>_<camera>[_x<scale>]/
        manifest.json            {"generator": <hash>, "frames": {"00007": {"generator", "objects", "main", ...}}}
        00007/
            disp0GT.pfm          GT disparity of the left view (inf = the ray hit nothing: sky)
            disp_sgbm.pfm        SGBM disparity (inf = no match)
            im0.png, im1.png     left and right RGB
            calib.txt            Middlebury: cam0, cam1, doffs=0, baseline (mm), width, height, ndisp
            objects.png          instance map (uint8, uint16 past 255 ids), 0 = background / support
            objects.json         {"objects": [{"id", "name", "main", "pixels", ...}], "family", "camera", "seed", ...}

A frame folder is written into a temporary sibling and renamed: it appears complete or not at all.
The manifest's ``generator`` hash covers the generator's source (this package and the SGBM
module); a frame whose entry carries another hash is generated again.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from somtorch.atomic import write_json
from somtorch.disparity.pfm import write_pfm
from somtorch.synth.frame import Frame, generate_frame

__all__ = ["cache_root", "dataset_dir", "ensure_frame", "frame_dir", "generator_version", "load_frame",
           "read_manifest", "write_frame", "VERSIONS"]

VERSIONS = {"gt": None, "sgbm": "disp_sgbm.pfm"}
"""Disparity versions of a frame: ``load_scene(folder, disparity_file=VERSIONS[v])``."""


def cache_root() -> Path:
    """The corpus: ``$SOMTORCH_CORPUS``, else ``$SOMTORCH_CACHE/corpus``, else ``~/.cache/somtorch/corpus``
    (the folder :func:`experiments.datasets.corpus_dir` reads)."""
    if os.environ.get("SOMTORCH_CORPUS"):
        return Path(os.environ["SOMTORCH_CORPUS"]).expanduser()
    base = os.environ.get("SOMTORCH_CACHE")
    return (Path(base).expanduser() if base else Path.home() / ".cache" / "somtorch") / "corpus"


def dataset_dir(family: str, camera: str, scale: float = 1.0, root: str | Path | None = None) -> Path:
    """Folder of one family x camera (x scale) data set."""
    name = f"{family}_{camera}" + ("" if scale == 1.0 else f"_x{scale:g}")
    return (cache_root() if root is None else Path(root)) / name


def frame_dir(family: str, camera: str, seed: int, scale: float = 1.0, root: str | Path | None = None) -> Path:
    """Folder of one frame: ``<dataset>/<seed:05d>``."""
    return dataset_dir(family, camera, scale, root) / f"{seed:05d}"


@cache
def generator_version() -> str:
    """12 hex digits of SHA-256 over the generator's source files (synth package + SGBM module)."""
    here = Path(__file__).resolve().parent
    files = sorted(here.glob("*.py")) + [here.parent / "disparity" / "stereo.py"]
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:12]


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError("OpenCV could not encode a PNG")
    return buf.tobytes()


def _calib(frame: Frame) -> str:
    c = frame.camera
    k = f"[{c.focal_px!r} 0 {c.cx!r}; 0 {c.focal_px!r} {c.cy!r}; 0 0 1]"
    h, w = frame.disparity.shape
    return (f"cam0={k}\ncam1={k}\ndoffs=0\nbaseline={c.baseline!r}\nwidth={w}\nheight={h}\n"
            f"ndisp={frame.ndisp}\n")


def write_frame(frame: Frame, folder: str | Path) -> Path:
    """Write ``frame`` into ``folder`` atomically (a temporary sibling renamed; an old folder replaced).

    Returns:
        The folder.
    """
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        write_pfm(tmp / "disp0GT.pfm", frame.disparity)
        if frame.sgbm is not None:
            write_pfm(tmp / "disp_sgbm.pfm", frame.sgbm)
        for name, img in (("im0.png", frame.left), ("im1.png", frame.right)):
            (tmp / name).write_bytes(_png(np.ascontiguousarray(img.permute(1, 2, 0).numpy()[:, :, ::-1])))
        ids = frame.objects.numpy()
        (tmp / "objects.png").write_bytes(_png(ids.astype(np.uint8 if ids.max() < 256 else np.uint16)))
        (tmp / "calib.txt").write_text(_calib(frame), encoding="utf-8")
        doc = {"objects": frame.object_info, **frame.meta, "generator": generator_version(),
               "main_rule": "most visible pixels in the left view; ties: smaller median depth"}
        (tmp / "objects.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        os.chmod(tmp, 0o755)
        if folder.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.old.", dir=folder.parent))
            os.replace(folder, old / "f")
            os.replace(tmp, folder)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return folder


def read_manifest(dataset: str | Path) -> dict[str, Any]:
    """The data set's manifest (empty if there is none or it is unreadable)."""
    path = Path(dataset) / "manifest.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {"frames": {}}
    return doc if isinstance(doc.get("frames"), dict) else {"frames": {}}


def manifest_entry(frame: Frame) -> dict[str, Any]:
    """One manifest row: generator hash, object count, main object, pitch, ndisp."""
    return {"generator": generator_version(), "objects": len(frame.object_info),
            "main": frame.object_info[0]["name"], "pitch_deg": frame.meta["pitch_deg"], "ndisp": frame.ndisp,
            "sub_seed": frame.meta["sub_seed"]}


def write_manifest(dataset: str | Path, entries: dict[str, dict[str, Any]]) -> Path:
    """Atomically rewrite the manifest with ``entries`` (``{"<seed:05d>": entry}``)."""
    return write_json(Path(dataset) / "manifest.json",
                      {"generator": generator_version(), "frames": dict(sorted(entries.items()))})


def is_current(dataset: str | Path, seed: int, manifest: dict[str, Any] | None = None) -> bool:
    """The frame's folder exists and its manifest entry has this generator's hash."""
    manifest = read_manifest(dataset) if manifest is None else manifest
    entry = manifest["frames"].get(f"{seed:05d}")
    return (Path(dataset) / f"{seed:05d}").is_dir() and isinstance(entry, dict) and \
        entry.get("generator") == generator_version()


def ensure_frame(family: str, seed: int, camera: str = "oakd", *, scale: float = 1.0,
                 root: str | Path | None = None) -> Path:
    """The frame's folder, generated (and entered in the manifest) unless already current."""
    dataset = dataset_dir(family, camera, scale, root)
    manifest = read_manifest(dataset)
    if not is_current(dataset, seed, manifest):
        frame = generate_frame(family, seed, camera, scale=scale)
        write_frame(frame, dataset / f"{seed:05d}")
        manifest = read_manifest(dataset)  # re-read: another writer may have added rows
        write_manifest(dataset, {**manifest["frames"], f"{seed:05d}": manifest_entry(frame)})
    return dataset / f"{seed:05d}"


def load_frame(family: str, seed: int, camera: str = "oakd", version: str = "gt", *, scale: float = 1.0,
               root: str | Path | None = None):
    """The :class:`~somtorch.disparity.scene.Scene` of a frame (generated into the cache if needed).

    ``version``: ``"gt"`` (``disp0GT.pfm``) or ``"sgbm"`` (``disp_sgbm.pfm``).
    """
    from somtorch.disparity import load_scene
    from somtorch.validation import check_choice

    check_choice("version", version, VERSIONS)
    folder = ensure_frame(family, seed, camera, scale=scale, root=root)
    scene = load_scene(folder, disparity_file=VERSIONS[version])
    scene.name = f"{family}_{camera}_{seed:05d}_{version}"
    return scene
