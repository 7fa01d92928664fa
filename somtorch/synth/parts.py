"""Composite objects built from primitives: person, car, cyclist, tree, bush, bench, table, chair, ...

Each function adds one labelled object (or a support, ``obj=0``) standing at ``(x, y)`` on height
``z0``, facing ``yaw`` (radians about Z), at natural size in metres, and returns its index.
"""

from __future__ import annotations

import math

from somtorch.synth.builder import Builder

__all__ = ["bench", "bush", "car", "chair", "cyclist", "lattice", "person", "pole", "sign", "small_object", "table",
           "tree"]


def _turn(x: float, y: float, yaw: float, dx: float, dy: float) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return x + c * dx - s * dy, y + s * dx + c * dy


def person(b: Builder, x: float, y: float, yaw: float = 0.0, z0: float = 0.0, height: float | None = None) -> int:
    """Add a standing person (legs, torso, arms, head) at ``(x, y)`` on height ``z0``, turned by ``yaw``;
    ``height`` in metres (random 1.55-1.9 when None); return its object id."""
    r = b.rng
    h = height or r.uniform(1.55, 1.9)
    o = b.new_object("person")
    skin, cloth, legs = b.material("skin"), b.material("object"), b.material("object")
    for side in (-1, 1):
        lx, ly = _turn(x, y, yaw, side * 0.1 * h / 1.75, 0.0)
        b.cylinder(lx, ly, z0, 0.065 * h / 1.75, 0.47 * h, o, legs)
    b.box_on(x, y, z0 + 0.47 * h, (0.36 * h / 1.75, 0.2 * h / 1.75, 0.34 * h), o, cloth, yaw)
    for side in (-1, 1):
        ax, ay = _turn(x, y, yaw, side * 0.23 * h / 1.75, 0.0)
        b.cylinder(ax, ay, z0 + 0.44 * h, 0.04 * h / 1.75, 0.36 * h, o, cloth)
    b.sphere((x, y, z0 + 0.9 * h), (0.07 * h, 0.08 * h, 0.075 * h), o, skin)
    return o


def car(b: Builder, x: float, y: float, yaw: float = 0.0) -> int:
    """Add a car at ``(x, y)`` turned by ``yaw``; return its object id."""
    r = b.rng
    o = b.new_object("car")
    length, width = r.uniform(3.8, 4.8), r.uniform(1.65, 1.9)
    paint, glass, tyre = b.material("object"), b.material("object", "low"), b.material("object", "none")
    b.box_on(x, y, 0.3, (width, length, r.uniform(0.55, 0.75)), o, paint, yaw)
    cx, cy = _turn(x, y, yaw, 0.0, r.uniform(-0.5, 0.0))
    b.box_on(cx, cy, 0.9, (width * 0.9, length * r.uniform(0.45, 0.55), r.uniform(0.45, 0.6)), o, glass, yaw)
    for sx in (-1, 1):
        for sy in (-1, 1):
            wx, wy = _turn(x, y, yaw, sx * width / 2 * 0.98, sy * length * 0.32)
            ax, ay = _turn(0, 0, yaw, 0.11, 0.0)
            b.rod((wx - ax, wy - ay, 0.33), (wx + ax, wy + ay, 0.33), 0.33, o, tyre)
    return o


def cyclist(b: Builder, x: float, y: float, yaw: float = 0.0) -> int:
    """Add a cyclist (bicycle and rider) at ``(x, y)`` turned by ``yaw``; return its object id."""
    o = b.new_object("cyclist")
    frame, tyre, skin, cloth = (b.material("object"), b.material("object", "none"), b.material("skin"),
                                b.material("object"))
    for sy in (-0.55, 0.55):
        wx, wy = _turn(x, y, yaw, 0.0, sy)
        ax, ay = _turn(0, 0, yaw, 0.025, 0.0)
        b.rod((wx - ax, wy - ay, 0.35), (wx + ax, wy + ay, 0.35), 0.35, o, tyre)
    b.box((x, y, 0.6), (0.05, 1.0, 0.08), o, frame, yaw)
    b.box((x, y, 1.15), (0.36, 0.25, 0.6), o, cloth, yaw + 0.1)
    for side in (-1, 1):
        lx, ly = _turn(x, y, yaw, side * 0.1, -0.05)
        b.rod((lx, ly, 0.85), (lx, ly + 0.1, 0.3), 0.055, o, cloth)
    b.sphere((x, y, 1.58), 0.12, o, skin)
    return o


