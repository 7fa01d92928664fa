"""Counts of plane hypotheses over sampled points, in the native library of
:mod:`somtorch.core.native` (``somtorch_plane_counts`` in ``csrc/bmu.cpp``): for each hypothesis
``z = a·x + b·y + c`` and each point ``(x, y, z)``, the float32 prediction as torch computes it
(the hypothesis rounded to float32, each product and sum rounded), and how many points lie within
a band of it, how many are predicted above the band, and how many of those lie beneath the band —
the counts of the ``(I, N)`` comparisons torch would materialise, without materialising them;
and one plane's band over a whole map (``somtorch_plane_band``, :func:`plane_band`): the pixels
within it and the same counts, in float64, in one pass instead of a dozen ``(H, W)`` tensors.
It knows nothing of disparity: the ground fit (:func:`somtorch.tasks.ground.fit_ground_plane`)
passes its hypotheses and sampled pixels to :func:`plane_counts` and the plane it verifies to
:func:`plane_band`, which take their torch definitions (:func:`torch_plane_counts`,
:func:`torch_plane_band`) where the kernel cannot serve.
"""

from __future__ import annotations

import torch

from .native import enabled, library

__all__ = ["native_plane_band", "native_plane_counts", "plane_band", "plane_counts", "surface_band",
           "torch_plane_band", "torch_plane_counts"]


