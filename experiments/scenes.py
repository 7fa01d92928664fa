"""The development scenes, declared once in ``conf/scene_lists/dev.yaml`` and loaded here.

Every consumer (the validation protocol, the computed-disparity and real-scene scripts, the
quality tests) reads the same list, so a scene is added in one place.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from . import CONF

SCENE_LISTS = CONF / "scene_lists"
SCENES_FILE = SCENE_LISTS / "dev.yaml"
LABELS = CONF / "labels"


@dataclass
class SceneSpec:
    """One development scene: ``folder`` under the data root and where its disparity comes from.

    ``disparity``: ``"gt"`` (the folder's own map), a file name in the folder (e.g. KITTI's
    ``disp_est.png``), or ``"sgbm"``: computed from ``left`` / ``right`` with our default SGBM and
    ``ndisp`` disparities. The folder's object masks score every variant.

    ``labels``: a polygon label file under ``conf/labels/`` (:func:`somtorch.disparity.labels.
    read_polygon_labels`) that gives the scene its objects where the data folder has no mask.

    ``junk``: a synthetic failure class added to the map (see :func:`add_junk`): ``"border"`` (a
    band of speckles along the top and left borders at the main object's disparity, as SGBM leaves
    where the other view has no match), ``"specks"`` (isolated 2×2 specks near the object, also at
    its disparity), ``"pole"`` (a thin pole in front of the object, occluding it: the issue's
    traffic-light pole; 1.5 % of the width, 1.25 × the object's 95th-percentile disparity, from
    half-way between the image top and the object's top down to the bottom row, a third of the
    way across the object), ``"flip"`` (the mirrored scene: a check that the rule has no
    left/right bias) or ``"resample:F"`` (the map resampled by the factor F).
    """

    name: str
    folder: str
    disparity: str = "gt"
    left: Optional[str] = None
    right: Optional[str] = None
    ndisp: int = 128
    junk: Optional[str] = None
    labels: Optional[str] = None

    @property
    def computed(self) -> bool:
        return self.disparity != "gt" or self.junk is not None


def dev_scenes(names: list[str] | None = None, scene_list: str = "dev") -> list[SceneSpec]:
    """The specs of ``conf/scene_lists/<scene_list>.yaml``: all in the file's order, or those named
    in the given order."""
    import yaml

    path = SCENE_LISTS / f"{scene_list}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in SCENE_LISTS.glob("*.yaml"))
        raise ValueError(f"scene_list={scene_list!r}: no {path}; known lists: {known}")
    specs = [SceneSpec(**d) for d in yaml.safe_load(path.read_text())]
    for s in specs:
        if s.junk is not None:
            try:
                check_junk_kind(s.junk)
            except ValueError as e:
                raise ValueError(f"{path}: scene {s.name!r}: {e}") from None
    if names is None:
        return specs
    known = {s.name for s in specs}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown scene(s) {unknown}; {path} lists {sorted(known)}")
    by_name = {s.name: s for s in specs}
    return [by_name[n] for n in names]


def load_dev_scene(spec: SceneSpec, data_dir: str | Path) -> Any:
    """The :class:`~somtorch.disparity.scene.Scene` of ``spec`` with the folder's object masks (or
    those of ``spec.labels``)."""
    scene = _load(spec, Path(data_dir))
    if spec.labels:
        import dataclasses

        from somtorch.disparity.labels import read_polygon_labels

        objects, info = read_polygon_labels(LABELS / spec.labels, tuple(scene.disparity.shape))
        scene = dataclasses.replace(scene, objects=objects, object_info=info)
    return add_junk(scene, spec.junk, seed=sum(map(ord, spec.name))) if spec.junk else scene


def _load(spec: SceneSpec, data_dir: Path) -> Any:
    from somtorch.disparity.io import read_image
    from somtorch.disparity.scene import load_scene, scene_from_arrays
    from somtorch.disparity.stereo import SGBMParams, compute_disparity

    path = data_dir / spec.folder
    if not path.is_dir():
        raise FileNotFoundError(f"scene folder not found: {path} (set paths.data_dir)")
    if spec.disparity == "gt":
        scene = load_scene(path)
        scene.name = spec.name
        return scene
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


JUNK_KINDS = ("border", "specks", "pole", "flip", "resample:F")


def check_junk_kind(kind: str) -> None:
    """Raise ``ValueError`` naming the known kinds unless ``kind`` is one of :data:`JUNK_KINDS`
    (``resample:F`` with F a positive number)."""
    if kind.startswith("resample:"):
        try:
            ok = float(kind.split(":", 1)[1]) > 0
        except ValueError:
            ok = False
        if ok:
            return
        raise ValueError(f"junk kind {kind!r}: resample needs a positive factor, e.g. resample:0.5")
    if kind not in JUNK_KINDS:
        raise ValueError(f"unknown junk kind {kind!r}: {', '.join(JUNK_KINDS)}")


def add_junk(scene: Any, kind: str, *, seed: int = 0) -> Any:
    """A copy of ``scene`` with a synthetic failure class added (see :class:`SceneSpec` ``junk``).

    The junk sits at the main object's median disparity, so that disparity alone cannot tell it
    from the object; the masks are unchanged (junk pixels are background).
    """
    import dataclasses

    import torch

    from somtorch.disparity.resize import resize_scene

    check_junk_kind(kind)
    if kind.startswith("resample:"):
        f = float(kind.split(":", 1)[1])
        out = resize_scene(scene, max(8, round(scene.width * f)), max(8, round(scene.height * f)))
        return dataclasses.replace(out, name=f"{scene.name}+{kind}")
    if kind == "flip":  # the mirrored scene (a mirrored world is a valid world; the camera is dropped)
        flip = {f: getattr(scene, f).flip(-1) for f in ("disparity", "valid", "image", "objects")
                if getattr(scene, f) is not None}
        return dataclasses.replace(scene, **flip, camera=None, name=f"{scene.name}+{kind}")
    obj = scene.main_object_mask & scene.valid
    d_obj = float(scene.disparity[obj].median())
    h, w = scene.disparity.shape
    g = torch.Generator().manual_seed(seed)
    junk = torch.zeros(h, w, dtype=torch.bool)
    if kind == "border":
        band = max(2, round(0.03 * min(h, w)))
        junk[:band] = torch.rand(band, w, generator=g) < 0.3
        junk[:, :band] |= torch.rand(h, band, generator=g) < 0.3
    elif kind == "specks":
        ys, xs = obj.nonzero(as_tuple=True)
        y0, y1, x0, x1 = int(ys.min()), int(ys.max()), int(xs.min()), int(xs.max())
        my, mx = (y1 - y0) // 2 + 1, (x1 - x0) // 2 + 1  # a frame half the object's size around it
        n = 40
        yy = torch.randint(max(0, y0 - my), min(h - 2, y1 + my), (n,), generator=g)
        xx = torch.randint(max(0, x0 - mx), min(w - 2, x1 + mx), (n,), generator=g)
        for y, x in zip(yy.tolist(), xx.tolist()):
            junk[y:y + 2, x:x + 2] = True
    elif kind == "pole":  # a thin pole in front of the object (it occludes what it crosses)
        ys, xs = obj.nonzero(as_tuple=True)
        x0, x1 = int(xs.min()), int(xs.max())
        pw = max(2, round(0.015 * w))
        px = x0 + (x1 - x0) // 3
        junk[int(ys.min()) // 2:, px:px + pw] = True
        d_near = float(torch.quantile(scene.disparity[obj].double()[::max(1, int(obj.sum()) // 20000)], 0.95))
        disparity = torch.where(junk, 1.25 * d_near, scene.disparity)
        objects = torch.where(junk, 0, scene.objects)
        return dataclasses.replace(scene, disparity=disparity, valid=scene.valid | junk, objects=objects,
                                   name=f"{scene.name}+{kind}")
    junk &= ~obj
    disparity = torch.where(junk, d_obj, scene.disparity)
    return dataclasses.replace(scene, disparity=disparity, valid=scene.valid | junk,
                               name=f"{scene.name}+{kind}")