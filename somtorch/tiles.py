"""Divide and conquer: the pipeline on overlapping tiles of a large map, areas reassembled.

The paper's future work: "the disparity map divided into several smaller disparity maps,
protruding detected objects reassembled before the data reduction". :func:`run_tiled` cuts the map
into a grid of tiles that overlap by ``overlap`` of a tile's side, runs steps 1a–1c on each tile
(in worker processes, or in this one), maps every kept area back to map coordinates, and then:

1. **reassembles** areas of different tiles that overlap or touch (within the overlap band) and
   lie at a similar disparity (``|Δd|`` at most ``objects.similarity`` × the map's disparity
   spread or ``objects.merge`` × the smaller contrast: the rules that link and join segments inside
   one map): an object cut by a tile border becomes one box again;
2. **ranks globally**: a tile keeps the most salient thing *it* sees, even where that is
   background, so the reassembled areas are ranked with the object step's own score (contrast ×
   area share of the whole map ^ ``size_power``) and the ``max_areas`` best with a positive
   score are kept, as one map's areas;
3. reduces the whole map with the kept boxes (step 1d) and scores it like :func:`~somtorch.pipeline.run_pipeline`.

Each tile is an independent problem (its own SOM, ground plane and disparity spread), which is
what makes it parallel; the price is that context across tiles (the ground under a far object,
the contrast against a distant background) is lost. ``docs/scaling.md`` compares tiled and
whole-map runs on the shared scenes and on a 3840 × 2160 map.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import torch

from .config import PipelineConfig
from .disparity.scene import Scene
from .interrupt import worker_pool
from .tasks.objects import disparity_spread
from .tasks.reduction import Reduction, reduce_map
from .tasks.scoring import Score, optimal_reduction, score_reduction

__all__ = ["TiledArea", "TiledResult", "run_tiled", "tile_windows"]

Box = tuple[int, int, int, int]


def tile_windows(h: int, w: int, grid: tuple[int, int], overlap: float) -> list[tuple[int, int, int, int]]:
    """``(y0, y1, x0, x1)`` (end exclusive) of a ``rows × cols`` grid of tiles covering an
    ``h × w`` map, each grown by ``overlap`` × its side on every inner border."""
    rows, cols = grid
    if rows < 1 or cols < 1:
        raise ValueError(f"tiles must be at least 1 x 1; got {rows} x {cols}")
    if not 0 <= overlap < 0.5:
        raise ValueError(f"overlap must be in [0, 0.5); got {overlap}")
    if rows > h or cols > w:
        raise ValueError(f"{rows} x {cols} tiles do not fit a {w} x {h} map")
    out = []
    for r in range(rows):
        for c in range(cols):
            y0, y1 = r * h // rows, (r + 1) * h // rows
            x0, x1 = c * w // cols, (c + 1) * w // cols
            my, mx = round(overlap * (y1 - y0)), round(overlap * (x1 - x0))
            out.append((max(0, y0 - my), min(h, y1 + my), max(0, x0 - mx), min(w, x1 + mx)))
    return out


def crop_scene(scene: Scene, y0: int, y1: int, x0: int, x1: int, *, with_objects: bool = True) -> Scene:
    """The part ``[y0:y1, x0:x1]`` of ``scene`` (image and, with ``with_objects``, the object
    masks cut alike; camera shifted)."""
    cam = scene.camera
    if cam is not None:
        cam = dataclasses.replace(cam, cx=cam.cx - x0, cy=cam.cy - y0)
    objects, info = None, []
    if scene.objects is not None and with_objects:
        objects = scene.objects[y0:y1, x0:x1].clone()
        present = set(torch.unique(objects).tolist()) - {0}
        info = [o for o in scene.object_info if o.id in present]
    return dataclasses.replace(
        scene, name=f"{scene.name}[{y0}:{y1},{x0}:{x1}]", disparity=scene.disparity[y0:y1, x0:x1].clone(),
        valid=scene.valid[y0:y1, x0:x1].clone(),
        image=scene.image[:, y0:y1, x0:x1].clone() if scene.image is not None else None,
        objects=objects, object_info=info, camera=cam)


@dataclass
class TiledArea:
    """A kept area in map coordinates: its box, pixels, mean disparity, contrast, the tiles it
    came from and its global rank score."""

    box: Box
    pixels: int
    mean_disparity: float
    contrast: float
    tiles: list[int]
    score: float = 0.0


@dataclass
class TiledMember:
    kept: list[TiledArea]
    candidates: list[TiledArea]
    reduction: Reduction
    score: Score | None


@dataclass
class TiledResult:
    """What :func:`run_tiled` returns.

    Attributes:
        members: per ensemble member, the merged kept areas, reduction and score.
        windows: the tiles ``(y0, y1, x0, x1)`` in pixels (end exclusive, see :func:`tile_windows`).
        timings: seconds: ``"tiles"`` (wall, all workers), ``"merge"``, ``"total"``.
        tile_seconds: each tile's own pipeline time.
    """

    members: list[TiledMember]
    windows: list[tuple[int, int, int, int]]
    timings: dict[str, float]  # seconds: "tiles" (wall, all workers), "merge", "total"
    tile_seconds: list[float]  # each tile's own pipeline time


def _tile_job(args: tuple[Scene, PipelineConfig, int]) -> tuple[int, list[list[tuple]], float]:
    """Run the pipeline on one tile; returns its kept areas per member (tile coordinates)."""
    from .pipeline import run_pipeline

    tile, cfg, k = args
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    if int(tile.valid.sum()) < 16:
        return k, [[] for _ in range(cfg.runs)], 0.0
    try:
        res = run_pipeline(tile, cfg, metrics=False)
    except ValueError:  # a tile the pipeline refuses (e.g. nothing to train on): it contributes nothing
        return k, [[] for _ in range(cfg.runs)], time.perf_counter() - t0
    out = [[(a.box, a.pixels, a.mean_disparity, a.contrast) for a in m.kept] if not m.no_object else []
           for m in res.members]
    return k, out, time.perf_counter() - t0


def _touch(a: Box, b: Box, gap: int) -> bool:
    return not (a[2] + gap < b[0] or b[2] + gap < a[0] or a[3] + gap < b[1] or b[3] + gap < a[1])


def _reassemble(areas: list[TiledArea], d_tol: float, gap: int, merge: float) -> list[TiledArea]:
    """Union-find over areas of different tiles whose boxes touch and whose mean disparities differ
    by at most ``max(d_tol, merge × the smaller contrast)``."""
    parent = list(range(len(areas)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, a in enumerate(areas):
        for j in range(i + 1, len(areas)):
            b = areas[j]
            if set(a.tiles) & set(b.tiles):
                continue
            tol = max(d_tol, merge * min(a.contrast, b.contrast))  # the merge rule of one map's segments
            if _touch(a.box, b.box, gap) and abs(a.mean_disparity - b.mean_disparity) <= tol:
                parent[find(j)] = find(i)
    groups: dict[int, list[TiledArea]] = {}
    for i, a in enumerate(areas):
        groups.setdefault(find(i), []).append(a)
    out = []
    for g in groups.values():
        px = sum(a.pixels for a in g)
        out.append(TiledArea(
            box=(min(a.box[0] for a in g), min(a.box[1] for a in g), max(a.box[2] for a in g), max(a.box[3] for a in g)),
            pixels=px, mean_disparity=sum(a.mean_disparity * a.pixels for a in g) / max(px, 1),
            contrast=max(a.contrast for a in g), tiles=sorted({t for a in g for t in a.tiles})))
    return out


def run_tiled(scene: Scene, cfg: PipelineConfig | None = None, *, tiles: tuple[int, int] = (2, 2),
              overlap: float = 0.1, workers: int = 0) -> TiledResult:
    """Steps 1a–1d on ``tiles`` (rows, cols) of ``scene`` (see the module docstring).

    Args:
        overlap: share of a tile's side added on each inner border.
        workers: processes running tiles at once (0: one after the other in this process). Workers
            are spawned: a script calling this with workers > 0 needs the usual
            ``if __name__ == "__main__":`` guard.
    """
    cfg = cfg or PipelineConfig()
    t0 = time.perf_counter()
    h, w = scene.height, scene.width
    windows = tile_windows(h, w, tiles, overlap)
    jobs = [(crop_scene(scene, *win, with_objects=False), cfg, k) for k, win in enumerate(windows)]
    if workers > 0:
        with worker_pool(workers) as pool:  # an error or a signal here ends the workers at once
            done = list(pool.map(_tile_job, jobs))
    else:
        done = [_tile_job(j) for j in jobs]
    t_tiles = time.perf_counter() - t0
    spread = disparity_spread(scene.disparity, scene.valid)[1]
    d_tol = cfg.objects.similarity * (spread[1] - spread[0])
    gap = max(1, round(overlap * min(h // tiles[0], w // tiles[1])))
    n_valid = max(int(scene.valid.sum()), 1)
    obj = scene.main_object_mask if cfg.object_id is None or scene.objects is None else scene.object_mask(cfg.object_id)
    x_opt = optimal_reduction(obj, scene.valid) if obj is not None else None
    oc, r = cfg.objects, cfg.reduction
    members = []
    for e in range(cfg.runs):
        areas = []
        for k, per_member, _ in done:
            y0, _, x0, _ = windows[k]
            for box, px, md, con in per_member[e]:
                areas.append(TiledArea((box[0] + x0, box[1] + y0, box[2] + x0, box[3] + y0), px, md, con, [k]))
        merged = _reassemble(areas, d_tol, gap, oc.merge)
        for a in merged:
            a.score = max(a.contrast, 0.0) * (a.pixels / n_valid) ** oc.size_power
        merged.sort(key=lambda a: -a.score)
        kept = [a for a in merged if a.score > 0][:oc.max_areas]
        if not kept:  # fail-safe, as one map: keep everything rather than nothing
            ys, xs = scene.valid.nonzero(as_tuple=True)
            kept = [TiledArea((int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())), n_valid, 0.0, 0.0, [])]
        red = reduce_map([a.box for a in kept], scene.valid, tolerance_px=r.tolerance_px,
                         tolerance_frac=r.tolerance_frac, tolerance_image=r.tolerance_image)
        score = score_reduction(red, obj, scene.valid, x_opt=x_opt) if obj is not None else None
        members.append(TiledMember(kept, merged, red, score))
    total = time.perf_counter() - t0
    return TiledResult(members, windows, {"tiles": t_tiles, "merge": total - t_tiles, "total": total},
                       [s for _, _, s in sorted(done)])
