"""Turn a :class:`~somtorch.pipeline.PipelineResult` into files and a metrics dictionary.

Every file is written atomically (temporary file + rename), so an interrupted run never leaves a
half-written file behind. Open3D (PLY) and TensorBoard are imported only when those outputs are
asked for.
"""

from __future__ import annotations

import logging
import math
import time

from pathlib import Path
from typing import Any

import numpy as np

from . import viz
from .atomic import atomic_path
from .config import OutputConfig  # noqa: F401  (re-exported: the output group's schema)
from .evaluation import summary_stats
from .disparity.scene import Scene
from .pipeline import PipelineResult
from .tasks.segmentation import color_map, grey_map

log = logging.getLogger(__name__)


def _finite(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def summarize(scene: Scene, result: PipelineResult, config: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything a run measured, as JSON-ready data (the content of ``metrics.json``)."""
    members = []
    for e, m in enumerate(result.members):
        members.append({
            "seed": m.seed,
            "quantization_error": _finite(float(result.quantization_error[e])),
            "topographic_error": _finite(float(result.topographic_error[e])),
            "n_areas": len(m.areas),
            "kept_areas": [{"neurons": a.neurons, "pixels": a.pixels, "box_xyxy": list(a.box),
                            "mean_disparity": a.mean_disparity, "contrast": a.contrast,
                            "area_frac": a.area_frac,
                            **{k: _finite(getattr(a, k)) for k in ("purity", "solidity", "confidence")}}
                           for a in m.kept],
            "kept_boxes_xyxy": [list(b) for b in m.reduction.boxes],
            "kept_valid_union": m.reduction.kept_union,
            "kept_valid_crops": m.reduction.kept_crops,
            "reduction_union": m.reduction.reduction_union,
            "reduction_crops": m.reduction.reduction_crops,
            "no_object": m.no_object,
            "kept_everything": m.reduction.reduction_union < 1.0,
            "score": m.score.as_dict() if m.score is not None else None,
        })
    out: dict[str, Any] = {
        "method": result.method,
        "scene": {"name": scene.name, "height": scene.height, "width": scene.width,
                  "valid_pixels": scene.n_valid,
                  "invalid_pixels": scene.height * scene.width - scene.n_valid,
                  "ground_pixels": int(result.ground.mask.sum()) if result.ground is not None else 0,
                  "has_objects": scene.objects is not None, "source": scene.source},
        "pixels": {"train": len(result.train_features), "segmented": len(result.features),
                   "train_stride": result.train_features.stride},
        "timings_s": dict(result.timings),
        "members": members,
    }
    scores = [m.score for m in result.members if m.score is not None]
    if scores:
        complete = [s.reduction_union for s in scores if s.identified_100]
        hits95 = [s.reduction_union for s in scores if s.identified_95]
        out["summary"] = {
            "runs": len(scores),
            "identified_100": sum(s.identified_100 for s in scores),
            "identified_95": sum(s.identified_95 for s in scores),
            "useful_hits": sum(s.useful_hit for s in scores),
            "x_opt": scores[0].x_opt,
            "reduction_complete": summary_stats(complete),
            "reduction_95": summary_stats(hits95),
            "reduction_crops_complete": summary_stats([s.reduction_crops for s in scores if s.identified_100]),
            "mean_identified_fraction": float(np.mean([s.identified_fraction for s in scores])),
        }
    if config is not None:
        out["config"] = config
    return out


def write_maps(scene: Scene, result: PipelineResult, out_dir: Path, member: int = 0) -> dict[str, np.ndarray]:
    """Write the pictures of one member (PNG) and the reduced map (NPZ); returns the pictures."""
    e = member
    lab = result.labels[e]
    k = result.num_segments
    lo, hi = result.members[e].stats.d_range
    back = viz.image_or_disparity(scene.image, scene.disparity, scene.valid)
    m = result.members[e]
    pics = {
        "disparity": viz.colorize(scene.disparity, scene.valid),
        "segments_grey": viz.grey(grey_map(lab[None], result.ref_disparity[e:e + 1])[0], lo=lo, hi=hi),
        "segments_color": color_map(lab[None], k, seed=0)[0].numpy(),
        # kept areas (red), kept boxes (yellow), object outline (green), ground plane (blue)
        "areas": viz.draw_areas(back, lab, [a.neurons for a in m.kept], m.reduction.boxes,
                                scene.main_object_mask if scene.objects is not None else None,
                                extra_mask=result.ground.mask if result.ground is not None else None),
        "reduced_disparity": viz.colorize(scene.disparity, scene.valid & m.reduction.mask, lo=lo, hi=hi),
    }
    if result.som is not None:
        pics["reference_vectors"] = viz.draw_reference_vectors(
            viz.colorize(scene.disparity, scene.valid),
            result.features.to_pixel_units(result.som.weight.detach()[e]), result.som.grid_d2)
    for name, img in pics.items():
        viz.save_png(img, out_dir / f"{name}.png")
    viz.summary_figure(scene, result, out_dir / "summary.png", member=e)
    with atomic_path(out_dir / "reduced.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(
                f, disparity=np.where(m.reduction.mask.numpy(), scene.disparity.numpy(), np.nan).astype(np.float32),
                valid=(scene.valid & m.reduction.mask).numpy(), mask=m.reduction.mask.numpy(),
                boxes_xyxy=np.asarray(m.reduction.boxes, dtype=np.int64).reshape(-1, 4),
                labels=lab.numpy().astype(np.int16))
    return pics


def write_point_clouds(scene: Scene, result: PipelineResult, out_dir: Path, *, member: int = 0,
                       voxel_size: float | None = None, render: bool = True,
                       render_backend: str = "auto") -> dict[str, Any]:
    """PLY files of the full and the reduced map (and a PNG view of the reduced one)."""
    from .geometry import disparity_to_point_cloud, render_point_cloud, write_ply

    cam = scene.camera
    if cam is None:
        log.warning("scene %s has no camera: no point cloud written", scene.name)
        return {"written": False, "reason": "no camera"}
    kw = dict(focal_px=cam.focal_px, cx=cam.cx, cy=cam.cy, baseline=cam.baseline, doffs=cam.doffs,
              image=scene.image, voxel_size=voxel_size)
    t0 = time.perf_counter()
    full = disparity_to_point_cloud(scene.disparity, scene.valid, **kw)
    reduced = disparity_to_point_cloud(scene.disparity, scene.valid,
                                       mask=result.members[member].reduction.mask, **kw)
    units = f"x y z in {cam.baseline_unit} (the baseline's unit), camera frame of the left view"
    write_ply(full, out_dir / "cloud_full.ply", comment=units)
    info: dict[str, Any] = {"written": True, "unit": cam.baseline_unit, "voxel_size": voxel_size,
                            "points_full": len(full), "points_reduced": len(reduced),
                            "bytes_full": full.nbytes, "bytes_reduced": reduced.nbytes}
    if len(reduced):
        write_ply(reduced, out_dir / "cloud_reduced.ply", comment=units)
        if render:
            info["render_backend"] = render_point_cloud(
                reduced, out_dir / "cloud_reduced.png", backend=render_backend, view="oblique",
                unit=cam.baseline_unit, title=f"{scene.name}: reduced point cloud, {len(reduced):,} points "
                                              "(framed on the 2-98 % range of x, y and depth)")
    info["seconds"] = time.perf_counter() - t0
    return info
