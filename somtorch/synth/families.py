"""The scene families (:data:`FAMILIES`): each draws a layout at natural size from a generator.

A family function ``fn(b, seed) -> Pose`` adds primitives to the :class:`Builder` ``b`` (every
random choice from ``b.rng``) and returns the left camera's pose. ``seed`` is the frame's seed,
used only to stratify the camera pitch of ``tabletop`` and ``room`` over 0°-90° and of ``floor``
over 55°-90° (golden-ratio sequence), so that any run of consecutive seeds covers the range.
Forward-looking families draw the pitch in 0°-25° down.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from somtorch.synth import parts
from somtorch.synth.builder import Builder
from somtorch.synth.cameras import Pose

__all__ = ["FAMILIES", "Family"]

_GOLDEN = 0.6180339887498949


@dataclass(frozen=True)
class Family:
    """A scene family: its builder and the natural depth range of its scenes (metres).

    Attributes:
        build: ``fn(builder, seed) -> Pose``.
        near_m, far_m: natural depth range; scaled into the camera's window (see ``frame.py``).
        texture_depth_m: typical depth at which textures span ~40 px.
    """

    build: Callable[[Builder, int], Pose]
    near_m: float
    far_m: float
    texture_depth_m: float


def _forward(b: Builder, h: tuple[float, float], pitch: tuple[float, float] = (0.0, 25.0)) -> Pose:
    return Pose(0.0, 0.0, b.rng.uniform(*h), b.rng.uniform(*pitch), b.rng.uniform(-8, 8))


def _looking_at(b: Builder, seed: int, fx: float, fy: float, fz: float, dist: float, min_h: float) -> Pose:
    """Camera pitched by the seed's stratified angle, its axis through ``(fx, fy, fz)`` at ``dist``."""
    pitch = 90.0 * ((seed * _GOLDEN + b.rng.uniform(0, 0.04)) % 1.0)
    p = math.radians(pitch)
    h = max(fz + dist * math.sin(p), fz + min_h)
    return Pose(fx, fy - dist * math.cos(p), h, pitch, 0.0)


def _visible_x(b: Builder, y: float, margin: float = 0.8) -> tuple[float, float]:
    w = b.visible_half_width(y) * margin
    return -w, w


# ------------------------------------------------------------------------------------- outdoor


def stairs(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material("ground", low=0.15))
    pose = _forward(b, (1.0, 1.8))
    n, rise, run, width = int(r.integers(4, 12)), r.uniform(0.14, 0.2), r.uniform(0.25, 0.35), r.uniform(1.0, 2.6)
    y0, x0, yaw = r.uniform(2.5, 6.0), r.uniform(-0.5, 0.5), math.radians(r.uniform(-30, 30))
    o = b.new_object("stairs")
    mat = b.material("ground", stripes=0.05)
    c, s = math.cos(yaw), math.sin(yaw)
    for i in range(n):
        depth = (n - i) * run
        ly = i * run + depth / 2  # staircase frame: steps climb along +y
        b.box_on(x0 - s * ly, y0 + c * ly, 0.0, (width, depth, (i + 1) * rise), o, mat, yaw)
    if r.uniform() < 0.3:
        b.wall(x0 - s * (n * run + 0.01), y0 + c * (n * run + 0.01), yaw, 12.0, n * rise + 2.5, b.material("wall"))
    extra = r.uniform()
    if extra < 0.35:  # something on a step
        i = int(r.integers(0, n))
        ly, lx = i * run + run / 2, r.uniform(-width / 3, width / 3)
        parts.small_object(b, x0 + c * lx - s * ly, y0 + s * lx + c * ly, (i + 1) * rise,
                           r.uniform(0.15, 0.25), yaw)
    elif extra < 0.7:  # beside it
        side = r.choice([-1, 1])
        px, py = x0 + side * (width / 2 + r.uniform(0.5, 1.2)), y0 + r.uniform(-1.0, 1.0)
        if r.uniform() < 0.5:
            parts.person(b, px, py, r.uniform(-1, 1))
        else:
            parts.small_object(b, px, py, 0.0, r.uniform(0.4, 0.9))
    return pose


