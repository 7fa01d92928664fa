"""The ``plane_components`` baseline of issue 31: the support plane, then depth-connected components.

Deterministic, classical, no SOM:

1. **Support plane.** The dominant plane ``d = a·x + b·y + c`` of the valid pixels in (x, y, d),
   found by RANSAC (under a pinhole camera a 3-D plane is a plane in disparity space), with the band
   ``|d − plane| ≤ max(band_px, band_frac · median d)``. Its pixels are removed only if the plane
   holds at least ``plane_min_share`` of the valid pixels.
2. **Components.** The rest is split into 4-connected components: two neighbours are connected when
   ``|Δd| ≤ max(step_px, step_frac · d)`` (``d`` the mean of the pair).
3. Components under ``min_share`` of the valid pixels are dropped.
4. The rest are ranked by pixels × median disparity (the largest near thing first); each becomes an
   :class:`~somtorch.tasks.baselines.registry.Obstacle` whose box is its pixels' extent (the
   runners add the reduction's tolerance, as for every baseline).

Where the best component spans the whole valid extent of the map (one component covering
everything: a smooth quantised depth map, a scene of one surface), it cannot point at anything: the
result is empty and the runners keep the whole map, flagged ``no_object``.

:func:`plane_components_o3d_boxes` is the route a robotics user tries first where the scene has a
metric camera: Open3D's ``segment_plane`` and ``cluster_dbscan`` on the metric point cloud, with
thresholds converted from the same constants at the median depth. It is registered as
``plane_components_o3d`` (needs a metric camera and Open3D). The default, ``plane_components``, is
the (x, y, d) route: it needs no calibration (synthetic and 8-bit depth scenes have none), no
optional dependency, and it is the rule whose figures the issue reports.

The constants are the issue's (:class:`PlaneComponentsParams`), not tuned on the corpus.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ...config.objects import CONTINUITY_STEP_FRAC, CONTINUITY_STEP_PX
from .registry import Obstacle, map_arrays, register_task_baseline

__all__ = ["PlaneComponentsParams", "plane_components_boxes", "plane_components_o3d_boxes", "support_plane"]


@dataclass(frozen=True)
class PlaneComponentsParams:
    """The constants of the ``plane_components`` baselines (issue 31, item 1).

    Attributes:
        plane_min_share: the plane is removed only if it holds at least this share of the valid pixels.
        band_px: the plane's band is ``max(band_px, band_frac · median disparity)`` px ...
        band_frac: ... (see ``band_px``).
        step_px: 4-neighbours are connected when ``|Δd| ≤ max(step_px, step_frac · d)`` ...
        step_frac: ... (see ``step_px``).
        min_share: components under this share of the valid pixels are dropped.
        ransac_iters: RANSAC hypotheses (3 pixels each).
        ransac_sample: pixels the hypotheses are counted on (a fixed subsample; the winner is refit and
            counted on all pixels).
        seed: RANSAC's sampling seed (the baseline is deterministic).
        dbscan_min_points: ``cluster_dbscan``'s ``min_points`` (Open3D route only).
        max_points: the Open3D route clusters at most this many points (a regular pixel stride).
    """

    plane_min_share: float = 0.20
    band_px: float = 0.5
    band_frac: float = 0.01
    step_px: float = CONTINUITY_STEP_PX  # the object step's depth-continuity rule is this one
    step_frac: float = CONTINUITY_STEP_FRAC
    min_share: float = 0.005
    ransac_iters: int = 256
    ransac_sample: int = 20_000
    seed: int = 0
    dbscan_min_points: int = 10
    max_points: int = 60_000


DEFAULT = PlaneComponentsParams()


def support_plane(d: np.ndarray, v: np.ndarray, params: PlaneComponentsParams = DEFAULT
                  ) -> tuple[np.ndarray | None, tuple[float, float, float] | None]:
    """The support plane's pixels and coefficients ``(a, b, c)`` of ``d = a·x + b·y + c``, or ``(None,
    None)`` where the best plane holds under ``plane_min_share`` of the valid pixels.

    Shape:
        ``d`` float ``(H, W)``, ``v`` bool ``(H, W)``; the mask ``(H, W)``.
    """
    h, w = d.shape
    ys, xs = np.nonzero(v)
    dv = d[ys, xs]
    n = len(dv)
    band = max(params.band_px, params.band_frac * float(np.median(dv)))
    rng = np.random.default_rng(params.seed)
    sub = rng.choice(n, size=min(n, params.ransac_sample), replace=False)
    pts = rng.integers(0, n, size=(params.ransac_iters, 3))
    a_mat = np.stack([xs[pts], ys[pts], np.ones_like(pts)], axis=-1).astype(np.float64)  # (I, 3, 3)
    ok = np.abs(np.linalg.det(a_mat)) > 1e-6  # three pixels on a line in the image give no plane
    if not ok.any():
        return None, None
    coef = np.linalg.solve(a_mat[ok], dv[pts[ok]][..., None])[..., 0]  # (I', 3)
    pred = coef[:, :1] * xs[sub] + coef[:, 1:2] * ys[sub] + coef[:, 2:]  # (I', S)
    counts = (np.abs(pred - dv[sub]) <= band).sum(axis=1)
    best = coef[int(counts.argmax())]  # the first of equal counts: deterministic
    inl = np.abs(best[0] * xs + best[1] * ys + best[2] - dv) <= band
    if inl.sum() >= 3:  # refit on every inlier, then count again on all pixels
        lsq = np.linalg.lstsq(np.stack([xs[inl], ys[inl], np.ones(int(inl.sum()))], axis=1).astype(np.float64),
                              dv[inl], rcond=None)[0]
        refit = np.abs(lsq[0] * xs + lsq[1] * ys + lsq[2] - dv) <= band
        if refit.sum() >= inl.sum():
            best, inl = lsq, refit
    if inl.sum() < params.plane_min_share * n:
        return None, None
    mask = np.zeros((h, w), dtype=bool)
    mask[ys[inl], xs[inl]] = True
    return mask, (float(best[0]), float(best[1]), float(best[2]))


def _components(d: np.ndarray, m: np.ndarray, params: PlaneComponentsParams) -> np.ndarray:
    """Labels ``(H, W)`` of the 4-connected components of ``m`` under the |Δd| rule; −1 outside ``m``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h, w = d.shape
    idx = np.arange(h * w).reshape(h, w)
    edges = []
    for a, b in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),  # right neighbour
                 ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):  # lower neighbour
        da, db = d[a], d[b]
        keep = m[a] & m[b] & (np.abs(da - db) <= np.maximum(params.step_px, params.step_frac * 0.5 * (da + db)))
        edges.append((idx[a][keep], idx[b][keep]))
    src = np.concatenate([e[0] for e in edges])
    dst = np.concatenate([e[1] for e in edges])
    graph = coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(h * w, h * w))
    _, lab = connected_components(graph, directed=False)
    lab = lab.reshape(h, w).astype(np.int64)
    lab[~m] = -1
    return lab


