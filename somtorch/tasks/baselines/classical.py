"""Classical task-level baselines for step 1c: obstacle boxes without a SOM, scored like the SOM's kept areas.

* :func:`uv_disparity_boxes` — the u-v-disparity obstacle detector of Labayrade, Aubert & Tarel
  (IV 2002): the ground is the dominant oblique line of the *v-disparity* image (one disparity
  histogram per row), obstacles are the cells of the *u-disparity* image (one histogram per
  column) that hold more pixels than a vertical surface of a minimum height would, grouped into
  connected segments; each segment's rows give its box.
* :func:`dsw_boxes` — the Disparity Sliding Window of Müller et al. (IROS 2018): for each
  disparity level, windows the size an object of a given metric size would have at that
  distance (``w_px = size · d / baseline``) slide over the band of pixels at that disparity; a
  window filled enough is a proposal. Needs the camera. The proposal nearest to the camera seeds
  the box of the connected band pixels it overlaps.

Both are deterministic (no seed), numpy + OpenCV, and return boxes ``(x0, y0, x1, y1)``
inclusive, best first, so that :func:`~somtorch.tasks.reduction.reduce_map` and the scorers of
:mod:`somtorch.evaluation` treat them exactly like the SOM's kept areas. Registered (see
:mod:`~somtorch.tasks.baselines.registry`) as ``uv_disparity`` (ranked by pixels × disparity: the
largest near obstacle first) and ``dsw`` (nearest proposal first; needs a metric camera).
"""

from __future__ import annotations


import cv2
import numpy as np
import torch

from .registry import Obstacle, map_arrays, register_task_baseline

__all__ = ["dsw_boxes", "uv_disparity_boxes"]


def _bins(d: np.ndarray, v: np.ndarray, n_bins: int) -> tuple[np.ndarray, float, float]:
    lo, hi = np.percentile(d[v], [0.5, 99.5])
    width = max((hi - lo) / n_bins, 1e-6)
    b = np.clip(((d - lo) / width).astype(np.int64), 0, n_bins - 1)
    return b, float(lo), float(width)


