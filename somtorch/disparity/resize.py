"""Resampling a :class:`~somtorch.disparity.scene.Scene` to another size (runtime studies at the
paper's 1264 × 720, or any resolution)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from somtorch.disparity.scene import Scene, _object_ids
from somtorch.validation import check_positive_int


def resize_scene(scene: Scene, width: int, height: int) -> Scene:
    """The scene resampled to ``width × height`` px (e.g. to the paper's 1264 × 720 for runtime studies).

    Disparity, validity and object ids are resampled nearest-neighbour (no invented disparities at
    depth edges) and disparities are multiplied by ``width / scene.width`` (disparity is measured
    in pixels of the image row); the image is resampled with area/bilinear interpolation. The camera
    is scaled along; if the aspect ratio changes by more than 1 % a single focal length no longer
    fits, and the camera is dropped (no point clouds for such a scene).
    """
    check_positive_int("width", width)
    check_positive_int("height", height)
    h, w = scene.height, scene.width
    if (width, height) == (w, h):
        return scene
    ys = ((torch.arange(height, dtype=torch.float64) + 0.5) * h / height).long().clamp_max(h - 1)
    xs = ((torch.arange(width, dtype=torch.float64) + 0.5) * w / width).long().clamp_max(w - 1)
    sx, sy = width / w, height / h
    disp = scene.disparity[ys][:, xs] * sx
    valid = scene.valid[ys][:, xs]
    objects = scene.objects[ys][:, xs] if scene.objects is not None else None
    image = None
    if scene.image is not None:
        import cv2

        interp = cv2.INTER_AREA if width * height < w * h else cv2.INTER_LINEAR
        img = cv2.resize(scene.image.permute(1, 2, 0).contiguous().numpy(), (width, height), interpolation=interp)
        image = torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).contiguous()
    camera = None
    if scene.camera is not None and abs(sx / sy - 1.0) <= 0.01:
        c = scene.camera
        camera = replace(c, focal_px=c.focal_px * sx, cx=(c.cx + 0.5) * sx - 0.5, cy=(c.cy + 0.5) * sy - 0.5,
                         doffs=c.doffs * sx)
    if objects is not None:  # an object may vanish when shrinking: keep only the ids still present
        present = _object_ids(objects)
        info = [o for o in scene.object_info if o.id in present]
    else:
        info = list(scene.object_info)
    return Scene(name=scene.name, disparity=torch.where(valid, disp, torch.zeros((), dtype=torch.float32)),
                 valid=valid, image=image, objects=objects, object_info=info, camera=camera,
                 source={**scene.source, "resized": f"{w}x{h} -> {width}x{height}"})
