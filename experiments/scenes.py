"""The development scenes, declared once in ``conf/scene_lists/dev.yaml`` and loaded here.

Every consumer (the validation protocol, the computed-disparity and real-scene scripts, the
quality tests) reads the same list, so a scene is added in one place.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

SCENES_FILE = Path(__file__).resolve().parents[1] / "conf" / "scene_lists" / "dev.yaml"


@dataclass
class SceneSpec:
    """One development scene: ``folder`` under the data root and where its disparity comes from.

    ``disparity``: ``"gt"`` (the folder's own map), a file name in the folder (e.g. KITTI's
    ``disp_est.png``), or ``"sgbm"``: computed from ``left`` / ``right`` with our default SGBM and
    ``ndisp`` disparities. The folder's object masks score every variant.
    """

    name: str
    folder: str
    disparity: str = "gt"
    left: Optional[str] = None
    right: Optional[str] = None
    ndisp: int = 128

    @property
    def computed(self) -> bool:
        return self.disparity != "gt"


def dev_scenes(names: list[str] | None = None) -> list[SceneSpec]:
    """The specs of ``conf/scene_lists/dev.yaml``: all in the file's order, or those named in the given order."""
    import yaml

    specs = [SceneSpec(**d) for d in yaml.safe_load(SCENES_FILE.read_text())]
    if names is None:
        return specs
    known = {s.name for s in specs}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown development scene(s) {unknown}; {SCENES_FILE} lists {sorted(known)}")
    by_name = {s.name: s for s in specs}
    return [by_name[n] for n in names]


def load_dev_scene(spec: SceneSpec, data_dir: str | Path) -> Any:
    """The :class:`~somtorch.disparity.scene.Scene` of ``spec`` with the folder's object masks."""
    from somtorch.disparity.io import read_image
    from somtorch.disparity.scene import load_scene, scene_from_arrays
    from somtorch.disparity.stereo import SGBMParams, compute_disparity

    path = Path(data_dir) / spec.folder
    if not path.is_dir():
        raise FileNotFoundError(f"scene folder not found: {path} (set paths.data_dir)")
    if spec.disparity == "gt":
        return load_scene(path)
    if spec.disparity != "sgbm":
        scene = load_scene(path, disparity_file=spec.disparity)
        scene.name = spec.name
        return scene
    gt = load_scene(path)
    images = []
    for f in (spec.left, spec.right):
        if f is None:
            raise ValueError(f"scene {spec.name!r}: disparity 'sgbm' needs left and right image files")
        im = read_image(path / f)  # (3, H, W) RGB uint8
        images.append(im.permute(1, 2, 0).numpy()[..., ::-1].copy())  # BGR, as OpenCV reads it
    disp, valid = compute_disparity(images[0], images[1], SGBMParams(numDisparities=spec.ndisp))
    return scene_from_arrays(disp, valid, image=gt.image, objects=gt.objects, object_info=gt.object_info,
                             camera=gt.camera, name=spec.name)