def garden(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material("lawn", texture="noise"))
    pose = _forward(b, (1.2, 1.9))
    taken: list[tuple[float, float, float]] = []
    n_trees, n_bush = int(r.integers(1, 4)), int(r.integers(0, 4))
    for x, y in b.scatter(n_trees, [2.0] * n_trees, (-6, 6), (5, 18), taken):
        parts.tree(b, x, y)
    for x, y in b.scatter(n_bush, [1.1] * n_bush, (-4, 4), (3.5, 12), taken):
        parts.bush(b, x, y)
    if r.uniform() < 0.6:
        for x, y in b.scatter(1, [1.2], (-2.5, 2.5), (3.5, 8), taken):
            parts.bench(b, x, y, r.uniform(-0.6, 0.6) + math.pi * (r.uniform() < 0.5))
    if r.uniform() < 0.5:
        b.wall(r.uniform(-3, 3), r.uniform(20, 26), r.uniform(-0.3, 0.3), 60.0, r.uniform(1.5, 3.0),
               b.material("leaves", texture="noise"))  # a hedge behind
    return pose


def road(b: Builder, seed: int) -> Pose:
    r = b.rng
    lane = r.uniform(3.0, 3.7)
    half = lane * int(r.integers(1, 3))
    b.ground(b.material("road", low=0.2, stripes=0.0, plain=0.0))
    walk = b.material("ground", stripes=0.1)
    for side in (-1, 1):  # kerbs and pavements
        b.box((side * (half + 2.0), 40.0, 0.075), (4.0, 120.0, 0.15), 0, walk)
    paint = b.material("wall", texture="none")
    for k in range(12):  # dashed centre line, flat
        b.box((0.0, 3.0 + 6.0 * k, 0.005), (0.12, 3.0, 0.01), 0, paint)
    for side in (-1, 1):
        if r.uniform() < 0.7:  # buildings far back at the side
            b.box((side * (half + r.uniform(8, 14)), 40.0, 6.0), (6.0, 80.0, 12.0), 0, b.material("wall"),
                  r.uniform(-0.05, 0.05))
    pose = Pose(r.uniform(-half / 2, half / 2), 0.0, r.uniform(1.4, 1.8), r.uniform(0, 15), r.uniform(-5, 5))
    taken: list[tuple[float, float, float]] = [(pose.x, 0.0, 2.0)]
    for x, y in b.scatter(int(r.integers(1, 5)), [2.6] * 4, (-half + 1, half - 1), (7, 40), taken):
        parts.car(b, x, y, r.choice([0.0, math.pi]) + r.uniform(-0.15, 0.15))
    for x, y in b.scatter(int(r.integers(0, 4)), [0.5] * 3, (half + 0.5, half + 3.5), (5, 25), taken):
        parts.person(b, x * r.choice([-1, 1]), y, r.uniform(-math.pi, math.pi), z0=0.15)
    for x, y in b.scatter(int(r.integers(0, 2)), [1.2], (-half + 0.6, half - 0.6), (6, 25), taken):
        parts.cyclist(b, x, y, r.uniform(-0.2, 0.2))
    for y in sorted(r.uniform(6, 45, int(r.integers(1, 5)))):
        side = r.choice([-1, 1])
        (parts.sign if r.uniform() < 0.4 else parts.pole)(b, side * (half + r.uniform(0.4, 1.5)), y)
    return pose


def fence(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material(r.choice(["lawn", "ground"])))
    pose = _forward(b, (1.0, 1.8))
    yf = r.uniform(3.0, 7.0)
    spacing, bar = r.uniform(0.12, 0.6), r.uniform(0.03, 0.08)
    parts.lattice(b, r.uniform(-1, 1), yf, r.uniform(6, 14), r.uniform(0.9, 2.0), r.uniform(-0.4, 0.4),
                  spacing, bar)
    taken: list[tuple[float, float, float]] = []
    behind = r.uniform() < 0.5
    yr = (yf + 1.0, yf + 6.0) if behind else (1.8, yf - 0.8)
    n = int(r.integers(1, 4))
    for x, y in b.scatter(n, [0.7] * n, _visible_x(b, yr[0], 0.7), yr, taken):
        kind = r.uniform()
        if kind < 0.4:
            parts.person(b, x, y, r.uniform(-math.pi, math.pi))
        elif kind < 0.7:
            parts.small_object(b, x, y, 0.0, r.uniform(0.4, 1.0))
        else:
            parts.bush(b, x, y)
    if r.uniform() < 0.5:
        b.wall(0.0, yf + r.uniform(7, 12), r.uniform(-0.3, 0.3), 40.0, 4.0, b.material("wall"))
    return pose