def _ground_line(b: np.ndarray, v: np.ndarray, n_bins: int) -> tuple[float, float] | None:
    """The ground's line ``bin = a · row + c`` in the v-disparity image, or None.

    The line through the rows' dominant bins of the lower half that most rows support (every pair
    of candidate points is tried: a deterministic RANSAC), if it rises down the image and at least
    a third of the lower rows lie on it.
    """
    h = b.shape[0]
    rows, peaks = [], []
    for r in range(h // 2, h):
        m = v[r]
        if m.sum() < 8:
            continue
        counts = np.bincount(b[r][m], minlength=n_bins)
        rows.append(r)
        peaks.append(int(counts.argmax()))
    if len(rows) < 8:
        return None
    r, p = np.array(rows, dtype=np.float64), np.array(peaks, dtype=np.float64)
    idx = np.linspace(0, len(r) - 1, min(len(r), 40)).round().astype(int)
    best, best_n = None, 0
    for i in idx:
        for j in idx:
            if r[j] - r[i] < 0.1 * h:
                continue
            a = (p[j] - p[i]) / (r[j] - r[i])
            c = p[i] - a * r[i]
            n = int((np.abs(p - (a * r + c)) <= 1.5).sum())
            if n > best_n:
                best, best_n = (a, c), n
    if best is None or best[0] <= 0 or best_n < len(r) / 3:
        return None
    inl = np.abs(p - (best[0] * r + best[1])) <= 1.5
    a, c = np.polyfit(r[inl], p[inl], 1)
    return (float(a), float(c)) if a > 0 else None


def uv_disparity_boxes(disparity: torch.Tensor, valid: torch.Tensor, *, n_bins: int = 64,
                       min_height: float = 0.04, min_width: float = 0.02, ground_band: float = 1.5) -> list[Obstacle]:
    """Obstacles of the u-v-disparity method (see the module docstring), nearest first.

    Args:
        n_bins: disparity bins between the 0.5 % and 99.5 % quantiles.
        min_height: a u-disparity cell is an obstacle cell when it holds at least this share of the
            image height (a vertical surface at least that tall in the column).
        min_width: obstacles narrower than this share of the image width are dropped.
        ground_band: pixels within this many bins of the ground line are ground.

    Shape:
        ``disparity``, ``valid`` ``(H, W)``.
    """
    d, v = map_arrays(disparity, valid)
    h, w = d.shape
    b, _, _ = _bins(d, v, n_bins)
    line = _ground_line(b, v, n_bins)
    obstacle = v.copy()
    if line is not None:
        a, c = line
        expect = a * np.arange(h, dtype=np.float64)[:, None] + c
        obstacle &= ~(np.abs(b - expect) <= ground_band)
    # u-disparity: U[bin, column]
    cols = np.broadcast_to(np.arange(w), (h, w))
    u = np.zeros((n_bins, w), dtype=np.int64)
    np.add.at(u, (b[obstacle], cols[obstacle]), 1)
    cells = (u >= max(4.0, min_height * h)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(cells, connectivity=8)
    out = []
    for k in range(1, n):
        x0, y0, cw, _, _ = stats[k]
        if cw < min_width * w:
            continue
        comp = lab == k  # (bins, columns)
        px = obstacle & comp[b, cols]
        if px.sum() < 16:
            continue
        ys, xs = np.nonzero(px)
        y_lo, y_hi = np.percentile(ys, [1, 99])
        box = (int(xs.min()), int(y_lo), int(xs.max()), int(np.ceil(y_hi)))
        out.append(Obstacle(box, float(np.median(d[px])), int(px.sum())))
    return sorted(out, key=lambda o: -o.disparity)


def dsw_boxes(disparity: torch.Tensor, valid: torch.Tensor, baseline: float, *,
              sizes: tuple[float, ...] = (0.25, 0.5, 1.0), levels: int = 32, band: float = 0.05,
              min_fill: float = 0.6, stride: float = 0.25, top: int = 5) -> list[Obstacle]:
    """Disparity Sliding Window proposals (see the module docstring), nearest first.

    Args:
        baseline: the stereo baseline in metres (``sizes`` are metres; ``w_px = size · d / baseline``).
        sizes: metric side lengths of the square windows.
        levels: disparity levels, geometric between the 5 % and 99.5 % quantiles.
        band: a pixel belongs to level ``d`` when ``|D − d| ≤ max(1, band · d)``.
        min_fill: share of a window's pixels in the band for it to be a proposal.
        stride: window step as a share of its side.
        top: proposals returned (non-overlapping seeds, nearest first).

    Shape:
        ``disparity``, ``valid`` ``(H, W)``.
    """
    if not baseline > 0:
        raise ValueError(f"baseline must be > 0 metres; got {baseline!r}")
    d, v = map_arrays(disparity, valid)
    h, w = d.shape
    lo, hi = np.percentile(d[v], [5, 99.5])
    lo = max(lo, 1e-3)
    used = np.zeros((h, w), dtype=bool)
    out: list[Obstacle] = []
    for level in np.geomspace(hi, lo, levels) if hi > lo else [hi]:  # nearest first
        tol = max(1.0, band * level)
        m = v & (np.abs(d - level) <= tol)
        if m.sum() < 16:
            continue
        ii = cv2.integral(m.astype(np.uint8), sdepth=cv2.CV_32S)
        seed = None
        for s in sizes:
            side = int(round(s * level / baseline))
            if side < 8 or side > min(h, w):
                continue
            step = max(1, int(side * stride))
            y = np.arange(0, h - side + 1, step)
            x = np.arange(0, w - side + 1, step)
            fill = (ii[y[:, None] + side, x[None] + side] - ii[y[:, None], x[None] + side]
                    - ii[y[:, None] + side, x[None]] + ii[y[:, None], x[None]]) / float(side * side)
            k = int(fill.argmax())
            if fill.flat[k] >= min_fill:
                yy, xx = divmod(k, len(x))
                seed = (int(y[yy]), int(x[xx]), side)
                break
        if seed is None:
            continue
        y0, x0, side = seed
        n, lab = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
        ids = np.unique(lab[y0:y0 + side, x0:x0 + side][m[y0:y0 + side, x0:x0 + side]])
        px = np.isin(lab, ids[ids > 0]) & ~used
        if px.sum() < 16:
            continue
        ys, xs = np.nonzero(px)
        q = np.percentile(ys, [0.5, 99.5]), np.percentile(xs, [0.5, 99.5])
        box = (int(q[1][0]), int(q[0][0]), int(np.ceil(q[1][1])), int(np.ceil(q[0][1])))
        used |= px
        out.append(Obstacle(box, float(np.median(d[px])), int(px.sum())))
        if len(out) == top:
            break
    return out


def _uv_disparity(disparity: torch.Tensor, valid: torch.Tensor, camera: object = None) -> list[Obstacle]:
    return sorted(uv_disparity_boxes(disparity, valid), key=lambda o: -o.pixels * o.disparity)


def _dsw(disparity: torch.Tensor, valid: torch.Tensor, camera: object = None) -> list[Obstacle]:
    return dsw_boxes(disparity, valid, camera.baseline_m)  # type: ignore[union-attr]


register_task_baseline("uv_disparity", _uv_disparity)
register_task_baseline("dsw", _dsw, needs_camera=True)