def _ranked(d: np.ndarray, lab: np.ndarray, n_valid: int, min_share: float, scale: int = 1
            ) -> list[Obstacle]:
    """The components of ``lab`` (−1 = none) of at least ``min_share · n_valid`` pixels, as obstacles
    ranked by pixels × median disparity. ``scale``: pixels each labelled pixel stands for."""
    ys, xs = np.nonzero(lab >= 0)
    ids = lab[ys, xs]
    if len(ids) == 0:
        return []
    order = np.lexsort((d[ys, xs], ids))  # by component, then by disparity
    ids_s, d_s = ids[order], d[ys, xs][order]
    uniq, start, count = np.unique(ids_s, return_index=True, return_counts=True)
    med = 0.5 * (d_s[start + (count - 1) // 2] + d_s[start + count // 2])
    big = count * scale >= min_share * n_valid
    if not big.any():
        return []
    pos = np.searchsorted(uniq, ids)
    x0 = np.full(len(uniq), lab.shape[1]); y0 = np.full(len(uniq), lab.shape[0])  # noqa: E702
    x1 = np.full(len(uniq), -1); y1 = np.full(len(uniq), -1)  # noqa: E702
    np.minimum.at(x0, pos, xs); np.minimum.at(y0, pos, ys)  # noqa: E702
    np.maximum.at(x1, pos, xs); np.maximum.at(y1, pos, ys)  # noqa: E702
    out = [Obstacle((int(x0[k]), int(y0[k]), int(x1[k]), int(y1[k])), float(med[k]), int(count[k] * scale))
           for k in np.flatnonzero(big)]
    return sorted(out, key=lambda o: -o.pixels * o.disparity)  # stable: ties keep the label order


def _unless_everything(found: list[Obstacle], v: np.ndarray) -> list[Obstacle]:
    """``found``, or [] where the best box spans the whole valid extent (it cannot point at anything)."""
    if not found:
        return found
    ys, xs = np.nonzero(v)
    return [] if found[0].box == (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())) else found


def plane_components_boxes(disparity: torch.Tensor, valid: torch.Tensor, camera: object = None, *,
                           params: PlaneComponentsParams = DEFAULT) -> list[Obstacle]:
    """The components left by the support plane, best first (see the module docstring).

    Args:
        disparity: disparity in px.
        valid: the valid pixels.
        camera: unused (the (x, y, d) route needs no calibration); taken for the registry's signature.
        params: the constants.

    Returns:
        Obstacles ranked by pixels × median disparity; [] where nothing is left after the plane and
        the size filter, or where the best component spans the whole map.

    Raises:
        TaskBaselineError: fewer than 16 valid pixels.

    Shape:
        ``disparity`` float ``(H, W)``, ``valid`` bool ``(H, W)``.
    """
    d, v = map_arrays(disparity, valid)
    plane, _ = support_plane(d, v, params)
    rest = v if plane is None else v & ~plane
    lab = _components(d, rest, params)
    return _unless_everything(_ranked(d, lab, int(v.sum()), params.min_share), v)


def plane_components_o3d_boxes(disparity: torch.Tensor, valid: torch.Tensor, camera: object = None, *,
                               params: PlaneComponentsParams = DEFAULT) -> list[Obstacle]:
    """The Open3D route: ``segment_plane`` then ``cluster_dbscan`` on the metric point cloud.

    The pixels' 3-D points (``Z = f·B / (d + doffs)``, ``X = (x − cx)·Z / f``, ``Y = (y − cy)·Z / f``,
    metres; at most ``max_points`` of them, on a regular pixel stride) are fed to Open3D. The plane's
    distance threshold and DBSCAN's ``eps`` are the (x, y, d) route's disparity tolerances converted to
    depth at the median depth ``Z_m`` (``ΔZ = Z · Δd / d``): ``Z_m · max(band_px / d_m, band_frac)`` and
    ``Z_m · max(step_px / d_m, step_frac)``. The plane is removed only if it holds ``plane_min_share``
    of the points; clusters are ranked as in :func:`plane_components_boxes`.

    Raises:
        TaskBaselineError: fewer than 16 valid pixels, or ``camera`` is not metric.
        ImportError: Open3D is not installed (the message says how to install it).

    Shape:
        ``disparity`` float ``(H, W)``, ``valid`` bool ``(H, W)``.
    """
    from somtorch._optional import optional_import

    from .registry import TaskBaselineError

    d, v = map_arrays(disparity, valid)
    base_m = getattr(camera, "baseline_m", None)
    if base_m is None:
        raise TaskBaselineError(f"plane_components_o3d needs a metric camera (baseline in m or mm); got {camera!r}")
    o3d = optional_import("open3d", hint="Open3D is needed for the plane_components_o3d baseline; "
                                         "plane_components works without it.")
    f, cx, cy, doffs = camera.focal_px, camera.cx, camera.cy, camera.doffs  # type: ignore[attr-defined]
    v = v & (d + doffs > 0)
    n_valid = int(v.sum())
    stride = max(1, int(np.ceil(np.sqrt(n_valid / params.max_points))))
    sv = np.zeros_like(v)
    sv[::stride, ::stride] = v[::stride, ::stride]
    ys, xs = np.nonzero(sv)
    z = f * base_m / (d[ys, xs] + doffs)
    pts = np.stack([(xs - cx) * z / f, (ys - cy) * z / f, z], axis=1)  # (N, 3) metres
    d_m, z_m = float(np.median(d[ys, xs])), float(np.median(z))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    o3d.utility.random.seed(params.seed)
    _, inliers = cloud.segment_plane(distance_threshold=z_m * max(params.band_px / d_m, params.band_frac),
                                     ransac_n=3, num_iterations=params.ransac_iters)
    keep = np.ones(len(pts), dtype=bool)
    if len(inliers) >= params.plane_min_share * len(pts):
        keep[np.asarray(inliers, dtype=np.int64)] = False
    rest = cloud.select_by_index(np.flatnonzero(keep).tolist())
    eps = z_m * max(params.step_px / d_m, params.step_frac)
    labels = np.asarray(rest.cluster_dbscan(eps=eps, min_points=params.dbscan_min_points), dtype=np.int64)
    lab = np.full(d.shape, -1, dtype=np.int64)
    lab[ys[keep], xs[keep]] = labels  # DBSCAN noise stays −1
    return _unless_everything(_ranked(d, lab, n_valid, params.min_share, scale=stride * stride), v)


register_task_baseline("plane_components", plane_components_boxes)
register_task_baseline("plane_components_o3d", plane_components_o3d_boxes, needs_camera=True)