def clutter(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material("ground"))
    pose = _forward(b, (0.8, 1.8))
    n = int(r.integers(8, 20))
    taken: list[tuple[float, float, float]] = []
    sizes = list(r.uniform(0.3, 1.1, n))
    for (x, y), size in zip(b.scatter(n, [s * 0.6 for s in sizes], (-4.0, 4.0), (1.8, 10.0), taken), sizes):
        if abs(x) > b.visible_half_width(y):
            continue
        if r.uniform() < 0.15:
            parts.person(b, x, y, r.uniform(-math.pi, math.pi))
        else:
            parts.small_object(b, x, y, 0.0, size, r.uniform(-math.pi, math.pi))
    if r.uniform() < 0.5:
        b.wall(0.0, r.uniform(11, 14), r.uniform(-0.4, 0.4), 40.0, 5.0, b.material("wall"))
    return pose


# -------------------------------------------------------------------------------------- indoor


def room(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material(r.choice(["wood", "ground"]), stripes=0.2))
    dist = r.uniform(2.2, 4.5) / b.narrowness()  # the same floor area in view for every camera
    fx, fy = 0.0, 4.0
    pose = _looking_at(b, seed, fx, fy, 0.0, dist, min_h=r.uniform(0.5, 1.6))
    reach = dist * min(b.camera.width, b.camera.height) / (2 * b.camera.focal_px)
    back_y = fy + r.uniform(1.5, 3.5)
    b.wall(fx + r.uniform(-1, 1), back_y, math.radians(r.uniform(-35, 35)), 14.0, 2.7, b.material("wall"))
    side = r.choice([-1, 1])
    b.wall(fx + side * r.uniform(2.0, 3.5), fy, math.pi / 2 + math.radians(r.uniform(-25, 25)), 14.0, 2.7,
           b.material("wall"))
    if pose.height_m < 2.4:  # a ceiling, unless the camera looks down from above the walls (a drone)
        b.ground(b.material("wall", texture="low"), z=2.7)
    makers = [lambda x, y, a: parts.table(b, x, y, (r.uniform(0.8, 1.6), r.uniform(0.6, 1.0)),
                                          r.uniform(0.7, 0.78), a),
              lambda x, y, a: parts.chair(b, x, y, a),
              lambda x, y, a: parts.person(b, x, y, a),
              lambda x, y, a: _bed(b, x, y, a),
              lambda x, y, a: _cabinet(b, x, y, a)]
    n = int(r.integers(2, 5))
    taken: list[tuple[float, float, float]] = []
    y_range = (fy - reach, min(fy + reach, back_y - 0.8))
    for x, y in b.scatter(n, [0.8] * n, (fx - reach, fx + reach), y_range, taken):
        makers[int(r.integers(len(makers)))](x, y, r.uniform(-math.pi, math.pi))
    return pose


def _bed(b: Builder, x: float, y: float, yaw: float) -> int:
    o = b.new_object("bed")
    b.box_on(x, y, 0.0, (1.4, 2.0, 0.3), o, b.material("wood"), yaw)
    b.box_on(x, y, 0.3, (1.35, 1.95, 0.2), o, b.material("object"), yaw)
    return o


def _cabinet(b: Builder, x: float, y: float, yaw: float) -> int:
    o = b.new_object("cabinet")
    b.box_on(x, y, 0.0, (b.rng.uniform(0.5, 1.2), b.rng.uniform(0.4, 0.6), b.rng.uniform(0.6, 1.9)), o,
             b.material("wood"), yaw)
    return o


