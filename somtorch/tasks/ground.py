"""Ground-plane detection in disparity space.

For a pinhole stereo camera a plane of the scene is a plane in (x, y, d): ``d = a·x + b·y + c``. The
supporting floor or road is the plane whose disparity grows towards the bottom of the image
(``b > 0``: nearer at the bottom) and whose points fill the lower part of the image. It usually holds
the largest disparities of the map, so the paper's "nearest area" rule picks it instead of the
object standing on it. :func:`fit_ground_plane` finds it with RANSAC on a subsample of the lower
image half and refines it by least squares on the inliers; a plane that does not look like ground
(too flat in y, tilted more in x than in y, too few inliers, the scene behind it, or filling the
top of the image) is rejected and None returned. Those tests are constraints of the RANSAC model:
estimated on a sample of the whole map for every hypothesis, so the best plane that satisfies
them is found instead of the best plane being refused (which made the verdict on a real floor
near a threshold depend on the seed).

That is the ``"position"`` rule (``GroundConfig.rule``): it recognises a floor by where a forward
camera sees it. The ``"support"`` rule recognises it by what it supports, at any camera pitch — a
floor filling the frame of a camera looking down, a table top, a slope: RANSAC on the whole map, no
test of orientation or image position; the plane must hold ``support_frac`` of the valid pixels,
or ``support_frac`` of the view's rim (:func:`view_rim`) with nothing substantial behind it: a floor
seen from above surrounds the things on it, so it holds most of the rim however much of the view
they fill. The position rule also wants nothing substantial behind the plane (``max_below_frac``: a
floor hides what lies beneath it); a plane verified by its share of the pixels need not pass that
test (a table top holding most of the view has the floor beyond its edges behind it).
``"either"`` accepts a plane that passes one of the two (RANSAC on the lower half, as the position
rule).

The band is ``noise_band`` × the map's per-pixel noise (read by neighbour differences), at least
``tol_px`` and ``tol_frac`` of its range. A support plane's band is also ``noise_band`` × the spread
of its own pixels about it where that is wider and resolved
(:func:`~somtorch.tasks.support_surface.own_band`): a dense sensor filters its map, so its error is
correlated across pixels and neighbour differences read a fraction of it. A dense sensor's
calibration residue bends its floor by a fraction of a pixel towards the corners, so a plane's band
misses the floor's rim: the support may be a **bent** surface
(:func:`~somtorch.tasks.support_surface.own_surface`), taken where it passes a support test no
plane passes (any, where none passes; the rim test, where the plane passed by its share of the
pixels alone). It is reported as :attr:`GroundPlane.bend`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..config import GroundConfig
from ..core.plane_counts import plane_band, plane_counts, surface_band
from ..validation import check_tensor
from .support_surface import own_band, own_surface, plane_fit, surface_map


@dataclass
class GroundPlane:
    """A fitted ground plane ``d = a·x + b·y + c`` and its inlier mask ``(H, W)``; ``support``: the
    support test verified it (rules ``"support"`` and ``"either"``), not only the position test;
    ``rim_frac``: the share of the view's rim (:func:`view_rim`) in its band (None: not measured);
    ``bend``: ``(e, f, g)`` of a bent support ``d = a·x + b·y + c + e·x² + f·x·y + g·y²``
    (:func:`~somtorch.tasks.support_surface.own_surface`; zeros for a plane)."""

    a: float
    b: float
    c: float
    tol: float
    mask: torch.Tensor
    inlier_frac: float
    support: bool = False
    rim_frac: float | None = None
    bend: tuple[float, float, float] = (0.0, 0.0, 0.0)

    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def disparity(self, h: int, w: int) -> torch.Tensor:
        """The surface's disparity at every pixel ``(H, W)`` (computed once per size; do not modify it)."""
        key = (h, w, self.a, self.b, self.c, self.bend)
        if key not in self._cache:
            self._cache.clear()
            self._cache[key] = surface_map((self.a, self.b, self.c, *self.bend), h, w).float()
        return self._cache[key]

    def as_dict(self) -> dict:
        """The plane's coefficients, tolerance, inlier share, share of the view's rim and support
        flag as a dict (for ``metrics.json``)."""
        return {"a": self.a, "b": self.b, "c": self.c, "tol": self.tol, "inlier_frac": self.inlier_frac,
                "rim_frac": self.rim_frac, "support": self.support, "bend": list(self.bend)}


