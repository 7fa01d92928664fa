"""Ray casting a list of primitives from a pinhole camera: depth, primitive index and shaded colour.

:func:`cast` finds the nearest hit of every pixel's ray (exact analytic intersections of
:mod:`somtorch.synth.geometry`, vectorised over the pixels of each primitive's screen-space
bounding rectangle: a primitive is only tested where its projected bounding box lies).
:func:`shade` colours the hits: a procedural texture evaluated at the 3-D hit point (so both views
of a stereo pair see the same pattern), Lambert shading from one directional light plus ambient.

Textures are sums of sinusoids in world coordinates, ``Σ_k sin(ω_k·p + φ_k)``, each attenuated by
``exp(-(|ω_k| σ)² / 4)`` where ``σ`` is the pixel's footprint on the surface (depth / f, stretched
by the slant): an analytic low-pass, so a far or grazing surface turns smoothly grey instead of
aliasing into noise that no stereo matcher could follow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from somtorch.synth.cameras import Pose
from somtorch.synth.geometry import Material, Primitive, intersect, to_local, unit_normal

__all__ = ["Hits", "cast", "pixel_rays", "shade", "texture_value"]

_MISS = 1e30
_AMBIENT = 0.35
_N_WAVES = 24
DTYPE = torch.float32


@dataclass(frozen=True)
class Hits:
    """The nearest hit of every pixel of one view.

    Attributes:
        depth: camera-frame depth Z of the hit (``inf`` where the ray hits nothing), float32.
        prim: index into the primitive list (``-1`` where nothing is hit), int64.
        origin: the camera centre (world, metres), ``(3,)``.
        dirs: world ray directions with unit camera-frame depth component, ``(H, W, 3)``.

    Shape:
        - depth, prim: :math:`(H, W)`.
    """

    depth: torch.Tensor
    prim: torch.Tensor
    origin: torch.Tensor
    dirs: torch.Tensor


def pixel_rays(pose: Pose, focal_px: float, cx: float, cy: float, width: int, height: int,
               offset_m: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """World origin ``(3,)`` and ray directions ``(H, W, 3)`` of a camera ``offset_m`` to the right of ``pose``.

    A direction is ``R @ ((u - cx)/f, (v - cy)/f, 1)``: its camera-frame depth is 1, so a hit at
    ray parameter ``t`` has depth ``Z = t``.
    """
    rot = torch.tensor(pose.rotation(), dtype=DTYPE)  # (3, 3) camera -> world
    u = (torch.arange(width, dtype=DTYPE) - cx) / focal_px
    v = (torch.arange(height, dtype=DTYPE) - cy) / focal_px
    cam = torch.stack([u[None, :].expand(height, width), v[:, None].expand(height, width),
                       torch.ones(height, width, dtype=DTYPE)], -1)  # (H, W, 3)
    dirs = cam[..., 0:1] * rot[:, 0] + cam[..., 1:2] * rot[:, 1] + cam[..., 2:3] * rot[:, 2]
    origin = torch.tensor(pose.centre() + offset_m * pose.rotation()[:, 0], dtype=DTYPE)
    return origin, dirs


def _screen_rect(prim: Primitive, rot: np.ndarray, origin: np.ndarray, focal_px: float, cx: float, cy: float,
                 width: int, height: int) -> tuple[int, int, int, int] | None:
    """Pixel rectangle ``(y0, y1, x0, x1)`` holding the primitive's projection; None if off screen."""
    pc = (prim.corners() - origin) @ rot  # (8, 3) camera frame
    z = pc[:, 2]
    if (z <= 1e-6).all():
        return None
    if (z <= 1e-6).any():  # straddles the camera plane: no bound from the projection
        return 0, height, 0, width
    u = focal_px * pc[:, 0] / z + cx
    v = focal_px * pc[:, 1] / z + cy
    x0, x1 = max(0, math.floor(u.min()) - 1), min(width, math.ceil(u.max()) + 2)
    y0, y1 = max(0, math.floor(v.min()) - 1), min(height, math.ceil(v.max()) + 2)
    if x0 >= x1 or y0 >= y1:
        return None
    return y0, y1, x0, x1


def cast(prims: list[Primitive], pose: Pose, focal_px: float, cx: float, cy: float, width: int,
         height: int, offset_m: float = 0.0) -> Hits:
    """Nearest hit per pixel of the camera ``offset_m`` right of ``pose`` (0: left view, B: right view).

    Shape:
        - Output fields: see :class:`Hits`.
    """
    origin, dirs = pixel_rays(pose, focal_px, cx, cy, width, height, offset_m)
    depth = torch.full((height, width), _MISS, dtype=DTYPE)
    index = torch.full((height, width), -1, dtype=torch.int64)
    o_np, rot = origin.double().numpy(), pose.rotation()
    for k, prim in enumerate(prims):
        rect = _screen_rect(prim, rot, o_np, focal_px, cx, cy, width, height)
        if rect is None:
            continue
        y0, y1, x0, x1 = rect
        t = intersect(prim, origin, dirs[y0:y1, x0:x1])  # (h, w)
        best = depth[y0:y1, x0:x1]
        closer = t < best
        best.copy_(torch.where(closer, t, best))
        sub = index[y0:y1, x0:x1]
        sub.copy_(torch.where(closer, torch.full_like(sub, k), sub))
    depth = torch.where(index >= 0, depth, torch.full_like(depth, math.inf))
    return Hits(depth=depth, prim=index, origin=origin, dirs=dirs)


