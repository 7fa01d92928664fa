"""One synthetic stereo frame: draw a layout, render both views, label the objects, run SGBM.

:func:`generate_frame` is deterministic per ``(family, seed, camera, scale)``: its generator is
seeded from a SHA-256 of those values (never from global state). A draw is rejected and the next
sub-seed drawn (deterministically) when no object keeps enough pixels or the GT disparity exceeds
the camera's ``max_ndisp``.

The main object: the labelled object with the most visible pixels in the left view (ties: the
nearer one, by median depth). Ids are renumbered by visible pixel count, largest first, so the
main object is always id 1.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from somtorch.disparity.camera import Camera
from somtorch.disparity.stereo import SGBMParams, compute_disparity
from somtorch.synth.builder import Builder, Layout
from somtorch.synth.cameras import SynthCamera, get_camera
from somtorch.synth.families import FAMILIES
from somtorch.synth.render import cast, shade
from somtorch.validation import check_choice

__all__ = ["Frame", "RenderedPair", "draw_layout", "generate_frame", "min_pixels", "render_layout"]

_MAX_SUBSEEDS = 50
_NOISE_SIGMA = 1.5  # grey levels of the mild Gaussian image noise


@dataclass(eq=False)
class Frame:
    """A rendered stereo frame and its labels.

    Attributes:
        left, right: RGB uint8 images, ``(3, H, W)``.
        disparity: GT disparity of the left view, float32, ``inf`` where the ray hits nothing.
        disparity_right: GT disparity of the right view (for tests and occlusion checks).
        sgbm: SGBM disparity of the pair (float32, ``inf`` where invalid), or None if not computed.
        objects: int64 instance map of the left view, 0 = background / support.
        object_info: ``[{"id", "name", "main", "pixels"}]``, id 1 = main.
        camera: the left camera (baseline in mm).
        ndisp: SGBM disparity range (GT max rounded up to a multiple of 16).
        meta: family, camera, seed, sub_seed, pitch_deg, height_m, scene_scale, ... (for objects.json).

    Shape:
        - disparity, disparity_right, sgbm, objects: :math:`(H, W)`.
    """

    left: torch.Tensor
    right: torch.Tensor
    disparity: torch.Tensor
    disparity_right: torch.Tensor
    sgbm: torch.Tensor | None
    objects: torch.Tensor
    object_info: list[dict[str, Any]]
    camera: Camera
    ndisp: int
    meta: dict[str, Any] = field(default_factory=dict)


def _rng(family: str, camera: str, seed: int, sub: int) -> np.random.Generator:
    digest = hashlib.sha256(f"somtorch.synth/{family}/{camera}/{seed}/{sub}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:16], "little"))


def min_pixels(width: int, height: int) -> int:
    """Smallest visible pixel count of a labelled object: 0.025 % of the image, at least 16."""
    return max(16, math.ceil(2.5e-4 * width * height))


def draw_layout(family: str, seed: int, camera: SynthCamera, sub: int = 0) -> tuple[Layout, np.random.Generator]:
    """The scene of one draw, scaled into the camera's depth window, and the draw's generator."""
    fam = FAMILIES[family]
    rng = _rng(family, camera.name, seed, sub)
    b = Builder(rng, camera, fam.texture_depth_m)
    pose = fam.build(b, seed)
    layout = b.layout(pose)
    s = max(camera.near_m / fam.near_m, min(1.0, camera.far_m / fam.far_m))
    return layout.scaled(s), rng


@dataclass(eq=False)
class RenderedPair:
    """Both views of a layout before quantisation.

    Attributes:
        rgb_left, rgb_right: float32 colour in [0, 1], ``(H, W, 3)``.
        disp_left, disp_right: GT disparity ``f·B/Z`` of each view, ``inf`` where nothing is hit.
        depth_left: depth Z of the left view, metres (``inf`` = nothing hit).
        prim_left, prim_right: index of the primitive seen at each pixel (-1 = nothing).
    """

    rgb_left: torch.Tensor
    rgb_right: torch.Tensor
    disp_left: torch.Tensor
    disp_right: torch.Tensor
    depth_left: torch.Tensor
    prim_left: torch.Tensor
    prim_right: torch.Tensor


def render_layout(layout: Layout, camera: Camera, width: int, height: int) -> RenderedPair:
    """Ray-cast and shade both views of ``layout`` (the right camera ``camera.baseline_m`` to the right)."""
    f, cx, cy = camera.focal_px, camera.cx, camera.cy
    light = torch.tensor(layout.light, dtype=torch.float32)
    fb = f * camera.baseline_m
    out = []
    for offset in (0.0, camera.baseline_m):
        hits = cast(layout.prims, layout.pose, f, cx, cy, width, height, offset)
        disp = torch.where(torch.isfinite(hits.depth), fb / hits.depth, torch.full_like(hits.depth, math.inf))
        out.append((shade(layout.prims, hits, f, light), disp, hits))
    (rgb_l, disp_l, hl), (rgb_r, disp_r, hr) = out
    return RenderedPair(rgb_l, rgb_r, disp_l, disp_r, hl.depth, hl.prim, hr.prim)


def _labels(layout: Layout, prim_map: torch.Tensor, depth: torch.Tensor, min_px: int
            ) -> tuple[torch.Tensor, list[dict[str, Any]]]:
    """Instance map renumbered by pixel count (id 1 = main) and its object list; small objects dropped."""
    obj_of_prim = torch.tensor([p.object for p in layout.prims] + [0], dtype=torch.int64)
    raw = obj_of_prim[prim_map]  # prim -1 (miss) -> last entry, 0
    counts = torch.bincount(raw.reshape(-1), minlength=len(layout.names) + 1)
    keep = [i for i in range(1, len(layout.names) + 1) if int(counts[i]) >= min_px]
    med = {i: float(depth[raw == i].median()) for i in keep}
    keep.sort(key=lambda i: (-int(counts[i]), med[i], i))
    lut = torch.zeros(len(layout.names) + 1, dtype=torch.int64)
    info = []
    for new, old in enumerate(keep, start=1):
        lut[old] = new
        info.append({"id": new, "name": layout.names[old - 1], "main": new == 1, "pixels": int(counts[old]),
                     "median_depth_m": round(med[old], 4)})
    return lut[raw], info


def _to_uint8(rgb: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    gen = torch.Generator().manual_seed(int(rng.integers(2**62)))
    noise = torch.randn(tuple(rgb.shape), generator=gen, dtype=torch.float32)
    img = (rgb * 255.0 + noise * _NOISE_SIGMA).round_().clamp_(0, 255).to(torch.uint8)
    return img.permute(2, 0, 1).contiguous()  # (H, W, 3) -> (3, H, W)


def generate_frame(family: str, seed: int, camera: str = "oakd", *, scale: float = 1.0,
                   sgbm: bool = True) -> Frame:
    """Render one frame of ``family`` for ``camera``, deterministically from ``seed``.

    Args:
        family: one of :data:`~somtorch.synth.families.FAMILIES`.
        seed: the frame's seed (``>= 0``).
        camera: one of :data:`~somtorch.synth.cameras.CAMERAS`.
        scale: image size factor (1 = the camera's full size; smaller for tests and previews).
        sgbm: also run SGBM (:func:`~somtorch.disparity.stereo.compute_disparity`, default
            parameters, ``numDisparities`` = ``ndisp``).

    Raises:
        ValueError: unknown family or camera, negative seed, bad scale.
        RuntimeError: no acceptable draw in 50 sub-seeds.
    """
    check_choice("family", family, FAMILIES)
    cam = get_camera(camera)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an int >= 0; got {seed!r}")
    if not (isinstance(scale, int | float) and 0 < scale <= 1):
        raise ValueError(f"scale must be in (0, 1]; got {scale!r}")
    width, height = cam.size(scale)
    camera_obj = cam.camera(scale)
    max_ndisp = max(16, int(cam.max_ndisp * width / cam.width) // 16 * 16)
    min_px = min_pixels(width, height)
    for sub in range(_MAX_SUBSEEDS):
        layout, rng = draw_layout(family, seed, cam, sub)
        pair = render_layout(layout, camera_obj, width, height)
        finite = pair.disp_left[torch.isfinite(pair.disp_left)]
        max_d = float(finite.max()) if finite.numel() else 0.0
        ndisp = 16 * math.ceil((math.floor(max_d) + 1) / 16)
        if ndisp > max_ndisp:
            continue
        objects, info = _labels(layout, pair.prim_left, pair.depth_left, min_px)
        if not info:
            continue
        break
    else:
        raise RuntimeError(f"{family}/{camera}/seed {seed}: no acceptable draw in {_MAX_SUBSEEDS} sub-seeds")
    left, right = _to_uint8(pair.rgb_left, rng), _to_uint8(pair.rgb_right, rng)
    sgbm_map = None
    if sgbm:
        d, valid = compute_disparity(left, right, SGBMParams(numDisparities=ndisp))
        sgbm_map = torch.where(valid, d, torch.full_like(d, math.inf))
    pose = layout.pose
    meta = {"family": family, "camera": camera, "seed": seed, "sub_seed": sub,
            "pitch_deg": round(pose.pitch_deg, 3), "yaw_deg": round(pose.yaw_deg, 3),
            "height_m": round(pose.height_m, 4), "scene_scale": round(layout.scale, 4),
            "width": width, "height": height, "ndisp": ndisp, "min_pixels": min_px,
            "sky_fraction": round(float((~torch.isfinite(pair.depth_left)).float().mean()), 4)}
    return Frame(left=left, right=right, disparity=pair.disp_left, disparity_right=pair.disp_right, sgbm=sgbm_map,
                 objects=objects, object_info=info, camera=camera_obj, ndisp=ndisp, meta=meta)
