"""Primitives of a synthetic scene and their exact ray intersections, in torch.

Every primitive is a unit shape mapped into the world by an affine map ``p = centre + axes @ q``:

* ``box``: the cube ``|q_i| <= 1``;
* ``cylinder``: ``q_x² + q_y² <= 1``, ``|q_z| <= 1`` (caps included);
* ``sphere``: ``|q| <= 1`` (an ellipsoid in the world when the axes differ in length);
* ``cone``: apex at ``q_z = 1``, base disc of radius 1 at ``q_z = -1`` (base included);
* ``plane``: the square ``|q_x|, |q_y| <= 1`` at ``q_z = 0`` (two-sided; huge axes = a ground plane).

A ray ``o + t·d`` maps to the ray ``A⁻¹(o - c) + t·A⁻¹d`` with the *same* ``t``, so the unit
shape's analytic intersection gives the world hit parameter directly, and the world normal is
``A⁻ᵀ n_unit``. The camera casts rays whose direction has camera-frame depth component 1, so ``t``
is the depth ``Z`` of the hit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["KINDS", "Material", "Primitive", "intersect", "unit_normal"]

KINDS = ("box", "cylinder", "sphere", "cone", "plane")
"""Names of the unit shapes."""

_EPS = 1e-6  # smallest hit parameter accepted (depth, scene units)
_BIG = 1e30


@dataclass(frozen=True)
class Material:
    """How a surface looks: base colour and procedural texture.

    Attributes:
        rgb: base albedo, each in [0, 1].
        texture: ``"noise"`` (multi-scale random sinusoids), ``"none"`` (textureless),
            ``"stripes"`` (one square-ish wave: repetitive), ``"low"`` (noise at 1/8 contrast).
        scale_m: longest wavelength of the texture, metres (the shortest is 1/16 of it).
        seed: the texture's own random seed (directions, phases).
    """

    rgb: tuple[float, float, float]
    texture: str = "noise"
    scale_m: float = 0.3
    seed: int = 0


@dataclass(frozen=True)
class Primitive:
    """One unit shape in the world (see the module docstring).

    Attributes:
        kind: one of :data:`KINDS`.
        centre: world position of the unit shape's origin, metres.
        axes: 3x3 matrix whose columns are the images of the unit axes (half extents, rotated).
        object: object index (1-based) in the scene's object list, 0 = support surface.
        material: the surface's look.
    """

    kind: str
    centre: tuple[float, float, float]
    axes: tuple[tuple[float, float, float], ...]
    object: int
    material: Material

    def corners(self) -> np.ndarray:
        """The 8 world corners of the unit cube's image (a bounding box of every kind), ``(8, 3)``."""
        q = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
        return np.asarray(self.centre) + q @ np.asarray(self.axes).T


def _safe(d: torch.Tensor) -> torch.Tensor:
    """Direction components with exact zeros nudged (slab divisions stay finite and signed)."""
    return torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)


