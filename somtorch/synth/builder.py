"""Building blocks of the scene families: a :class:`Builder` collecting primitives and named objects.

All lengths are metres in the world frame of :mod:`somtorch.synth.cameras` (Z up, ground at 0).
Objects get 1-based indices in the order they are created; support surfaces (ground, walls,
tables, kerbs) are object 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from somtorch.synth.cameras import Pose, SynthCamera
from somtorch.synth.geometry import Material, Primitive

__all__ = ["Builder", "Layout"]

_HUGE = 1e4  # half extent of an "infinite" ground plane, metres

# base colours (RGB 0..1) by surface role; a draw perturbs them
PALETTE = {
    "ground": [(0.55, 0.52, 0.48), (0.45, 0.45, 0.47), (0.6, 0.55, 0.45)],
    "lawn": [(0.32, 0.52, 0.22), (0.38, 0.58, 0.25)],
    "road": [(0.33, 0.33, 0.35), (0.4, 0.4, 0.42)],
    "wall": [(0.85, 0.82, 0.75), (0.75, 0.8, 0.85), (0.8, 0.72, 0.65)],
    "wood": [(0.6, 0.42, 0.25), (0.7, 0.55, 0.38), (0.5, 0.35, 0.22)],
    "bark": [(0.4, 0.28, 0.18), (0.35, 0.25, 0.2)],
    "leaves": [(0.2, 0.45, 0.15), (0.28, 0.5, 0.18), (0.35, 0.45, 0.12)],
    "skin": [(0.85, 0.65, 0.52), (0.7, 0.5, 0.38), (0.45, 0.32, 0.25)],
    "object": [(0.8, 0.2, 0.2), (0.2, 0.4, 0.8), (0.9, 0.75, 0.2), (0.3, 0.7, 0.4), (0.7, 0.7, 0.72),
               (0.6, 0.3, 0.7), (0.95, 0.5, 0.15), (0.25, 0.25, 0.28), (0.9, 0.9, 0.88)],
}


@dataclass
class Layout:
    """A composed scene: primitives, object names (index i -> object i + 1), camera pose, light.

    Attributes:
        prims: the primitives.
        names: object names; ``names[i]`` is object ``i + 1``.
        pose: left camera pose.
        light: unit vector towards the light, world frame.
        scale: the factor the family's natural sizes were multiplied by for this camera.
    """

    prims: list[Primitive]
    names: list[str]
    pose: Pose
    light: tuple[float, float, float]
    scale: float = 1.0

    def scaled(self, s: float) -> Layout:
        """The same scene with every length multiplied by ``s`` (about the world origin)."""
        prims = [replace(p, centre=tuple(s * c for c in p.centre),
                         axes=tuple(tuple(s * a for a in row) for row in p.axes),
                         material=replace(p.material, scale_m=p.material.scale_m * s)) for p in self.prims]
        pose = replace(self.pose, x=self.pose.x * s, y=self.pose.y * s, height_m=self.pose.height_m * s)
        return Layout(prims, list(self.names), pose, self.light, self.scale * s)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _frame_around(axis: np.ndarray) -> np.ndarray:
    """Two unit vectors perpendicular to ``axis`` and to each other, ``(3, 2)``."""
    a = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(a, u)], axis=1)


@dataclass
class Builder:
    """Collects primitives for one scene draw; every random choice comes from ``rng``.

    Attributes:
        rng: the draw's generator.
        camera: the target camera (its focal length sets the texture scale).
        texture_depth_m: a typical depth of the scene at its natural size: textures are sized so
            their longest wavelength spans ~40 px there.
    """

    rng: np.random.Generator
    camera: SynthCamera
    texture_depth_m: float
    prims: list[Primitive] = field(default_factory=list)
    names: list[str] = field(default_factory=list)

    # ---------------------------------------------------------------------------- materials, objects
    def material(self, role: str = "object", texture: str | None = None, *, stripes: float = 0.1,
                 plain: float = 0.08, low: float = 0.08) -> Material:
        """A material of ``role``'s palette; texture drawn (noise / stripes / none / low) unless given."""
        r = self.rng
        base = np.array(PALETTE[role][r.integers(len(PALETTE[role]))])
        rgb = tuple(float(v) for v in np.clip(base * r.uniform(0.85, 1.15, 3), 0.05, 1.0))
        if texture is None:
            u = r.uniform()
            texture = ("stripes" if u < stripes else "none" if u < stripes + plain
                       else "low" if u < stripes + plain + low else "noise")
        scale = self.texture_depth_m / self.camera.focal_px * r.uniform(30, 60)
        return Material(rgb=rgb, texture=texture, scale_m=float(scale), seed=int(r.integers(2**31)))

    def new_object(self, name: str) -> int:
        """Register an object; returns its 1-based index."""
        self.names.append(name)
        return len(self.names)

    def _add(self, kind: str, centre: np.ndarray, axes: np.ndarray, obj: int, mat: Material) -> None:
        self.prims.append(Primitive(kind, tuple(float(c) for c in centre),
                                    tuple(tuple(float(a) for a in row) for row in axes), obj, mat))

    # ---------------------------------------------------------------------------------- primitives
    def box(self, centre, size, obj: int, mat: Material, yaw: float = 0.0) -> None:
        """Box of full ``size`` (x, y, z) at ``centre``, turned by ``yaw`` (radians) about Z."""
        self._add("box", np.asarray(centre, float), _rot_z(yaw) @ np.diag(np.asarray(size, float) / 2), obj, mat)

    def box_on(self, x: float, y: float, z0: float, size, obj: int, mat: Material, yaw: float = 0.0) -> None:
        """Box standing on height ``z0``."""
        self.box((x, y, z0 + size[2] / 2), size, obj, mat, yaw)

    def oriented_box(self, centre, axes, obj: int, mat: Material) -> None:
        """Box ``centre ± a0 ± a1 ± a2``, ``a_i`` the columns of ``axes`` (half extents, any orientation)."""
        self._add("box", np.asarray(centre, float), np.asarray(axes, float), obj, mat)

    def rod(self, p0, p1, radius: float, obj: int, mat: Material) -> None:
        """Cylinder of ``radius`` from ``p0`` to ``p1`` (any orientation)."""
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        half = (p1 - p0) / 2
        perp = _frame_around(half) * radius
        self._add("cylinder", (p0 + p1) / 2, np.stack([perp[:, 0], perp[:, 1], half], axis=1), obj, mat)

    def cylinder(self, x: float, y: float, z0: float, radius: float, height: float, obj: int,
                 mat: Material) -> None:
        """Upright cylinder standing on height ``z0``."""
        self._add("cylinder", np.array([x, y, z0 + height / 2]), np.diag([radius, radius, height / 2]), obj, mat)

    def sphere(self, centre, radii, obj: int, mat: Material) -> None:
        """Ellipsoid with semi-axes ``radii`` (a number for a sphere)."""
        r = np.broadcast_to(np.asarray(radii, float), (3,))
        self._add("sphere", np.asarray(centre, float), np.diag(r), obj, mat)

    def cone(self, x: float, y: float, z0: float, radius: float, height: float, obj: int, mat: Material) -> None:
        """Upright cone, base of ``radius`` at ``z0``."""
        self._add("cone", np.array([x, y, z0 + height / 2]), np.diag([radius, radius, height / 2]), obj, mat)

    def rect(self, centre, ex, ey, obj: int, mat: Material) -> None:
        """Planar rectangle ``centre ± ex ± ey`` (half-extent vectors)."""
        ex, ey = np.asarray(ex, float), np.asarray(ey, float)
        n = np.cross(ex, ey)
        self._add("plane", np.asarray(centre, float), np.stack([ex, ey, n / np.linalg.norm(n)], axis=1), obj, mat)

    def wall(self, x: float, y: float, yaw: float, width: float, height: float, mat: Material) -> None:
        """Vertical support rectangle on the ground, centred at ``(x, y)``, facing ``-Y`` turned by ``yaw``."""
        ex = _rot_z(yaw) @ np.array([width / 2, 0.0, 0.0])
        self.rect((x, y, height / 2), ex, (0.0, 0.0, height / 2), 0, mat)

    def ground(self, mat: Material, z: float = 0.0) -> None:
        """The infinite horizontal support plane at height ``z``."""
        self.rect((0.0, 0.0, z), (_HUGE, 0.0, 0.0), (0.0, _HUGE, 0.0), 0, mat)

    # ------------------------------------------------------------------------------------- layout
    def narrowness(self) -> float:
        """How much narrower the camera's view is than the OAK-D's (min(W, H) / f relative to 480/451)."""
        return (min(self.camera.width, self.camera.height) / self.camera.focal_px) / (480 / 451)

    def visible_half_width(self, depth: float) -> float:
        """Half the ground width the camera sees at ``depth`` (horizontal view), metres."""
        return depth * self.camera.width / (2 * self.camera.focal_px)

    def scatter(self, n: int, radii: list[float], x_range: tuple[float, float], y_range: tuple[float, float],
                taken: list[tuple[float, float, float]] | None = None, *, tries: int = 60
                ) -> list[tuple[float, float]]:
        """Up to ``n`` ground positions in the box whose discs (``radii[i]``) do not overlap each other
        or ``taken`` (``(x, y, r)``, extended in place); positions that find no room are left out."""
        taken = [] if taken is None else taken
        out = []
        for i in range(n):
            for _ in range(tries):
                x, y = self.rng.uniform(*x_range), self.rng.uniform(*y_range)
                if all((x - a) ** 2 + (y - b) ** 2 > (radii[i] + r) ** 2 for a, b, r in taken):
                    taken.append((x, y, radii[i]))
                    out.append((x, y))
                    break
        return out

    def light(self) -> tuple[float, float, float]:
        """A light from above, 25°-70° elevation, any azimuth."""
        el, az = math.radians(self.rng.uniform(25, 70)), self.rng.uniform(0, 2 * math.pi)
        return (math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el))

    def layout(self, pose: Pose) -> Layout:
        """The scene built so far (primitives, object names, light) seen from ``pose``."""
        return Layout(list(self.prims), list(self.names), pose, self.light())