def tabletop(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material("ground"))
    top = r.uniform(0.7, 0.8)
    dist = r.uniform(0.5, 1.3)
    fx, fy = 0.0, 2.0
    pose = _looking_at(b, seed, fx, fy, top, dist, min_h=r.uniform(0.12, 0.3))
    reach = dist * min(b.camera.width, b.camera.height) / (2 * b.camera.focal_px)
    front = min(pose.y + 0.05, fy - reach)
    size = (max(1.4, 3 * reach), fy + max(0.6, 1.5 * reach) - front)
    parts.table(b, fx, front + size[1] / 2, size, top, support=True)
    b.wall(fx, front + size[1] + r.uniform(0.3, 2.0), r.uniform(-0.4, 0.4), 30.0, 6.0, b.material("wall"))
    n = int(r.integers(3, 8))
    sizes = list(dist * b.narrowness() * r.uniform(0.08, 0.25, n))  # ~1-10 % of the image each
    for (x, y), s in zip(b.scatter(n, [s * 0.6 for s in sizes], (fx - reach, fx + reach),
                                   (fy - reach * 0.8, fy + reach * 0.8)), sizes):
        parts.small_object(b, x, y, top, s, r.uniform(-math.pi, math.pi))
    return pose


def floor(b: Builder, seed: int) -> Pose:
    """Things lying on a floor seen from above (55°-90° down, 0.5-1.6 m high: a robot's or a hand-held
    camera looking at the floor): the floor fills the view, one to four objects of 2-20 % of it."""
    r = b.rng
    b.ground(b.material(r.choice(["wood", "ground"]), stripes=0.2))
    pitch = 55.0 + 35.0 * ((seed * _GOLDEN + r.uniform(0, 0.04)) % 1.0)
    p, h = math.radians(pitch), r.uniform(0.5, 1.6)
    dist = h / math.sin(p)  # along the axis to the floor
    fy = 2.0
    reach = dist * min(b.camera.width, b.camera.height) / (2 * b.camera.focal_px)
    n = int(r.integers(1, 5))
    sizes = list(reach * r.uniform(0.35, 0.8, n))
    for (x, y), s in zip(b.scatter(n, [s * 0.6 for s in sizes], (-reach * 1.2, reach * 1.2),
                                   (fy - reach * 0.7, fy + reach * 0.7)), sizes):
        if r.uniform() < 0.3:  # a flat thing: a parcel, a bag, a folded garment
            o = b.new_object("parcel")
            b.box_on(x, y, 0.0, (s, s * r.uniform(0.4, 1.0), s * r.uniform(0.1, 0.35)), o,
                     b.material("object"), r.uniform(-math.pi, math.pi))
        else:
            parts.small_object(b, x, y, 0.0, s, r.uniform(-math.pi, math.pi))
    return Pose(0.0, fy - dist * math.cos(p), h, pitch, r.uniform(-8, 8))


def floor_near(b: Builder, seed: int) -> Pose:
    """Things on a floor seen from above at arm's length (55°-90° down, 0.4-0.9 m high: a robot's
    wrist camera, a phone held over the floor): one to three objects whose footprints add up to
    30-60 % of the floor in view, so that the floor holds far less of the view than in ``floor``
    (pre-registered in session 16, before any run of the pipeline on it: the regime of a probe in
    which ``plane_components`` led)."""
    r = b.rng
    b.ground(b.material(r.choice(["wood", "ground"]), stripes=0.2))
    pitch = 55.0 + 35.0 * ((seed * _GOLDEN + r.uniform(0, 0.04)) % 1.0)
    p, h = math.radians(pitch), r.uniform(0.4, 0.9)
    dist = h / math.sin(p)
    fy = 1.0
    half_w, half_h = (dist * n / (2 * b.camera.focal_px) for n in (b.camera.width, b.camera.height))
    n = int(r.integers(1, 4))
    # each object's footprint side, at most 1.6 x the shorter half view; heights at most 0.4 x the
    # camera's: nothing reaches into the lens
    side = min(math.sqrt(r.uniform(0.3, 0.6) * 4 * half_w * half_h / n), 1.6 * min(half_w, half_h))
    for x, y in b.scatter(n, [side * 0.5] * n, (-max(half_w - side / 2, 0.0), max(half_w - side / 2, 0.0)),
                          (fy - max(half_h - side / 2, 0.0), fy + max(half_h - side / 2, 0.0))):
        yaw = r.uniform(-math.pi, math.pi)
        if r.uniform() < 0.5:  # a parcel, a crate, a bag
            o = b.new_object("parcel")
            b.box_on(x, y, 0.0, (side, side * r.uniform(0.7, 1.0), min(side * r.uniform(0.15, 0.5), 0.4 * h)),
                     o, b.material("object"), yaw)
        else:
            parts.small_object(b, x, y, 0.0, min(side, 0.4 * h), yaw)
    return Pose(0.0, fy - dist * math.cos(p), h, pitch, r.uniform(-8, 8))


