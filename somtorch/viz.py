"""Pictures of the pipeline: disparity maps, segment maps, reference vectors (Fig. 10), object areas.

All functions return ``uint8`` RGB arrays ``(H, W, 3)`` (so they also feed TensorBoard) and
:func:`save_png` writes them atomically. matplotlib is used with the Agg backend only.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np
import torch

from .atomic import atomic_path


def save_png(image: np.ndarray, path: str | os.PathLike) -> Path:
    """Write an RGB ``(H, W, 3)`` or grey ``(H, W)`` uint8 image as PNG, atomically."""
    arr = np.ascontiguousarray(image)
    if arr.dtype != np.uint8:
        raise TypeError(f"image must be uint8; got {arr.dtype}")
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), arr):
            raise OSError(f"OpenCV could not write {path}")
    return Path(path)


def _unit(values: torch.Tensor, valid: torch.Tensor | None, lo: float | None,
          hi: float | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Values scaled to [0, 1] between lo and hi (default: their range) and the mask of usable ones."""
    v = values.detach().double().cpu().numpy()
    ok = np.isfinite(v) if valid is None else (valid.cpu().numpy() & np.isfinite(v))
    if not ok.any():
        return None
    lo = float(v[ok].min()) if lo is None else lo
    hi = float(v[ok].max()) if hi is None else hi
    return np.clip((np.where(ok, v, lo) - lo) / max(hi - lo, 1e-12), 0, 1), ok


