"""A support surface fitted to its own pixels: planes and bent (quadratic) surfaces in (x, y, d),
and the band that the spread of their pixels sets (used by :mod:`somtorch.tasks.ground`).

A dense sensor filters its map, so its error is correlated across pixels: neighbour differences
read a fraction of it, and a plane's band is better set by the spread of the plane's own pixels
about it (:func:`own_band`). Its calibration residue bends its floor by a fraction of a pixel
towards the corners: a quadratic surface holds such a floor where no plane does
(:func:`own_surface`). Both stop where the band would pass the object step's depth-continuity
step: they have found a run of surfaces, not one surface's error.
"""

from __future__ import annotations

import math

import torch

from ..config.objects import CONTINUITY_STEP_FRAC, CONTINUITY_STEP_PX


#: :func:`own_band` stops when a round widens the band by less than this share (a numerical
#: tolerance: the band converges geometrically) …
OWN_BAND_RTOL = 0.01
#: … or after this many rounds.
OWN_BAND_ROUNDS = 50


def own_band(coef: torch.Tensor, pts: torch.Tensor, tol: float, k: float, cap: float) -> float:
    """The band of the plane ``coef`` = (a, b, c) that holds its own pixels among ``pts`` ``(N, 3)``
    rows (x, y, d): ``k`` × their spread about it, at least ``tol``.

    The plane is refitted by least squares on the pixels within the band, and the band set to ``k``
    × the standard deviation of their residuals, corrected for the truncation at ± the band (a normal
    error truncated at ± k σ has the standard deviation ``truncated_sd(k)`` σ); repeated while the
    band grows. A surface whose error is a peak of width σ converges at k σ (a per-pixel error,
    however correlated across pixels, or a smooth distortion of the map). A band that would pass the
    object step's depth-continuity step at the median disparity of its pixels
    (``max(CONTINUITY_STEP_PX, CONTINUITY_STEP_FRAC · d)``: what the method calls a depth edge)
    or ``cap`` has found no peak but a run of surfaces (the objects on the plane, a room): ``tol``
    is returned.
    """
    band, _, end = _own_rounds(coef, pts, tol, k, cap, plane_fit, 3)
    return tol if end == "run" else band


def _own_rounds(coef: torch.Tensor, pts: torch.Tensor, tol: float, k: float, cap: float, fit,
                n_min: int) -> tuple[float, torch.Tensor, str]:
    """The rounds of :func:`own_band` and :func:`own_surface` from the surface ``coef``
    (:func:`surface_at`), refitted by ``fit`` on the pixels of ``pts`` within the band: (band, its
    surface, how it ended: ``"peak"`` converged, ``"run"`` past the continuity step or ``cap``,
    ``"few"`` under ``n_min`` pixels in the band)."""
    ratio = truncated_sd(k)
    band = tol
    for _ in range(OWN_BAND_ROUNDS):
        inside = (pts[:, 2] - surface_at(coef, pts[:, 0], pts[:, 1])).abs() < band
        if int(inside.sum()) < n_min:
            return band, coef, "few"
        coef = fit(pts[inside])
        r = pts[:, 2] - surface_at(coef, pts[:, 0], pts[:, 1])
        inside = r.abs() < band
        if int(inside.sum()) < n_min:
            return band, coef, "few"
        wider = max(tol, k * float(r[inside].std()) / ratio)
        step = max(CONTINUITY_STEP_PX, CONTINUITY_STEP_FRAC * float(pts[inside, 2].median()))
        if wider > min(cap, step):
            return band, coef, "run"
        if wider <= band * (1.0 + OWN_BAND_RTOL):
            break
        band = wider
    return band, coef, "peak"


def truncated_sd(k: float) -> float:
    """The standard deviation of a standard normal truncated to [−k, k] (k > 0)."""
    phi = math.exp(-0.5 * k * k) / math.sqrt(2.0 * math.pi)
    return math.sqrt(1.0 - 2.0 * k * phi / math.erf(k / math.sqrt(2.0)))