def _box(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    inv = 1.0 / _safe(d)
    t1, t2 = (-1.0 - o) * inv, (1.0 - o) * inv
    tmin = torch.minimum(t1, t2).amax(-1)
    tmax = torch.maximum(t1, t2).amin(-1)
    hit = (tmax >= tmin) & (tmin > _EPS)
    return torch.where(hit, tmin, torch.full_like(tmin, _BIG))


def _quadric_near(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Both roots of ``a t² + 2 b t + c = 0`` (``_BIG`` where none), smaller first."""
    disc = b * b - a * c
    ok = (disc >= 0) & (a.abs() > 1e-18)
    s = torch.sqrt(disc.clamp_min(0))
    a_ = torch.where(ok, a, torch.ones_like(a))
    r1, r2 = (-b - s) / a_, (-b + s) / a_
    lo, hi = torch.minimum(r1, r2), torch.maximum(r1, r2)
    big = torch.full_like(a, _BIG)
    return torch.where(ok, lo, big), torch.where(ok, hi, big)


def _first(*ts: torch.Tensor) -> torch.Tensor:
    """The smallest candidate above ``_EPS`` (``_BIG`` if none)."""
    out = torch.full_like(ts[0], _BIG)
    for t in ts:
        out = torch.where((t > _EPS) & (t < out), t, out)
    return out


def _sphere(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    a = (d * d).sum(-1)
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - 1.0
    return _first(*_quadric_near(a, b, c))


def _cap(o: torch.Tensor, d: torch.Tensor, z: float) -> torch.Tensor:
    """Hit of the disc ``q_x² + q_y² <= 1`` at ``q_z = z``."""
    t = (z - o[..., 2]) / _safe(d[..., 2])
    x, y = o[..., 0] + t * d[..., 0], o[..., 1] + t * d[..., 1]
    return torch.where(x * x + y * y <= 1.0, t, torch.full_like(t, _BIG))


def _within_z(o: torch.Tensor, d: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    z = o[..., 2] + t * d[..., 2]
    return torch.where(z.abs() <= 1.0, t, torch.full_like(t, _BIG))


def _cylinder(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    ox, oy, dx, dy = o[..., 0], o[..., 1], d[..., 0], d[..., 1]
    r1, r2 = _quadric_near(dx * dx + dy * dy, ox * dx + oy * dy, ox * ox + oy * oy - 1.0)
    return _first(_within_z(o, d, r1), _within_z(o, d, r2), _cap(o, d, -1.0), _cap(o, d, 1.0))


def _cone(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    # x² + y² = k² (1 - z)², k = 1/2 (radius 1 at z = -1, 0 at the apex z = 1)
    ox, oy, dx, dy, dz = o[..., 0], o[..., 1], d[..., 0], d[..., 1], d[..., 2]
    w, k2 = 1.0 - o[..., 2], 0.25
    r1, r2 = _quadric_near(dx * dx + dy * dy - k2 * dz * dz, ox * dx + oy * dy + k2 * w * dz,
                           ox * ox + oy * oy - k2 * w * w)
    return _first(_within_z(o, d, r1), _within_z(o, d, r2), _cap(o, d, -1.0))


def _plane(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    t = -o[..., 2] / _safe(d[..., 2])
    x, y = o[..., 0] + t * d[..., 0], o[..., 1] + t * d[..., 1]
    inside = (x.abs() <= 1.0) & (y.abs() <= 1.0) & (t > _EPS)
    return torch.where(inside, t, torch.full_like(t, _BIG))


_INTERSECT = {"box": _box, "cylinder": _cylinder, "sphere": _sphere, "cone": _cone, "plane": _plane}


def to_local(prim: Primitive, origin: torch.Tensor, direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays in the primitive's unit frame (same ``t``).

    Shape:
        - origin: :math:`(3,)` or :math:`(..., 3)`; direction: :math:`(..., 3)`; outputs broadcast.
    """
    inv = torch.linalg.inv(torch.tensor(prim.axes, dtype=direction.dtype))  # (3, 3)
    c = torch.tensor(prim.centre, dtype=direction.dtype)
    o = (origin - c) @ inv.T
    d = direction @ inv.T
    return o, d


def intersect(prim: Primitive, origin: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """Ray parameter ``t`` of the first hit of ``origin + t·direction`` with ``prim`` (``1e30`` = miss).

    Shape:
        - origin: :math:`(3,)` (one camera centre); direction: :math:`(..., 3)`.
        - Output: :math:`(...)`.
    """
    o, d = to_local(prim, origin, direction)
    return _INTERSECT[prim.kind](o, d)


def unit_normal(prim: Primitive, q: torch.Tensor) -> torch.Tensor:
    """World-space unit normal (not yet oriented) at unit-frame hit points ``q`` of ``prim``.

    Shape:
        - q: :math:`(N, 3)`; output :math:`(N, 3)`.
    """
    if prim.kind == "box":
        a = q.abs()
        n = torch.zeros_like(q)
        idx = a.argmax(-1, keepdim=True)
        n.scatter_(-1, idx, torch.sign(q.gather(-1, idx)))
    elif prim.kind == "sphere":
        n = q.clone()
    elif prim.kind == "plane":
        n = torch.zeros_like(q)
        n[:, 2] = 1.0
    else:  # cylinder, cone: side or cap
        # side or cap: whichever surface the point lies closer to (robust to float32 round-off)
        r = (q[:, 0] ** 2 + q[:, 1] ** 2).sqrt()
        if prim.kind == "cylinder":
            side = torch.stack([q[:, 0], q[:, 1], torch.zeros_like(q[:, 0])], -1)
            cap = (q[:, 2].abs() - 1.0).abs() < (r - 1.0).abs()
        else:
            side = torch.stack([q[:, 0], q[:, 1], 0.25 * (1.0 - q[:, 2])], -1)  # grad of x²+y²-(1-z)²/4, halved
            cap = (q[:, 2] + 1.0).abs() < (r - 0.5 * (1.0 - q[:, 2])).abs()
        capn = torch.zeros_like(q)
        capn[:, 2] = torch.sign(q[:, 2])
        n = torch.where(cap[:, None], capn, side)
    inv_t = torch.linalg.inv(torch.tensor(prim.axes, dtype=q.dtype)).T  # normals map by A^-T
    n = n @ inv_t.T
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
