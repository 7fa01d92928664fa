"""Turn a :class:`~somtorch.results.PipelineResult` into files and a metrics dictionary.

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
import torch

from . import viz
from .atomic import atomic_path
from .config import OutputConfig  # noqa: F401  (re-exported: the output group's schema)
from .evaluation import summary_stats
from .disparity.scene import Scene
from .pipeline import PipelineResult
from .tasks.context import object_mode
from .tasks.segmentation import color_map, grey_map

log = logging.getLogger(__name__)


def _finite(v: float) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _map_seed(result: PipelineResult, e: int, seed: int) -> int:
    seg = result.segmentation
    return int(seg.seeds[e]) if seg is not None and len(seg.seeds) > e else int(seed)


def summarize(scene: Scene, result: PipelineResult, config: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything a run measured, as JSON-ready data (the content of ``metrics.json``)."""
    members = []
    for e, m in enumerate(result.members):
        members.append({
            "seed": m.seed,
            # PipelineConfig.consensus: the kept map of the run's maps (its index and seed: the
            # checkpoint's), and how well it agrees with the others (mean IoU of the kept pixels; null
            # with one map per run)
            "consensus_map": m.consensus_map, "map_seed": _map_seed(result, e, m.seed),
            "agreement": _finite(m.agreement),
            # how many of the run's maps were useful alone (null: one map a run, or nothing to score)
            "maps_useful": m.maps_useful,
            "quantization_error": _finite(float(result.quantization_error[e])),
            "topographic_error": _finite(float(result.topographic_error[e])),
            "n_areas": len(m.areas),
            "kept_areas": [{"neurons": a.neurons, "pixels": a.pixels, "box_xyxy": list(a.box),
                            "mean_disparity": a.mean_disparity, "contrast": a.contrast,
                            "area_frac": a.area_frac,
                            **{k: _finite(getattr(a, k)) for k in ("purity", "solidity", "solidity_rel",
                                                                    "confidence", "grown_contrast")}}
                           for a in m.kept],
            "kept_boxes_xyxy": [list(b) for b in m.reduction.boxes],
            "kept_valid_union": m.reduction.kept_union,
            "kept_valid_crops": m.reduction.kept_crops,
            "reduction_union": m.reduction.reduction_union,
            "reduction_crops": m.reduction.reduction_crops,
            "no_object": m.no_object,
            "kept_everything": m.reduction.reduction_union < 1.0,
            # what became of each area the selection looked at (tasks.candidates.Candidate), best first
            "candidates": [{"rank": c.rank, "score": c.score, "verdict": c.verdict, "pixels": c.area.pixels,
                            "box_xyxy": list(c.area.box), "mean_disparity": c.area.mean_disparity,
                            "contrast": c.area.contrast, "grown_contrast": _finite(c.area.grown_contrast)}
                           for c in m.candidates],
            "areas_not_ranked": dict(m.unranked),
            "score": m.score.as_dict() if m.score is not None else None,
        })
    out: dict[str, Any] = {
        "method": result.method,
        "scene": {"name": scene.name, "height": scene.height, "width": scene.width,
                  "valid_pixels": scene.n_valid,
                  "invalid_pixels": scene.height * scene.width - scene.n_valid,
                  "ground_pixels": int(result.ground.mask.sum()) if result.ground is not None else 0,
                  "median_window": result.median,
                  "has_objects": scene.objects is not None, "source": scene.source},
        "pixels": {"train": len(result.train_features), "segmented": len(result.features),
                   **train_strides(scene, result)},
        "timings_s": dict(result.timings),
        "object_step": object_step(result),
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


def object_step(result: PipelineResult) -> dict[str, str] | None:
    """How step 1c linked and ranked the areas, and why (:func:`~somtorch.tasks.context.object_mode`):
    ``{"mode": "support" | "contrast" | "paper", "reason": ...}``; ``"contrast"`` is the fallback of
    the default rule where no support plane was verified. None for a run without a SOM config."""
    if result.config is None:
        return None
    mode, why = object_mode(result.ground, result.config.objects)
    return {"mode": mode, "reason": why}


def train_strides(scene: Scene, result: PipelineResult) -> dict[str, Any]:
    """The configured ``features.train_stride``, the one used on this scene and why they differ."""
    used = result.train_features.stride
    out: dict[str, Any] = {"train_stride": used, "train_stride_effective": used}
    f = result.config.features if result.config is not None else None
    if f is not None:
        out["train_stride"] = f.train_stride
        if used != f.train_stride:
            out["train_stride_reason"] = (
                f"features.train_stride={f.train_stride} is counted on an image of features.reference_pixels="
                f"{f.reference_pixels} px; at {scene.width}x{scene.height} it becomes {used} (x sqrt of the pixel "
                "ratio, so the share of training pixels does not depend on the resolution; reference_pixels=0: "
                "strides as given)")
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
    info["objects"] = object_extents(scene, result, member)
    for i, o in enumerate(info["objects"]):
        if o is not None:
            size = " x ".join(_length(v) for v in o["size_xyz"])
            h = o["height_above_plane"]
            above = "" if h is None else f", {_length(h)} above the ground plane"
            log.info("scene %s: kept area %d: %s %s (x, y, z), its centre at a depth of %s%s", scene.name, i, size,
                     cam.baseline_unit, _length(o["centroid_xyz"][2]), above)
    info["seconds"] = time.perf_counter() - t0
    return info


def _length(v: float) -> str:
    """A length for a log line: three significant digits, whole units from 1000 on (millimetres)."""
    return f"{v:.0f}" if abs(v) >= 1000 else f"{v:.3g}"


def object_extents(scene: Scene, result: PipelineResult, member: int = 0) -> list[dict[str, Any] | None]:
    """Where each kept area of ``member`` is in 3-D and how large it is
    (:func:`~somtorch.geometry.object_extent`, in the camera's baseline unit): the valid pixels of
    its segments inside its box, and its height above the ground plane where one was cut (a plane:
    a bent support surface has none, ``height_above_plane`` null). One entry per kept area, None for
    an area with no pixel of finite depth; [] without a camera."""
    from .geometry import object_extent
    from .tasks.objects import label_mask

    cam = scene.camera
    if cam is None:
        return []
    g = result.ground
    plane = (g.a, g.b, g.c) if g is not None and not any(g.bend) else None
    labels = result.labels[member]
    out: list[dict[str, Any] | None] = []
    for a in result.members[member].kept:
        x0, y0, x1, y1 = a.box
        inside = torch.zeros_like(scene.valid)
        inside[y0:y1 + 1, x0:x1 + 1] = True
        mask = label_mask(labels, a.neurons) & scene.valid & inside
        ext = object_extent(scene.disparity, mask, focal_px=cam.focal_px, cx=cam.cx, cy=cam.cy,
                            baseline=cam.baseline, doffs=cam.doffs, plane=plane)
        out.append(None if ext is None else {**ext.as_dict(), "unit": cam.baseline_unit})
    return out


class SequenceWriter:
    """The pictures of a disparity sequence, written frame by frame (bounded in size whatever the
    number of frames): ``kept.mp4`` (what the reduction kept, :func:`viz.kept_view`, OpenCV's mp4v
    codec, at most ``max_width`` px wide, ``fps`` frames per second) and ``contact_sheet.png`` (up to
    ``sheet`` frames spread evenly over the sequence, ``thumb_width`` px wide each, 4 per row).
    """

    def __init__(self, out_dir: Path, frames: int, *, fps: float = 10.0, max_width: int = 640, sheet: int = 16,
                 thumb_width: int = 320) -> None:
        self.out_dir, self.fps, self.max_width, self.thumb_width = Path(out_dir), fps, max_width, thumb_width
        self.picks = set(np.linspace(0, max(frames - 1, 0), min(sheet, max(frames, 1))).round().astype(int).tolist())
        self.thumbs: list[tuple[int, np.ndarray]] = []
        self._video = None
        self._size: tuple[int, int] | None = None
        self.frames = 0

    def add(self, index: int, scene: Scene, member: Any) -> None:
        """Frame ``index``: ``scene`` and its :class:`~somtorch.results.MemberResult` ``member``."""
        import cv2

        img = viz.kept_view(scene.disparity, scene.valid, member.reduction.mask, member.reduction.boxes)
        h, w = img.shape[:2]
        if self._size is None:
            f = min(1.0, self.max_width / w)
            self._size = (max(2, round(w * f) // 2 * 2), max(2, round(h * f) // 2 * 2))  # even sides
            self._video = cv2.VideoWriter(str(self.out_dir / "kept.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                                          self.fps, self._size)
        frame = cv2.resize(img, self._size, interpolation=cv2.INTER_AREA)
        cv2.putText(frame, f"{index}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        self._video.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        self.frames += 1
        if index in self.picks:
            tw = self.thumb_width
            self.thumbs.append((index, cv2.resize(frame, (tw, max(1, round(frame.shape[0] * tw / frame.shape[1]))),
                                                  interpolation=cv2.INTER_AREA)))

    def close(self) -> dict[str, Any]:
        """Finish the video and write the contact sheet; returns what was written."""
        if self._video is not None:
            self._video.release()
            self._video = None
        if not self.thumbs:
            return {"frames": 0}
        cols = min(4, len(self.thumbs))
        th, tw = self.thumbs[0][1].shape[:2]
        rows = -(-len(self.thumbs) // cols)
        sheet = np.zeros((rows * th, cols * tw, 3), np.uint8)
        for i, (_, t) in enumerate(self.thumbs):
            r, c = divmod(i, cols)
            sheet[r * th:r * th + t.shape[0], c * tw:c * tw + t.shape[1]] = t[:th, :tw]
        viz.save_png(sheet, self.out_dir / "contact_sheet.png")
        return {"frames": self.frames, "video": "kept.mp4", "video_size": list(self._size or ()),
                "fps": self.fps, "contact_sheet": "contact_sheet.png",
                "contact_sheet_frames": [i for i, _ in self.thumbs]}