def hands(b: Builder, seed: int) -> Pose:
    r = b.rng
    b.ground(b.material("ground"))
    desk = r.uniform(0.7, 0.78)
    height = desk + r.uniform(0.3, 0.5)
    b.box_on(0.0, 0.6, desk - 0.04, (2.0, 1.4, 0.04), 0, b.material("wood", stripes=0.1))
    b.wall(0.0, r.uniform(1.4, 2.5), r.uniform(-0.4, 0.4), 20.0, 5.0, b.material("wall"))
    palms = [_arm(b, r.uniform(-0.2, 0.2), desk) for _ in range(int(r.integers(1, 3)) if r.uniform() < 0.4 else 1)]
    for x, y in b.scatter(int(r.integers(0, 3)), [0.06] * 2, (-0.35, 0.35), (0.55, 0.9)):
        parts.small_object(b, x, y, desk, r.uniform(0.06, 0.14), r.uniform(-math.pi, math.pi))
    # aim at the hands (off-centre by up to a third of the half field of view)
    px, py, pz = np.mean(palms, axis=0)
    half_fov = math.degrees(math.atan(b.camera.height / (2 * b.camera.focal_px)))
    pitch = math.degrees(math.atan2(height - pz, py)) + r.uniform(-1, 1) * half_fov / 3
    yaw = math.degrees(math.atan2(px, py)) + r.uniform(-1, 1) * half_fov / 3
    return Pose(0.0, 0.0, height, float(np.clip(pitch, 5, 60)), yaw)


def _arm(b: Builder, x: float, desk: float) -> np.ndarray:
    """A forearm reaching towards the camera with an open hand (palm + four fingers + thumb); the palm centre."""
    r = b.rng
    o = b.new_object("hand")
    skin, sleeve = b.material("skin", texture="noise"), b.material("object")
    elbow = np.array([x + r.uniform(-0.15, 0.15), r.uniform(0.75, 0.95), desk + r.uniform(0.03, 0.12)])
    wrist = np.array([x + r.uniform(-0.05, 0.05), r.uniform(0.42, 0.55), desk + r.uniform(0.08, 0.22)])
    b.rod(elbow, wrist, r.uniform(0.035, 0.045), o, sleeve)
    fwd = (wrist - elbow) / np.linalg.norm(wrist - elbow)
    side = np.cross(fwd, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    palm_c = wrist + fwd * 0.05
    b.oriented_box(palm_c, np.stack([side * 0.045, np.cross(side, fwd) * 0.014, fwd * 0.05], axis=1), o, skin)
    for k in range(4):
        base = palm_c + fwd * 0.05 + side * (-0.034 + 0.0227 * k)
        tip = base + (fwd + side * (k - 1.5) * r.uniform(0.0, 0.12)) * r.uniform(0.06, 0.085)
        b.rod(base, tip, 0.009, o, skin)
    thumb = palm_c + side * 0.045
    b.rod(thumb, thumb + (fwd * 0.6 + side * 0.8) * 0.06, 0.011, o, skin)
    return palm_c


FAMILIES: dict[str, Family] = {
    "stairs": Family(stairs, 2.0, 10.0, 5.0),
    "garden": Family(garden, 3.0, 25.0, 8.0),
    "road": Family(road, 4.0, 50.0, 12.0),
    "room": Family(room, 1.0, 6.0, 3.0),
    "tabletop": Family(tabletop, 0.4, 1.6, 0.9),
    "hands": Family(hands, 0.3, 1.2, 0.6),
    "fence": Family(fence, 1.5, 12.0, 5.0),
    "clutter": Family(clutter, 1.0, 10.0, 4.0),
    "floor": Family(floor, 0.4, 2.0, 1.0),
    "floor_near": Family(floor_near, 0.2, 1.0, 0.6),
}
"""The families by name."""