def fit_ground_plane(disparity: torch.Tensor, valid: torch.Tensor, cfg: GroundConfig | None = None, *,
                     seed: int = 0, sigma: float | None = None) -> GroundPlane | None:
    """Find the ground plane of a disparity map, or None if there is none (see the module docstring).

    ``seed``: RANSAC's own seed. The pipeline keeps 0: the plane is a property of the map, the
    same for every SOM seed and every member of an ensemble; tests vary it to check that the
    plane found does not depend on the draw. ``sigma``: :func:`noise_sigma` of the map's valid
    pixels where the caller has measured it already (the pipeline's median trigger), else measured
    here.

    Shape:
        ``disparity``, ``valid``: ``(H, W)``.
    """
    cfg = cfg or GroundConfig()
    check_tensor("disparity", disparity, ndim=2, floating=True)
    check_tensor("valid", valid, ndim=2, dtype=torch.bool)
    if cfg.rule == "none":
        return None
    h, w = disparity.shape
    ok = valid & torch.isfinite(disparity)
    n_valid = int(ok.sum())
    if n_valid < 10:
        return None
    yx_ok = ok.nonzero()  # the valid pixels in row-major order, as disparity[ok] lists them
    if n_valid > 20_000:  # a sample of disparity[ok], read at its pixels rather than gathered whole
        pick = yx_ok[torch.randint(n_valid, (20_000,), generator=torch.Generator().manual_seed(seed))]
        dv = disparity[pick[:, 0], pick[:, 1]].double()
    else:
        dv = disparity[ok].double()
    m = dv.numel()
    lo_q = dv.kthvalue(max(1, int(0.01 * m))).values
    hi_q = dv.kthvalue(max(1, int(0.99 * m))).values
    span = max(float(hi_q - lo_q), 1e-9)  # robust disparity range (outliers of SGBM maps ignored)
    if cfg.noise_band > 0:
        s = noise_sigma(disparity, ok) if sigma is None else sigma
        # a map stored in steps of q px (integer, 8-bit) is a flight of flat terraces: its pixels
        # lie up to q/2 off any plane through them, a uniform error of variance q²/12 that the
        # neighbour differences (0 on a terrace) do not see
        noise = cfg.noise_band * math.sqrt(s * s + quantum(dv) ** 2 / 12.0)
    else:
        noise = 0.0
    if noise > 0.5 * span:  # neighbours differ as much as the whole map: noise, no surface to fit
        noise = 0.0  # (a band of half the range would hold most pixels of any map)
    tol = max(cfg.tol_px, cfg.tol_frac * span, noise)
    g = torch.Generator().manual_seed(seed)
    lower = ok.clone()
    if cfg.rule != "support":  # where a forward camera sees its floor
        lower[: h // 2] = False
    yx = lower.nonzero()
    if yx.shape[0] < 10:
        return None
    pts = _sample(yx, disparity, cfg.sample, g)
    # RANSAC: all hypotheses at once
    tri = torch.randint(pts.shape[0], (cfg.iterations, 3), generator=g)
    p = pts[tri]  # (I, 3, 3) rows (x, y, d)
    A = torch.cat([p[..., :2], torch.ones_like(p[..., :1])], -1)  # (I, 3, 3)
    det = torch.linalg.det(A)
    good = det.abs() > 1e-6
    if not bool(good.any()):
        return None
    coef = torch.zeros(cfg.iterations, 3, dtype=torch.float64)
    coef[good] = torch.linalg.solve(A[good], p[good][..., 2:]).squeeze(-1)  # (a, b, c)
    min_b = cfg.min_slope_frac * span / h
    oriented = (coef[:, 1] >= min_b) & (coef[:, 0].abs() <= coef[:, 1] * w / h)  # position rule
    plausible = good & oriented if cfg.rule == "position" else good
    if not bool(plausible.any()):
        return None
    # each hypothesis's residual at each sampled pixel in float32 (disparities of a few hundred px, a
    # band of at least tol_px: far above its rounding); element-wise, so the same counts at any
    # thread count, from the native kernel or torch (core.plane_counts)
    # the support-surface tests are constraints of the model, checked on a sample of the whole map
    # for every hypothesis: the best plane that passes them, not the best plane, is tested on the
    # full map (a single best hypothesis near a test's threshold made the verdict a lottery of the
    # RANSAC seed)
    q = _sample(yx_ok, disparity, cfg.sample, g)
    rim = view_rim(ok)
    on_rim = _sample(rim.nonzero(), disparity, cfg.sample, g)

    def inliers(band: float) -> torch.Tensor:
        return plane_counts(coef, pts, band, tests=False)[0].masked_fill(~plausible, -1)

    def best_plane(band: float, score: torch.Tensor) -> GroundPlane | None:
        """The best hypothesis by ``score`` (its inliers within ``band``) that passes the tests, verified."""
        score = score.masked_fill(~_passes_sampled(coef, q, on_rim, band, oriented, cfg), -1)
        best = int(torch.argmax(score))  # the first of the best: argmax returns the lowest index of ties
        if int(score[best]) < 0:
            return None
        return _verified(coef[best], pts, disparity, ok, n_valid, band, min_b, cfg, rim)

    counts = inliers(tol)
    top = coef[int(torch.argmax(counts))]  # the hypothesis with the most pixels in the band
    own = cfg.noise_band > 0 and cfg.rule != "position"  # a support surface's own band and shape

    def short_rim(plane: GroundPlane | None) -> bool:  # verified by its share of the pixels alone
        return plane is not None and plane.support and plane.rim_frac < cfg.support_frac

    def bent_support(plane: GroundPlane | None) -> GroundPlane | None:
        """The bent surface where it passes a support test that ``plane`` does not: any, where no plane
        passes; the rim's, where ``plane`` passed by its share of the pixels alone. Else None."""
        bent = own_surface(top, pts, tol, cfg.noise_band, 0.5 * span, h, w)
        if bent is None:
            return None
        curved = verify_plane(tuple(float(v) for v in bent[1]), disparity, ok, bent[0], cfg, min_b=min_b,
                              n_valid=n_valid, rim=rim)
        passes = curved is not None and curved.support
        return curved if passes and (plane is None or curved.rim_frac >= cfg.support_frac) else None

    if own:
        # a support surface whose error is correlated over many pixels (a dense sensor's filtered
        # map) differs little from its neighbours, so the noise reading above misses it: its band
        # is the spread of its own pixels about it, where that spread is resolved (own_band)
        # and the plane so banded is the verified support — or, where it misses the view's rim,
        # the bent surface that holds it (session 23: a bowl the wider band did not close)
        wide = own_band(top, pts, tol, cfg.noise_band, 0.5 * span)
        if wide > tol:
            plane = best_plane(wide, inliers(wide))
            if plane is not None and plane.support:
                return (bent_support(plane) if short_rim(plane) else None) or plane
    plane = best_plane(tol, counts)
    if own and (plane is None or short_rim(plane)):
        # no plane passes, or one passes by its share of the pixels but misses the view's rim: a dense
        # sensor's calibration residue bends its floor by a fraction of a pixel, and a plane's band
        # then misses the floor's rim (own_surface)
        return bent_support(plane) or plane
    return plane


def _sample(yx: torch.Tensor, disparity: torch.Tensor, n: int, g: torch.Generator) -> torch.Tensor:
    """``n`` of the pixels ``yx`` ``(P, 2)`` drawn with replacement by ``g``, as rows (x, y, d)
    ``(min(n, P), 3)`` float64."""
    pick = yx[torch.randint(yx.shape[0], (min(n, yx.shape[0]),), generator=g)]
    ys, xs = pick[:, 0], pick[:, 1]
    return torch.stack([xs.double(), ys.double(), disparity[ys, xs].double()], 1)


def noise_sigma(disparity: torch.Tensor, valid: torch.Tensor) -> float:
    """The map's per-pixel disparity noise in px: the median absolute deviation of the differences
    of horizontally neighbouring valid pixels, as a standard deviation (× 1.4826) of one pixel (/ √2).
    A smooth surface differs little from its neighbour (its gradient is the differences' median,
    taken out); depth edges are outliers the median ignores. Read for the pixels one and two apart,
    the larger: a map resampled from a grid half as fine (a depth map registered to a larger image)
    repeats or interpolates each value over two pixels, whose differences read a fraction of its
    noise (none where they repeat it). On every ``k``-th row, ``k`` chosen for at most about half a
    million pairs.

    Shape:
        ``disparity``, ``valid`` ``(H, W)``.
    """
    h, w = disparity.shape
    k = max(1, -(-(h * w) // 500_000))  # rounded up: at most half a million pixels read
    d, v = disparity[::k].cpu().numpy(), valid[::k].cpu().numpy()
    sigma = 0.0
    for lag in (1, 2):
        both = v[:, :-lag] & v[:, lag:]
        with np.errstate(invalid="ignore", over="ignore"):  # inf - inf: NaN, as torch has it, silently
            diff = (d[:, lag:] - d[:, :-lag])[both].astype(np.float64)  # in the map's dtype, then widened
        if diff.size < 10:
            continue
        with np.errstate(invalid="ignore"):
            mad = _median(np.abs(diff - _median(diff)))
        sigma = max(sigma, float(1.4826 * mad / math.sqrt(2.0)))
    return sigma


def _median(x: np.ndarray) -> float:
    """torch's median of a 1-D float64 array: the lower of the two middle values where their number
    is even, NaN where there is one; by numpy's partial sort, 2–4× faster than ``torch.median`` on
    the half a million differences :func:`noise_sigma` reads. Partial sorting slows down on many
    equal values, and a map's neighbour differences are mostly exact zeros (a flat or stored-in-steps
    surface), so the zeros are counted and only the values on the median's side of them sorted."""
    if not np.isfinite(x).all():
        return float(torch.from_numpy(x).median())  # NaN propagates as torch has it; ±inf sorted alike
    k = (x.size - 1) // 2
    below = x < 0
    n_below = int(np.count_nonzero(below))
    if k < n_below:
        part = x[below]
    else:
        n_zero = int(np.count_nonzero(x == 0))
        if k < n_below + n_zero:
            return 0.0  # (a zero's sign reaches no reading: it is subtracted, then taken absolute)
        part, k = x[x > 0], k - n_below - n_zero
    return float(np.partition(part, k)[k])


def quantum(values: torch.Tensor) -> float:
    """The step in px of the grid a map's disparities ``values`` (1-D: its valid pixels or a sample
    of them) are stored on: the smallest gap between distinct values, where every distinct value
    lies on that grid (within 0.1 % of a step) — 1 for an integer map, 1/16 for OpenCV's SGBM, up
    to 1/3 for a third-size Middlebury 2005/2006 ground truth, a float's resolution for a
    floating-point map — else 0 (a few flat surfaces at unrelated disparities are no grid, nor are
    values a float32 rounding puts one unit apart; nor are fewer than two distinct values)."""
    u = torch.unique(values.double())
    if u.numel() < 2:
        return 0.0
    q = float((u[1:] - u[:-1]).min())
    steps = (u - u[0]) / q
    return q if bool(((steps - steps.round()).abs() <= 1e-3).all()) else 0.0


def _passes_sampled(coef: torch.Tensor, q: torch.Tensor, rim: torch.Tensor, tol: float,
                    oriented: torch.Tensor, cfg: GroundConfig) -> torch.Tensor:
    """Which hypotheses ``coef`` ``(I, 3)`` pass the tests of ``cfg.rule`` on the sample ``q``
    ``(N, 3)`` rows (x, y, d) of the whole map and ``rim`` ``(M, 3)`` of the view's rim (the
    full-map tests of :func:`_verified`, estimated).
    ``oriented`` ``(I,)``: the hypotheses that pass the position rule's orientation test."""
    n_in, n_seen, n_behind = plane_counts(coef, q, tol)
    # shares in float32, count / N: the bits of the mean of the (I, N) 0 / 1 comparisons
    share = n_in.float() / q.shape[0]
    on_rim = plane_counts(coef, rim, tol, tests=False)[0].float() / rim.shape[0]
    ok = share >= cfg.min_inlier_frac
    hides = n_behind <= cfg.max_below_frac * n_seen.clamp_min(1)  # a floor hides what lies beneath
    surrounds = (on_rim >= cfg.support_frac) & hides
    return ok & _either(cfg.rule, oriented & hides, (share >= cfg.support_frac) | surrounds)


def view_rim(ok: torch.Tensor) -> torch.Tensor:
    """The rim of the view ``(H, W)`` bool: the first and last valid pixel of every row and of every
    column of ``ok`` (where the map's view ends: an SGBM map's invalid margin does not count)."""
    h, w = ok.shape
    rim = torch.zeros_like(ok)
    rows = ok.any(1).nonzero().squeeze(1)
    cols = ok.any(0).nonzero().squeeze(1)
    rim[rows, ok.int().argmax(1)[rows]] = True
    rim[rows, w - 1 - ok.flip(1).int().argmax(1)[rows]] = True
    rim[ok.int().argmax(0)[cols], cols] = True
    rim[h - 1 - ok.flip(0).int().argmax(0)[cols], cols] = True
    return rim


def _either(rule: str, position, support):
    """The verdict of ``rule`` from the position and support verdicts (bools or bool tensors)."""
    return position if rule == "position" else support if rule == "support" else position | support


def _verified(best: torch.Tensor, pts: torch.Tensor, disparity: torch.Tensor, ok: torch.Tensor, n_valid: int,
              tol: float, min_b: float, cfg: GroundConfig, rim: torch.Tensor) -> GroundPlane | None:
    """Hypothesis ``best`` refined by least squares on its inliers among ``pts`` and tested on the
    full map (:func:`verify_plane`) — inlier share and scene behind it for every rule; slope and
    tilt (position rule); share of the pixels or of the rim (support rule) — or None."""
    # refine by least squares on the inliers of the sampled pixels, then recompute on the full map
    inl = (best[0] * pts[:, 0] + best[1] * pts[:, 1] + best[2] - pts[:, 2]).abs() < tol
    if int(inl.sum()) >= 3:
        best = plane_fit(pts[inl])
    return verify_plane(tuple(float(v) for v in best), disparity, ok, tol, cfg, min_b=min_b, n_valid=n_valid,
                        rim=rim)


def verify_plane(coef: tuple[float, ...], disparity: torch.Tensor, ok: torch.Tensor, tol: float,
                 cfg: GroundConfig, *, min_b: float = 0.0, n_valid: int | None = None,
                 rim: torch.Tensor | None = None) -> GroundPlane | None:
    """The plane ``d = a·x + b·y + c`` (``coef`` = (a, b, c); a bent surface: (a, b, c, e, f, g),
    :func:`~somtorch.tasks.support_surface.own_surface`) with band ``tol`` px as a
    :class:`GroundPlane` if it passes the tests of ``cfg.rule`` on the map (see the module docstring;
    ``min_b``: the position rule's least ``b``; ``rim``: :func:`view_rim` of ``ok`` where the caller
    has it), else None.

    Shape:
        ``disparity``, ``ok`` (valid, finite pixels), ``rim`` ``(H, W)``.
    """
    if n_valid is None:  # a call from outside: check the inputs once
        check_tensor("disparity", disparity, ndim=2, floating=True)
        check_tensor("ok", ok, ndim=2, dtype=torch.bool)
        n_valid = max(int(ok.sum()), 1)
    h, w = disparity.shape
    a, b, c = coef[:3]
    bend = tuple(coef[3:]) if len(coef) > 3 else (0.0, 0.0, 0.0)
    position = b >= min_b and abs(a) <= b * w / h
    if cfg.rule == "position" and not position:
        return None
    # its band, and where it is in view and what lies behind it (a plane: in one native pass)
    if any(bend):  # a bent support surface
        mask, n_in, n_seen, n_behind = surface_band(surface_map((a, b, c, *bend), h, w), disparity, ok, tol)
    else:
        mask, n_in, n_seen, n_behind = plane_band((a, b, c), disparity, ok, tol)
    frac = n_in / n_valid
    if frac < cfg.min_inlier_frac:
        return None
    hides = n_behind <= cfg.max_below_frac * max(n_seen, 1)
    position = position and hides
    rim_frac = rim_share(mask, view_rim(ok) if rim is None else rim)
    # a floor seen from above surrounds what it supports: it holds most of the view's rim
    surrounds = hides and rim_frac >= cfg.support_frac
    support = cfg.rule != "position" and (frac >= cfg.support_frac or surrounds)
    if not _either(cfg.rule, position, support):
        return None
    return GroundPlane(a, b, c, tol, mask, frac, support, rim_frac, bend)


def rim_share(mask: torch.Tensor, rim: torch.Tensor) -> float:
    """The share of the view's rim (``rim``: :func:`view_rim` of the valid pixels) that ``mask``
    holds (0 without a rim). Shape: ``mask``, ``rim`` ``(H, W)``."""
    return int((mask & rim).sum()) / max(int(rim.sum()), 1)