def torch_plane_counts(coef: torch.Tensor, pts: torch.Tensor, tol: float, *, tests: bool = True
                       ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """The definition :func:`native_plane_counts` reproduces, in torch: ``(inliers, seen, behind)``
    ``(I,)`` long each (``seen`` and ``behind`` None without ``tests``) for the hypotheses ``coef``
    ``(I, 3)`` (a, b, c) over the points ``pts`` ``(N, 3)`` rows (x, y, z): ``|pred − z| < tol``,
    ``pred > tol``, and ``pred > tol`` with ``z < pred − tol``, ``pred`` and every comparison in
    float32."""
    c = coef.float()
    x, y = pts[None, :, 0].float(), pts[None, :, 1].float()
    pred = c[:, 0:1] * x + c[:, 1:2] * y + c[:, 2:3]
    z = pts[None, :, 2].float()
    inl = ((pred - z).abs() < tol).sum(1)
    if not tests:
        return inl, None, None
    seen = pred > tol
    return inl, seen.sum(1), (seen & (z < pred - tol)).sum(1)


@torch.no_grad()
def native_plane_counts(coef: torch.Tensor, pts: torch.Tensor, tol: float, *, tests: bool = True
                        ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None] | None:
    """:func:`torch_plane_counts` in one native pass (single-threaded; 400 hypotheses × 5,000 points
    in a few milliseconds), the same integers; None where the kernel cannot serve the call
    (``SOMTORCH_NATIVE=0``, no library, tensors off the CPU or of other shapes).

    Shape:
        ``coef`` ``(I, 3)``; ``pts`` ``(N, 3)``.
    """
    if not enabled() or coef.device.type != "cpu" or pts.device.type != "cpu" or coef.ndim != 2 \
            or coef.shape[1] != 3 or pts.ndim != 2 or pts.shape[1] != 3:
        return None
    lib = library()
    if lib is None:
        return None
    i, n = int(coef.shape[0]), int(pts.shape[0])
    cf = coef.double().contiguous()
    xs, ys, zs = (pts[:, k].float().contiguous() for k in range(3))
    inl = torch.zeros(i, dtype=torch.long)
    seen = torch.zeros(i, dtype=torch.long) if tests else None
    behind = torch.zeros(i, dtype=torch.long) if tests else None
    rc = lib.somtorch_plane_counts(cf.data_ptr(), i, xs.data_ptr(), ys.data_ptr(), zs.data_ptr(), n,
                                   float(torch.tensor(tol, dtype=torch.float32)), inl.data_ptr(),
                                   None if seen is None else seen.data_ptr(),
                                   None if behind is None else behind.data_ptr())
    return (inl, seen, behind) if rc == 0 else None


def plane_counts(coef: torch.Tensor, pts: torch.Tensor, tol: float, *, tests: bool = True
                 ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """:func:`native_plane_counts` where the kernel serves the call, else :func:`torch_plane_counts`:
    the same integers either way."""
    got = native_plane_counts(coef, pts, tol, tests=tests)
    return got if got is not None else torch_plane_counts(coef, pts, tol, tests=tests)


def torch_plane_band(coef: tuple[float, float, float], z: torch.Tensor, ok: torch.Tensor, tol: float
                     ) -> tuple[torch.Tensor, int, int, int]:
    """The definition :func:`native_plane_band` reproduces, in torch: for the plane
    ``p = a·x + b·y + c`` (``coef``; x the column, y the row) over the map ``z``, in float64,
    ``(band, inliers, seen, behind)``: the ``(H, W)`` bool mask ``ok & (|p − z| < tol)`` and its
    count, the count of ``ok & (p > tol)``, and of those the pixels with ``z < p − tol``."""
    h, w = z.shape
    ys = torch.arange(h, dtype=torch.float64)[:, None]
    xs = torch.arange(w, dtype=torch.float64)[None, :]
    cf = torch.tensor(coef, dtype=torch.float64)
    return surface_band(cf[0] * xs + cf[1] * ys + cf[2], z, ok, tol)


def surface_band(surface: torch.Tensor, z: torch.Tensor, ok: torch.Tensor, tol: float
                 ) -> tuple[torch.Tensor, int, int, int]:
    """:func:`torch_plane_band` for any surface given at every pixel (``surface`` ``(H, W)``
    float64: a plane, or a bent one), the map ``z`` widened to float64."""
    d = z.double()
    band = ok & ((surface - d).abs() < tol)
    seen = ok & (surface > tol)
    return band, int(band.sum()), int(seen.sum()), int((seen & (d < surface - tol)).sum())


@torch.no_grad()
def native_plane_band(coef: tuple[float, float, float], z: torch.Tensor, ok: torch.Tensor, tol: float
                      ) -> tuple[torch.Tensor, int, int, int] | None:
    """:func:`torch_plane_band` in one native pass over the map (rows split over torch's threads;
    the same mask and integers), or None where the kernel cannot serve the call
    (``SOMTORCH_NATIVE=0``, no library, tensors off the CPU or not a float32 map and a bool mask of
    one ``(H, W)`` shape).

    Shape:
        ``z``, ``ok`` ``(H, W)``.
    """
    if not enabled() or z.device.type != "cpu" or ok.device.type != "cpu" or z.ndim != 2 \
            or z.dtype != torch.float32 or ok.dtype != torch.bool or ok.shape != z.shape:
        return None
    lib = library()
    if lib is None:
        return None
    h, w = z.shape
    cf = torch.tensor([float(v) for v in coef[:3]], dtype=torch.float64)
    zc, okc = z.contiguous(), ok.contiguous()
    band = torch.empty(h, w, dtype=torch.bool)
    counts = torch.zeros(3, dtype=torch.long)
    rc = lib.somtorch_plane_band(cf.data_ptr(), zc.data_ptr(), okc.data_ptr(), h, w, float(tol),
                                 band.data_ptr(), counts.data_ptr(), torch.get_num_threads())
    if rc != 0:
        return None
    n_in, n_seen, n_behind = counts.tolist()
    return band, n_in, n_seen, n_behind


def plane_band(coef: tuple[float, float, float], z: torch.Tensor, ok: torch.Tensor, tol: float
               ) -> tuple[torch.Tensor, int, int, int]:
    """:func:`native_plane_band` where the kernel serves the call, else :func:`torch_plane_band`:
    the same mask and integers either way."""
    got = native_plane_band(coef, z, ok, tol)
    return got if got is not None else torch_plane_band(coef, z, ok, tol)