def _waves(material: Material) -> tuple[torch.Tensor, torch.Tensor]:
    """Angular frequencies ``(K, 3)`` (rad/m) and phases ``(K,)`` of a material's texture."""
    rng = np.random.default_rng(material.seed)
    if material.texture == "stripes":
        axis = rng.normal(size=3)
        axis[2] *= 0.3  # mostly horizontal bars across vertical surfaces, and stripes on the ground
        k = 2 * math.pi / material.scale_m * axis / np.linalg.norm(axis)
        return torch.tensor(k[None], dtype=DTYPE), torch.tensor([rng.uniform(0, 2 * math.pi)], dtype=DTYPE)
    dirs = rng.normal(size=(_N_WAVES, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wavelength = material.scale_m * np.exp(rng.uniform(math.log(1 / 16), 0.0, _N_WAVES))
    omega = dirs * (2 * math.pi / wavelength)[:, None]
    return torch.tensor(omega, dtype=DTYPE), torch.tensor(rng.uniform(0, 2 * math.pi, _N_WAVES), dtype=DTYPE)


def texture_value(material: Material, points: torch.Tensor, footprint_m: torch.Tensor) -> torch.Tensor:
    """Zero-mean texture (about unit spread) at world ``points``, low-passed for ``footprint_m``.

    Shape:
        - points: :math:`(N, 3)`; footprint_m: :math:`(N,)`; output :math:`(N,)`.
    """
    omega, phase = _waves(material)
    # (N, K): ω_k·p + φ_k, element-wise (addmm's BLAS sums differ in the last bit with the thread count)
    arg = torch.outer(points[:, 0], omega[:, 0]).add_(phase)
    arg.addcmul_(points[:, 1:2], omega[:, 1]).addcmul_(points[:, 2:3], omega[:, 2])
    wave = torch.sin_(arg)
    if material.texture == "stripes":
        wave = torch.tanh_(wave.mul_(2.5))
    damp = torch.outer(footprint_m.square(), omega.square().sum(1) / -4).exp_()  # (N, K)
    return (wave.mul_(damp)).sum(-1) / math.sqrt(omega.shape[0] / 2)


_CONTRAST = {"noise": 0.45, "none": 0.0, "stripes": 0.55, "low": 0.45 / 8}


def shade(prims: list[Primitive], hits: Hits, focal_px: float, light: torch.Tensor) -> torch.Tensor:
    """Colour of every pixel: textured albedo x (ambient + Lambert) on hits, a sky gradient elsewhere.

    Args:
        light: unit vector towards the light, world frame, ``(3,)``.

    Shape:
        - Output: :math:`(H, W, 3)` float32 in [0, 1].
    """
    dirs = hits.dirs
    elev = (dirs[..., 2] / dirs.norm(dim=-1)).clamp(-1, 1)  # (H, W)
    sky_lo, sky_hi = torch.tensor([0.78, 0.84, 0.9], dtype=DTYPE), torch.tensor([0.5, 0.66, 0.88], dtype=DTYPE)
    w = elev.clamp(0, 1)[..., None]
    unit = (dirs / dirs.norm(dim=-1, keepdim=True)).reshape(-1, 3)
    sky = Material(rgb=(1.0, 1.0, 1.0), texture="noise", scale_m=40 / focal_px, seed=7)  # "metres" = radians
    clouds = texture_value(sky, unit, torch.zeros_like(unit[:, 0])).reshape(elev.shape)  # at infinity: d = 0
    out = (sky_lo * (1 - w) + sky_hi * w) * (1 + 0.12 * clouds)[..., None]  # (H, W, 3)
    flat_idx = hits.prim.reshape(-1)
    flat_out = out.reshape(-1, 3)
    flat_dirs = dirs.reshape(-1, 3)
    flat_depth = hits.depth.reshape(-1)
    order = torch.argsort(flat_idx, stable=True)
    counts = torch.bincount(flat_idx + 1, minlength=len(prims) + 1).tolist()
    start = counts[0]
    for k, prim in enumerate(prims):
        n = counts[k + 1]
        if n == 0:
            continue
        pix = order[start:start + n]
        start += n
        d, z = flat_dirs[pix], flat_depth[pix]
        p = hits.origin + z[:, None] * d  # (n, 3) world hit points
        q, _ = to_local(prim, p, d)
        normal = unit_normal(prim, q)
        dn = d / d.norm(dim=-1, keepdim=True)
        cos = (normal * dn).sum(-1)
        normal = torch.where(cos[:, None] > 0, -normal, normal)  # facing the camera
        footprint = z * d.norm(dim=-1) / focal_px / cos.abs().clamp_min(0.2)
        mat = prim.material
        tex = texture_value(mat, p, footprint) if mat.texture != "none" else torch.zeros_like(z)
        albedo = torch.tensor(mat.rgb, dtype=DTYPE) * (1 + _CONTRAST[mat.texture] * tex).clamp(0.15, 1.85)[:, None]
        lambert = (normal * light).sum(-1).clamp_min(0)
        flat_out[pix] = (albedo * (_AMBIENT + (1 - _AMBIENT) * lambert)[:, None]).clamp(0, 1)
    return out