def pole(b: Builder, x: float, y: float, height: float | None = None, name: str = "pole") -> int:
    """Add a pole (random 3-6 m when ``height`` is None) at ``(x, y)``; return its object id."""
    o = b.new_object(name)
    h = height or b.rng.uniform(3.0, 6.0)
    b.cylinder(x, y, 0.0, b.rng.uniform(0.04, 0.09), h, o, b.material("object"))
    return o


def sign(b: Builder, x: float, y: float, yaw: float = 0.0) -> int:
    """Add a road sign (a pole with a plate) at ``(x, y)`` turned by ``yaw``; return its object id."""
    o = pole(b, x, y, b.rng.uniform(2.0, 3.0), name="sign")
    h = b.prims[-1].axes[2][2] * 2
    plate = b.material("object", "low")
    if b.rng.uniform() < 0.5:
        b.box((x, y, h + 0.3), (0.7, 0.04, 0.6), o, plate, yaw)
    else:
        ax, ay = _turn(0, 0, yaw, 0.0, 0.02)
        b.rod((x - ax, y - ay, h + 0.35), (x + ax, y + ay, h + 0.35), 0.35, o, plate)
    return o


def tree(b: Builder, x: float, y: float) -> int:
    """Add a tree (a trunk and a round or conical crown) at ``(x, y)``; return its object id."""
    r = b.rng
    o = b.new_object("tree")
    trunk_h, trunk_r = r.uniform(1.2, 3.5), r.uniform(0.1, 0.3)
    b.cylinder(x, y, 0.0, trunk_r, trunk_h + 0.3, o, b.material("bark"))
    crown = b.material("leaves")
    if r.uniform() < 0.5:
        cr = r.uniform(1.0, 2.4)
        b.sphere((x, y, trunk_h + cr * 0.8), (cr, cr, cr * r.uniform(0.8, 1.2)), o, crown)
    else:
        cr = r.uniform(0.9, 1.8)
        b.cone(x, y, trunk_h * 0.7, cr, r.uniform(2.0, 4.5), o, crown)
    return o


def bush(b: Builder, x: float, y: float) -> int:
    """Add a bush (a random ellipsoid) at ``(x, y)``; return its object id."""
    o = b.new_object("bush")
    rx, ry, rz = b.rng.uniform(0.4, 1.1), b.rng.uniform(0.4, 1.1), b.rng.uniform(0.35, 0.8)
    b.sphere((x, y, rz * 0.6), (rx, ry, rz), o, b.material("leaves"))
    return o


def bench(b: Builder, x: float, y: float, yaw: float = 0.0) -> int:
    """Add a park bench (wooden seat and back, metal legs) at ``(x, y)`` turned by ``yaw``; return its object
    id."""
    o = b.new_object("bench")
    wood, metal = b.material("wood"), b.material("object")
    length = b.rng.uniform(1.2, 2.0)
    b.box_on(x, y, 0.42, (length, 0.45, 0.05), o, wood, yaw)
    bx, by = _turn(x, y, yaw, 0.0, 0.22)
    b.box_on(bx, by, 0.5, (length, 0.05, 0.4), o, wood, yaw)
    for sx in (-1, 1):
        for sy in (-1, 1):
            lx, ly = _turn(x, y, yaw, sx * length * 0.42, sy * 0.18)
            b.box_on(lx, ly, 0.0, (0.06, 0.06, 0.42), o, metal, yaw)
    return o