def colorize(values: torch.Tensor, valid: torch.Tensor | None = None, *, lo: float | None = None,
             hi: float | None = None, cmap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """Colour-map a float map ``(H, W)`` (NaN / invalid → black). Returns ``(H, W, 3)`` uint8 RGB."""
    unit = _unit(values, valid, lo, hi)
    if unit is None:
        return np.zeros((*values.shape, 3), np.uint8)
    g, ok = unit
    rgb = cv2.cvtColor(cv2.applyColorMap((g * 255).astype(np.uint8), cmap), cv2.COLOR_BGR2RGB)
    rgb[~ok] = 0
    return rgb


def grey(values: torch.Tensor, valid: torch.Tensor | None = None, *, lo: float | None = None,
         hi: float | None = None) -> np.ndarray:
    """Grey rendering of a float map (near = bright), invalid black. ``(H, W)`` → ``(H, W, 3)`` uint8."""
    unit = _unit(values, valid, lo, hi)
    if unit is None:
        return np.zeros((*values.shape, 3), np.uint8)
    g, ok = unit
    g = (g * 215 + 40).astype(np.uint8)
    g[~ok] = 0
    return np.repeat(g[..., None], 3, axis=2)


def draw_reference_vectors(background: np.ndarray, ref_px: torch.Tensor, grid_d2: torch.Tensor) -> np.ndarray:
    """Fig. 10: the neurons drawn as dots at their (x, y), grid neighbours joined by lines.

    Shape:
        ``background`` ``(H, W, 3)`` uint8, ``ref_px`` ``(K, 3)`` (y, x, d) px, ``grid_d2`` ``(K, K)``.
    """
    img = background.copy()
    pts = ref_px[:, :2].detach().cpu().numpy()
    d = ref_px[:, 2].detach().cpu().numpy()
    k = len(pts)
    adj = ((grid_d2 <= 1.0 + 1e-6) & (grid_d2 > 0)).cpu().numpy()
    scale = max(1, round(max(img.shape[:2]) / 400))
    for i in range(k):
        for j in range(i + 1, k):
            if adj[i, j]:
                p = (int(round(pts[i, 1])), int(round(pts[i, 0])))
                q = (int(round(pts[j, 1])), int(round(pts[j, 0])))
                cv2.line(img, p, q, (255, 255, 255), scale, cv2.LINE_AA)
    lo, hi = float(d.min()), float(d.max())
    for i in range(k):
        g = (d[i] - lo) / max(hi - lo, 1e-12)
        color = tuple(int(c) for c in cv2.applyColorMap(np.uint8([[g * 255]]), cv2.COLORMAP_TURBO)[0, 0][::-1])
        c = (int(round(pts[i, 1])), int(round(pts[i, 0])))
        cv2.circle(img, c, 4 * scale, color, -1, cv2.LINE_AA)
        cv2.circle(img, c, 4 * scale, (0, 0, 0), max(1, scale // 2), cv2.LINE_AA)
    return img


def draw_areas(background: np.ndarray, labels: torch.Tensor, kept_neurons: list[list[int]],
               boxes: list[tuple[int, int, int, int]], object_mask: torch.Tensor | None = None,
               extra_mask: torch.Tensor | None = None) -> np.ndarray:
    """Kept object areas tinted, kept boxes in yellow, the ground-truth object outline in green and
    an optional extra mask (e.g. the ground plane) tinted blue.

    Shape:
        ``background`` ``(H, W, 3)`` uint8, ``labels`` ``(H, W)`` long, masks ``(H, W)`` bool.
    """
    img = background.astype(np.float32).copy()
    lab = labels.cpu().numpy()
    if extra_mask is not None:
        m = extra_mask.cpu().numpy()
        img[m] = 0.5 * img[m] + 0.5 * np.array([40, 90, 255], np.float32)
    tints = [(255, 60, 60), (255, 160, 0), (200, 60, 255), (0, 200, 200)]
    for i, neurons in enumerate(kept_neurons):
        m = np.isin(lab, np.asarray(neurons))
        img[m] = 0.45 * img[m] + 0.55 * np.array(tints[i % len(tints)], np.float32)
    out = img.clip(0, 255).astype(np.uint8)
    if object_mask is not None:
        contours, _ = cv2.findContours(object_mask.cpu().numpy().astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, contours, -1, (0, 255, 0), 2)
    for x0, y0, x1, y1 in boxes:
        cv2.rectangle(out, (x0, y0), (x1, y1), (255, 255, 0), 2)
    return out


def kept_view(disparity: torch.Tensor, valid: torch.Tensor, kept: torch.Tensor,
              boxes: list[tuple[int, int, int, int]], *, lo: float | None = None, hi: float | None = None
              ) -> np.ndarray:
    """What a reduction kept: the coloured disparity inside the kept boxes, dimmed outside, the
    boxes in yellow (one frame of a sequence's video).

    Shape:
        ``disparity`` ``(H, W)`` float, ``valid`` and ``kept`` ``(H, W)`` bool → ``(H, W, 3)`` uint8.
    """
    img = colorize(disparity, valid, lo=lo, hi=hi).astype(np.float32)
    out_side = ~kept.cpu().numpy()
    img[out_side] *= 0.3
    out = img.clip(0, 255).astype(np.uint8)
    for x0, y0, x1, y1 in boxes:
        cv2.rectangle(out, (x0, y0), (x1, y1), (255, 255, 0), 2)
    return out


def image_or_disparity(image: torch.Tensor | None, disparity: torch.Tensor, valid: torch.Tensor) -> np.ndarray:
    """The left image as ``(H, W, 3)`` uint8, or a grey disparity rendering when there is none."""
    if image is not None:
        return image.permute(1, 2, 0).contiguous().cpu().numpy()
    return grey(disparity, valid)


# ------------------------------------------------------------------------------- summary figure
TINTS = [(255, 60, 60), (255, 160, 0), (200, 60, 255), (0, 200, 200)]
"""Colours of the kept areas in :func:`draw_areas` (area 1, 2, …), also the summary's legend."""


def identified_percent(fraction: float) -> str:
    """``fraction`` (0–1) as a percentage floored to one decimal: 0.998 → ``"99.8 %"``, and only a
    complete identification reads ``"100 %"`` (rounding would print 99.96 % as 100 %).

    >>> identified_percent(0.9980125), identified_percent(0.99996), identified_percent(1.0)
    ('99.8 %', '99.9 %', '100 %')
    """
    if fraction >= 1.0:
        return "100 %"
    return f"{math.floor(fraction * 1000 + 1e-9) / 10:.1f} %"  # + 1e-9: 0.29 * 1000 is 289.99…


def summary_figure(scene, result, path: str | os.PathLike, member: int = 0) -> Path:
    """:func:`draw_summary` written to ``path`` as PNG, atomically."""
    import matplotlib.pyplot as plt

    fig = draw_summary(scene, result, member)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def draw_summary(scene, result, member: int = 0):
    """The paper's Fig. 18 for one member, figure-ready: (a) disparity with its colour bar in px,
    invalid pixels grey and the removed ground hatched blue; (b) the SOM's reference vectors over
    it; (c) the segments; (d) the object areas (kept ones tinted, their boxes, the labelled object
    outlined) with a legend; (e) what is kept (valid pixels inside the boxes) and (f) the reduced
    map with the same colour scale as (a). The title carries the verdict (the identified share floored,
    :func:`identified_percent`). Returns the matplotlib figure (Agg; close it after use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch
    from matplotlib.transforms import offset_copy

    from .tasks.segmentation import color_map

    m = result.members[member]
    lab = result.labels[member]
    valid = scene.valid.numpy()
    d = np.where(valid, scene.disparity.numpy(), np.nan)
    lo, hi = (np.nanpercentile(d, [1, 99]) if valid.any() else (0.0, 1.0))
    ground = result.ground.mask.numpy() if result.ground is not None else None
    h, w = d.shape
    # two rows of panels about 4.4 in wide (h / w of that high) plus titles, tick labels, x labels and
    # the legends under (d) and (e)
    fig, axes = plt.subplots(2, 3, figsize=(15, 2 * 4.4 * h / w + 3.2), dpi=80, constrained_layout=True)
    cmap = matplotlib.colormaps["turbo"].with_extremes(bad=(0.55, 0.55, 0.55))

    def disparity_panel(ax, values, title):
        im = ax.imshow(values, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
        fig.colorbar(im, cax=ax.inset_axes([1.03, 0.0, 0.04, 1.0]), label="disparity [px]")  # as high as the map
        ax.set_title(title)

    disparity_panel(axes[0, 0], d, "(a) disparity (grey: no value)")
    if ground is not None:
        axes[0, 0].contourf(ground.astype(float), levels=[0.5, 1.5], colors="none", hatches=["///"])
        axes[0, 0].set_title("(a) disparity (grey: no value; hatched: ground plane)")
    ax = axes[0, 1]
    if result.som is not None:
        ax.imshow(draw_reference_vectors(colorize(scene.disparity, scene.valid),
                                         result.features.to_pixel_units(result.som.weight.detach()[member]),
                                         result.som.grid_d2))
        ax.set_title(f"(b) SOM {result.som.rows}x{result.som.cols}: reference vectors and grid links")
    else:
        ax.imshow(colorize(scene.disparity, scene.valid))
        ax.set_title(f"(b) method {result.method}: no SOM grid")
    seg = color_map(lab[None], result.num_segments, seed=0)[0].numpy()
    axes[0, 2].imshow(seg, interpolation="nearest")
    axes[0, 2].set_title(f"(c) segments: one per neuron ({result.num_segments}; black: none)")
    back = image_or_disparity(scene.image, scene.disparity, scene.valid)
    obj = scene.main_object_mask if scene.objects is not None else None
    axes[1, 0].imshow(draw_areas(back, lab, [a.neurons for a in m.kept], m.reduction.boxes, obj,
                                 extra_mask=result.ground.mask if result.ground is not None else None))
    handles = [Patch(color=np.array(TINTS[i % len(TINTS)]) / 255, label=f"kept area {i + 1}"
                     + (f" (confidence {a.confidence:.2f})" if a.confidence is not None else ""))
               for i, a in enumerate(m.kept)]
    handles.append(Patch(facecolor="none", edgecolor=(1, 1, 0), linewidth=2, label="kept box (with tolerance)"))
    if obj is not None:
        handles.append(Patch(facecolor="none", edgecolor=(0, 1, 0), linewidth=2, label="labelled object"))
    if ground is not None:
        # the ground is left out of the segmentation; inside a kept box its pixels are kept, as (e) shows
        handles.append(Patch(color=(40 / 255, 90 / 255, 1.0), alpha=0.5,
                             label="ground plane (not segmented; kept inside a kept box)"))
    below = offset_copy(axes[1, 0].transAxes, fig=fig, y=-34, units="points")  # under the x label
    axes[1, 0].legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=below,
                      ncol=1, fontsize=8, frameon=False)
    axes[1, 0].set_title("(d) object areas" + (" — no convincing area: whole map kept" if m.no_object else ""))
    kept = np.zeros((h, w), np.int8)
    kept[valid] = 1
    kept[valid & m.reduction.mask.numpy()] = 2
    axes[1, 1].imshow(kept, cmap=ListedColormap([(0.55, 0.55, 0.55), (0.85, 0.85, 0.85), (0.1, 0.45, 0.85)]),
                      vmin=0, vmax=2, interpolation="nearest")
    axes[1, 1].legend(handles=[Patch(color=(0.1, 0.45, 0.85), label=f"kept ({m.reduction.kept_union:,} px)"),
                               Patch(color=(0.85, 0.85, 0.85), label="removed"),
                               Patch(color=(0.55, 0.55, 0.55), label="no disparity")],
                      loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3, fontsize=8, frameon=False,
                      bbox_transform=offset_copy(axes[1, 1].transAxes, fig=fig, y=-34, units="points"))
    axes[1, 1].set_title(f"(e) kept region: reduction {m.reduction.reduction_union:.1f} %")
    disparity_panel(axes[1, 2], np.where(valid & m.reduction.mask.numpy(), d, np.nan), "(f) reduced map")
    for ax in axes.flat:
        ax.set_xlabel("x [px]")
        ax.set_ylabel("y [px]")
    verdict = ""
    if m.score is not None:
        s = m.score
        verdict = (f" — object {identified_percent(s.identified_fraction)} identified, x_opt {s.x_opt:.1f} %: "
                   f"{'useful' if s.useful_hit else 'not useful'}")
    # several maps per run (PipelineConfig.consensus): which one the run kept, and how well the others agree
    kept_map = "" if m.agreement is None else f", map {m.consensus_map} kept (agreement {m.agreement:.2f})"
    fig.suptitle(f"{scene.name}, member {member} (seed {m.seed}{kept_map}), {len(m.kept)} kept area(s), reduction "
                 f"{m.reduction.reduction_union:.1f} %{verdict}", fontsize=13)
    return fig
