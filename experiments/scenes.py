"""Loading the frames of the dataset registry (:mod:`experiments.datasets`) and the synthetic failure
classes added to real scenes (:func:`add_junk`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from . import CONF

LABELS = CONF / "labels"


def load_dev_scene(spec: Any, data_dir: str | Path) -> Any:
    """The :class:`~somtorch.disparity.scene.Scene` of ``spec`` with the folder's object masks (or
    those of ``spec.labels``)."""
    scene = _load(spec, Path(data_dir))
    if spec.labels:
        import dataclasses

        from somtorch.disparity.labels import read_polygon_labels

        objects, info = read_polygon_labels(LABELS / spec.labels, tuple(scene.disparity.shape))
        scene = dataclasses.replace(scene, objects=objects, object_info=info)
    return add_junk(scene, spec.junk, seed=sum(map(ord, spec.name))) if spec.junk else scene


def rematched(spec: Any, scene: Any, variant: str, data_dir: str | Path, corpus: str | Path | None = None
              ) -> Any | None:
    """``scene`` (the frame of ``spec``) with its SGBM map matched again from its stereo pair under
    the corpus's setting changed by ``SGBM_VARIANTS[variant]`` (the ``sgbm:NAME`` transform): the
    objects, image and camera kept. None for a frame whose map is not SGBM's from a pair the
    corpus holds (ground truth, a device's or an estimator's map, a frame with junk added).
    Synthetic frames read ``im0.png`` / ``im1.png`` and their ``ndisp`` (``calib.txt``) from the
    corpus (``corpus``, else :func:`~experiments.datasets.corpus_dir`); real ones ``spec.left`` /
    ``spec.right`` under ``data_dir``."""
    import dataclasses

    from somtorch.disparity import parse_middlebury_calib, scene_from_arrays
    from somtorch.disparity.stereo import SGBMParams

    check_junk_kind(f"sgbm:{variant}")
    if spec.junk:
        return None
    if spec.synthetic and spec.disparity == "disp_sgbm.pfm":
        from .datasets import corpus_dir

        path = Path(corpus or corpus_dir()) / spec.folder
        pair, ndisp = ("im0.png", "im1.png"), int(parse_middlebury_calib(path / "calib.txt")["ndisp"])
    elif not spec.synthetic and spec.disparity == "sgbm":
        path, pair, ndisp = Path(data_dir) / spec.folder, (spec.left, spec.right), spec.ndisp
    else:
        return None
    f = SGBM_RESOLUTION.get(variant, 1.0)
    if f != 1.0:  # the search range scales with the image, to a multiple of 16
        ndisp = max(16, -(-round(ndisp * f) // 16) * 16)
    params = dataclasses.replace(SGBMParams(numDisparities=ndisp), **SGBM_VARIANTS[variant])
    disp, valid = _matched(path, pair, params, f)
    if f != 1.0:
        from somtorch.disparity.resize import resize_scene

        scene = resize_scene(scene, disp.shape[-1], disp.shape[-2])
    return scene_from_arrays(disp, valid, image=scene.image, objects=scene.objects,
                             object_info=scene.object_info, camera=scene.camera,
                             name=f"{scene.name}+sgbm:{variant}")


def _matched(path: Path, pair: tuple[str, str], params: Any, factor: float = 1.0) -> tuple[Any, Any]:
    """SGBM's ``(disparity, valid)`` of the stereo pair ``pair`` (left, right image files) under
    ``path``, matched with ``params`` — on the pair downsized by ``factor`` (area interpolation)
    where it is not 1."""
    import cv2

    from somtorch.disparity.io import read_image
    from somtorch.disparity.stereo import compute_disparity

    # (3, H, W) RGB uint8 → (H, W, 3) BGR, as OpenCV reads it
    images = [read_image(path / f).permute(1, 2, 0).numpy()[..., ::-1].copy() for f in pair]
    if factor != 1.0:
        h, w = images[0].shape[:2]
        size = (max(8, round(w * factor)), max(8, round(h * factor)))
        images = [cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in images]
    return compute_disparity(images[0], images[1], params)


def _load(spec: Any, data_dir: Path) -> Any:
    from somtorch.disparity import load_scene, scene_from_arrays
    from somtorch.disparity.stereo import SGBMParams

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
    if spec.left is None or spec.right is None:
        raise ValueError(f"scene {spec.name!r}: disparity 'sgbm' needs left and right image files")
    disp, valid = _matched(path, (spec.left, spec.right), SGBMParams(numDisparities=spec.ndisp))
    return scene_from_arrays(disp, valid, image=gt.image, objects=gt.objects, object_info=gt.object_info,
                             camera=gt.camera, name=spec.name)


JUNK_KINDS = ("border", "specks", "pole", "flip", "resample:F", "noise:S", "quantize:Q", "scale:F", "bowl:P",
              "blotch:S", "smear:S", "relief:F", "wide:F", "offset:T", "shift:N", "sgbm:NAME")
#: ``sgbm:NAME``: the frame's stereo pair matched again with the corpus's SGBM setting
#: (:class:`~somtorch.disparity.stereo.SGBMParams`, its number of disparities) changed by these
#: fields — what another camera's matcher may be set to (:func:`rematched`).
SGBM_VARIANTS = {
    # the corpus setting without its filters: no uniqueness margin, no left-right check, no speckle filter
    "raw": {"uniquenessRatio": 0, "disp12MaxDiff": -1, "speckleWindowSize": 0},
    # a setting common in OpenCV's examples: a 7 px block, P1 / P2 from it, plain SGBM, a wide speckle range
    "tutorial": {"blockSize": 7, "P1": 8 * 3 * 7 ** 2, "P2": 32 * 3 * 7 ** 2, "speckleRange": 32,
                 "mode": "sgbm"},
    # the corpus setting on a camera of half the resolution (below): a small sensor's SGBM map
    "half": {},
}
#: ``sgbm:NAME`` on a camera of another resolution, the same field of view: the stereo pair is
#: downsized by this factor (area interpolation) before it is matched, the number of disparities with
#: it (to a multiple of 16), and the objects, image and camera are resampled to the map's size.
SGBM_RESOLUTION = {"half": 0.5}
#: ``blotch:S``: the correlation length of its noise, as a share of the image's shorter side.
BLOTCH_SCALE = 0.02


def check_junk_kind(kind: str) -> None:
    """Raise ``ValueError`` naming the known kinds unless ``kind`` is one of :data:`JUNK_KINDS`
    (``resample:F`` with F a positive number)."""
    for prefix, what, example in (("resample:", "a positive factor", "resample:0.5"),
                                  ("noise:", "a positive standard deviation in px", "noise:0.5"),
                                  ("quantize:", "a positive step in px", "quantize:1"),
                                  ("scale:", "a positive factor", "scale:0.5"),
                                  ("bowl:", "a positive relative error", "bowl:0.01"),
                                  ("blotch:", "a positive standard deviation in px", "blotch:0.5"),
                                  ("smear:", "a positive blur radius in px", "smear:2"),
                                  ("relief:", "a positive factor", "relief:0.5"),
                                  ("wide:", "a factor in (0, 1]", "wide:0.5"),
                                  ("offset:", "a positive offset in px", "offset:20")):
        if kind.startswith(prefix):
            try:
                v = float(kind.split(":", 1)[1])
                ok = v > 0 and (v <= 1 or prefix != "wide:")
            except ValueError:
                ok = False
            if ok:
                return
            raise ValueError(f"junk kind {kind!r}: {prefix[:-1]} needs {what}, e.g. {example}")
    if kind.startswith("shift:"):
        if kind[6:].isdigit() and int(kind[6:]) > 0:
            return
        raise ValueError(f"junk kind {kind!r}: shift needs a positive whole number of px, e.g. shift:5")
    if kind.startswith("sgbm:"):
        if kind[5:] in SGBM_VARIANTS:
            return
        raise ValueError(f"junk kind {kind!r}: sgbm needs a setting of {', '.join(SGBM_VARIANTS)}, "
                         "e.g. sgbm:raw")
    if kind not in JUNK_KINDS:
        raise ValueError(f"unknown junk kind {kind!r}: {', '.join(JUNK_KINDS)}")


def add_junk(scene: Any, kind: str, *, seed: int = 0) -> Any:
    """A copy of ``scene`` with a synthetic failure class added (see :class:`experiments.datasets.FrameSpec` ``junk``).

    The junk sits at the main object's median disparity, so that disparity alone cannot tell it
    from the object; the masks are unchanged (junk pixels are background).
    """
    import dataclasses

    import torch

    from somtorch.disparity.resize import resize_scene

    check_junk_kind(kind)
    if kind.startswith("sgbm:"):
        raise ValueError(f"junk kind {kind!r} matches a frame's stereo pair again: rematched(spec, ...), "
                         "not add_junk (a transform of validate)")
    if kind.startswith("resample:"):
        f = float(kind.split(":", 1)[1])
        out = resize_scene(scene, max(8, round(scene.width * f)), max(8, round(scene.height * f)))
        return dataclasses.replace(out, name=f"{scene.name}+{kind}")
    if kind.startswith("noise:"):  # a dense sensor's per-pixel noise: Gaussian, on every valid pixel
        sigma = float(kind.split(":", 1)[1])
        g = torch.Generator().manual_seed(seed)
        noise = torch.randn(scene.disparity.shape, generator=g, dtype=scene.disparity.dtype)
        noisy = scene.disparity + sigma * noise
        keep = scene.valid & (noisy > 0)  # a disparity pushed to 0 or below is no measurement
        return dataclasses.replace(scene, disparity=torch.where(keep, noisy, scene.disparity), valid=keep,
                                   name=f"{scene.name}+{kind}")
    if kind.startswith("scale:"):  # another rig: f·B (focal length × baseline) multiplies every disparity
        f = float(kind.split(":", 1)[1])
        return dataclasses.replace(scene, disparity=torch.where(scene.valid, scene.disparity * f, scene.disparity),
                                   name=f"{scene.name}+{kind}")
    if kind.startswith("offset:"):  # a rig whose principal points differ: d + T (Middlebury's doffs)
        t = float(kind.split(":", 1)[1])
        moved = torch.where(scene.valid, scene.disparity + t, scene.disparity)
        return dataclasses.replace(scene, disparity=moved, name=f"{scene.name}+{kind}")
    if kind.startswith("bowl:"):  # a dense sensor's systematic error: relative, growing to the corners
        p = float(kind.split(":", 1)[1])
        h, w = scene.disparity.shape
        ys = torch.linspace(-1.0, 1.0, h, dtype=torch.float64)[:, None]
        xs = torch.linspace(-1.0, 1.0, w, dtype=torch.float64)[None, :]
        gain = (1.0 + p * (ys * ys + xs * xs - 1.0)).to(scene.disparity.dtype)  # 1 − p centre, 1 + p corner
        bent = torch.where(scene.valid, scene.disparity * gain, scene.disparity)
        return dataclasses.replace(scene, disparity=bent, name=f"{scene.name}+{kind}")
    if kind.startswith("blotch:"):  # a filtered dense sensor's noise: correlated over a few px, std S
        import torch.nn.functional as F

        sigma = float(kind.split(":", 1)[1])
        h, w = scene.disparity.shape
        s = max(1.0, BLOTCH_SCALE * min(h, w))
        r = int(3 * s)
        k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float64) / s) ** 2)
        k = (k / k.sum()).float()
        g = torch.Generator().manual_seed(seed)
        n = torch.randn(1, 1, h + 2 * r, w + 2 * r, generator=g)
        n = F.conv2d(F.conv2d(n, k.view(1, 1, -1, 1)), k.view(1, 1, 1, -1))[0, 0]
        noisy = scene.disparity + sigma * n / n.std()
        keep = scene.valid & (noisy > 0)
        return dataclasses.replace(scene, disparity=torch.where(keep, noisy, scene.disparity), valid=keep,
                                   name=f"{scene.name}+{kind}")
    if kind.startswith("wide:"):  # a lens F × as long from the same place, f·B kept: the view shrinks to
        # its centre and the floor around it comes into view (the background's plane, continued)
        f = float(kind.split(":", 1)[1])
        h, w = scene.disparity.shape
        nw, nh = max(8, round(w * f)), max(8, round(h * f))
        small = resize_scene(scene, nw, nh)
        y0, x0 = (h - nh) // 2, (w - nw) // 2
        d_small = small.disparity * (w / nw)  # resize_scene scales disparities with the width: undone
        bg = small.valid if small.objects is None else small.valid & (small.objects == 0)
        if int(bg.sum()) < 3:  # an object filling the view: the plane of the whole map
            bg = small.valid
        ys, xs = bg.nonzero(as_tuple=True)
        a_ = torch.stack([xs.double() + x0, ys.double() + y0, torch.ones(xs.numel(), dtype=torch.float64)], 1)
        coef = torch.linalg.lstsq(a_, d_small[bg].double()[:, None]).solution[:, 0]
        yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                                indexing="ij")
        disparity = (coef[0] * xx + coef[1] * yy + coef[2]).to(scene.disparity.dtype)
        valid = disparity > 0
        disparity[y0:y0 + nh, x0:x0 + nw] = d_small
        valid[y0:y0 + nh, x0:x0 + nw] = small.valid
        disparity = torch.where(valid, disparity, 0.0)
        objects = image = None
        if small.objects is not None:
            objects = torch.zeros(h, w, dtype=small.objects.dtype)
            objects[y0:y0 + nh, x0:x0 + nw] = small.objects
        if small.image is not None:
            image = torch.full((3, h, w), 128, dtype=small.image.dtype)
            image[:, y0:y0 + nh, x0:x0 + nw] = small.image
        return dataclasses.replace(small, disparity=disparity, valid=valid, objects=objects, image=image,
                                   camera=None, name=f"{scene.name}+{kind}")
    if kind.startswith("relief:"):  # the world F × as deep about its mean plane: planes stay planes
        f = float(kind.split(":", 1)[1])
        h, w = scene.disparity.shape
        yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                                indexing="ij")
        v = scene.valid
        a_ = torch.stack([xx[v], yy[v], torch.ones_like(xx[v])], 1)
        coef = torch.linalg.lstsq(a_, scene.disparity[v].double()[:, None]).solution[:, 0]
        mean_plane = coef[0] * xx + coef[1] * yy + coef[2]  # (x, y, d) ↦ (x, y, (1 − F)·plane + F·d): affine
        flat = (1.0 - f) * mean_plane + f * scene.disparity.double()
        keep = scene.valid & (flat > 0)
        flat = torch.where(keep, flat.to(scene.disparity.dtype), scene.disparity)
        return dataclasses.replace(scene, disparity=flat, valid=keep, name=f"{scene.name}+{kind}")
    if kind.startswith("smear:"):  # a filtered or learned dense map: depth edges bleed into ramps
        import torch.nn.functional as F

        s = float(kind.split(":", 1)[1])
        r = max(1, int(3 * s))
        k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float64) / s) ** 2)
        k = (k / k.sum()).float()

        def blur(a: torch.Tensor) -> torch.Tensor:  # a separable Gaussian, zero outside the image
            a = F.pad(a[None, None].float(), (r, r, r, r))
            return F.conv2d(F.conv2d(a, k.view(1, 1, -1, 1)), k.view(1, 1, 1, -1))[0, 0]

        wsum = blur(scene.valid)  # normalised: invalid pixels neither pull a value nor receive one
        mixed = blur(torch.where(scene.valid, scene.disparity, 0.0)) / wsum.clamp_min(1e-6)
        mixed = torch.where(scene.valid, mixed.to(scene.disparity.dtype), scene.disparity)
        return dataclasses.replace(scene, disparity=mixed, name=f"{scene.name}+{kind}")
    if kind.startswith("quantize:"):  # a sensor that reports whole steps (integer or 8-bit disparity)
        q = float(kind.split(":", 1)[1])
        rounded = torch.round(scene.disparity / q) * q
        keep = scene.valid & (rounded > 0)  # a disparity rounded to 0 is no measurement
        return dataclasses.replace(scene, disparity=torch.where(keep, rounded, scene.disparity), valid=keep,
                                   name=f"{scene.name}+{kind}")
    if kind.startswith("shift:"):  # the same view on a pixel grid N px further right and down: the first
        # N rows and columns cut, so that every strided step (the OR sample, the object step's grid)
        # reads other pixels of the scene (camera shifted, objects cut alike)
        from somtorch.tiles import crop_scene

        n = int(kind.split(":", 1)[1])
        h, w = scene.disparity.shape
        if n >= min(h, w) // 2:
            raise ValueError(f"junk kind {kind!r}: shifts the {w}x{h} scene {scene.name!r} by half its "
                             "shorter side or more")
        return dataclasses.replace(crop_scene(scene, n, h, n, w), name=f"{scene.name}+{kind}")
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