def table(b: Builder, x: float, y: float, size: tuple[float, float], height: float, yaw: float = 0.0,
          support: bool = False) -> int:
    """A table (top + 4 legs); ``support=True`` makes it a support surface (object 0)."""
    o = 0 if support else b.new_object("table")
    wood = b.material("wood", stripes=0.15)
    b.box_on(x, y, height - 0.04, (size[0], size[1], 0.04), o, wood, yaw)
    for sx in (-1, 1):
        for sy in (-1, 1):
            lx, ly = _turn(x, y, yaw, sx * (size[0] / 2 - 0.06), sy * (size[1] / 2 - 0.06))
            b.box_on(lx, ly, 0.0, (0.05, 0.05, height - 0.04), o, wood, yaw)
    return o


def chair(b: Builder, x: float, y: float, yaw: float = 0.0) -> int:
    """Add a chair at ``(x, y)`` turned by ``yaw``; return its object id."""
    o = b.new_object("chair")
    mat = b.material(b.rng.choice(["wood", "object"]))
    b.box_on(x, y, 0.43, (0.45, 0.45, 0.04), o, mat, yaw)
    bx, by = _turn(x, y, yaw, 0.0, 0.2)
    b.box_on(bx, by, 0.47, (0.45, 0.04, 0.45), o, mat, yaw)
    for sx in (-1, 1):
        for sy in (-1, 1):
            lx, ly = _turn(x, y, yaw, sx * 0.19, sy * 0.19)
            b.box_on(lx, ly, 0.0, (0.04, 0.04, 0.43), o, mat, yaw)
    return o


def small_object(b: Builder, x: float, y: float, z0: float, size: float, yaw: float = 0.0) -> int:
    """A box, can, ball, cone or bottle of about ``size`` (metres) standing on ``z0``."""
    r = b.rng
    kind = r.choice(["box", "can", "ball", "cone", "bottle"])
    o = b.new_object(str(kind))
    mat = b.material("object")
    if kind == "box":
        b.box_on(x, y, z0, tuple(size * r.uniform(0.5, 1.0, 3)), o, mat, yaw)
    elif kind == "can":
        b.cylinder(x, y, z0, size * r.uniform(0.2, 0.4), size * r.uniform(0.6, 1.2), o, mat)
    elif kind == "ball":
        rad = size * r.uniform(0.3, 0.5)
        b.sphere((x, y, z0 + rad), rad, o, mat)
    elif kind == "cone":
        b.cone(x, y, z0, size * r.uniform(0.3, 0.5), size * r.uniform(0.7, 1.2), o, mat)
    else:
        rad, h = size * r.uniform(0.15, 0.25), size * r.uniform(0.6, 0.9)
        b.cylinder(x, y, z0, rad, h, o, mat)
        b.cone(x, y, z0 + h, rad, h * 0.5, o, mat)
    return o


def lattice(b: Builder, x: float, y: float, width: float, height: float, yaw: float, spacing: float,
            bar: float) -> int:
    """A fence: posts every ``spacing``, rails, optional diagonal-free lattice of thin bars."""
    o = b.new_object("fence")
    mat = b.material(b.rng.choice(["wood", "object"]), stripes=0.0)
    n = max(2, int(width / spacing) + 1)
    for i in range(n):
        px, py = _turn(x, y, yaw, -width / 2 + i * width / (n - 1), 0.0)
        b.box_on(px, py, 0.0, (bar, bar, height), o, mat, yaw)
    n_rails = int(b.rng.integers(2, 5))
    for j in range(n_rails):
        z = height * (0.15 + 0.8 * j / max(1, n_rails - 1))
        b.box((x, y, min(z, height - bar)), (width, bar * 0.8, bar * 0.8), o, mat, yaw)
    return o