def own_surface(coef: torch.Tensor, pts: torch.Tensor, tol: float, k: float, cap: float, h: int,
                w: int) -> tuple[float, torch.Tensor] | None:
    """The bent surface ``d = a·x + b·y + c + e·x² + f·x·y + g·y²`` that holds the pixels of the plane
    ``coef`` = (a, b, c) among ``pts`` ``(N, 3)`` rows (x, y, d) of an ``(h, w)`` map, and its band:
    ``(band, (a, b, c, e, f, g))``, or None.

    The rounds of :func:`own_band`, with the quadratic surface refitted on the pixels within the band
    in place of the plane. None where the band would pass the depth-continuity step or ``cap`` (no
    peak: a run of surfaces), or where the surface departs from the plane nearest its pixels by more
    than the continuity step at their median disparity: a floor bent by its sensor's calibration
    departs by a fraction of a pixel, a dome or a ramp of steps by a depth edge.
    """
    coef = torch.cat([coef.double(), torch.zeros(3, dtype=torch.float64)])
    try:
        band, coef, end = _own_rounds(coef, pts, tol, k, cap, lambda p: _surface_fit(p, h, w), 6)
        if end != "peak":
            return None
        inside = (pts[:, 2] - surface_at(coef, pts[:, 0], pts[:, 1])).abs() < band
        if int(inside.sum()) < 6:
            return None
        flat = plane_fit(pts[inside])
    except torch.linalg.LinAlgError:  # pixels on a few lines (a map of columns): no surface to fit
        return None
    x, y = pts[inside, 0], pts[inside, 1]
    bend = (surface_at(coef, x, y) - surface_at(flat, x, y)).abs()
    step = max(CONTINUITY_STEP_PX, CONTINUITY_STEP_FRAC * float(pts[inside, 2].median()))
    return None if float(bend.max()) > step else (band, coef)


def surface_at(coef: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``d = a·x + b·y + c + e·x² + f·x·y + g·y²`` at ``x``, ``y`` (float64); ``coef`` = (a, b, c) or
    (a, b, c, e, f, g)."""
    x, y = x.double(), y.double()
    d = coef[0] * x + coef[1] * y + coef[2]
    if len(coef) > 3:
        d = d + coef[3] * x * x + coef[4] * x * y + coef[5] * y * y
    return d


def surface_map(coef, h: int, w: int) -> torch.Tensor:
    """The surface ``coef`` (:func:`surface_at`) at every pixel of an ``(H, W)`` map, float64."""
    ys = torch.arange(h, dtype=torch.float64)[:, None]
    xs = torch.arange(w, dtype=torch.float64)[None, :]
    coef = tuple(coef) if any(coef[3:]) else tuple(coef[:3])  # a plane: no quadratic terms to add
    return surface_at(torch.tensor(coef, dtype=torch.float64), xs, ys)


def _surface_fit(pts: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """Least-squares (a, b, c, e, f, g) of :func:`surface_at` through ``pts`` ``(N, 3)`` rows (x, y, d)
    (:func:`_normal_solve`, in coordinates scaled to the map: x / w, y / h)."""
    u, v, d = pts[:, 0].double() / w, pts[:, 1].double() / h, pts[:, 2].double()
    beta = _normal_solve((u, v, torch.ones_like(u), u * u, u * v, v * v), d)
    return beta / torch.tensor([w, h, 1.0, w * w, w * h, h * h], dtype=torch.float64)


def plane_fit(pts: torch.Tensor) -> torch.Tensor:
    """Least-squares ``(a, b, c)`` of ``d = a·x + b·y + c`` through ``pts`` ``(N, 3)`` rows (x, y, d)
    (:func:`_normal_solve`)."""
    x, y, d = pts[:, 0].double(), pts[:, 1].double(), pts[:, 2].double()
    return _normal_solve((x, y, torch.ones_like(x)), d)


def _normal_solve(cols: tuple[torch.Tensor, ...], d: torch.Tensor) -> torch.Tensor:
    """The least-squares coefficients of ``d`` on the columns ``cols``, by the normal equations from
    element-wise float64 sums: the same bits on every run (``torch.linalg.lstsq`` differed in the
    last digits between identical runs). Raises ``torch.linalg.LinAlgError`` where they are singular."""
    ata = torch.tensor([[float((u * v).sum()) for v in cols] for u in cols], dtype=torch.float64)
    atb = torch.tensor([float((u * d).sum()) for u in cols], dtype=torch.float64)
    return torch.linalg.solve(ata, atb)
