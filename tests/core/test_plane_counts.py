"""The native counts of plane hypotheses over sampled points, and of one plane's band over a map,
against their torch definitions."""

from __future__ import annotations

import torch

from somtorch.core.plane_counts import (native_plane_band, native_plane_counts, plane_band, torch_plane_band,
                                       torch_plane_counts)


def _hypotheses(n: int, g: torch.Generator) -> torch.Tensor:
    # slopes and offsets of the size a disparity map's planes have (px per px, px), some steep
    scale = torch.tensor([0.05, 0.2, 40.0], dtype=torch.float64)
    return torch.randn(n, 3, generator=g, dtype=torch.float64) * scale + torch.tensor([0.0, 0.05, 30.0],
                                                                                       dtype=torch.float64)


def test_the_native_counts_are_torchs_on_random_planes_and_points(kernel):
    g = torch.Generator().manual_seed(0)
    counted = torch.zeros(3, dtype=torch.long)
    for n_pts, tol in ((1, 0.5), (7, 0.1), (5000, 0.7), (3001, 2.3), (64, 1e-3)):
        coef = _hypotheses(400, g)
        pts = torch.stack([torch.randint(0, 1264, (n_pts,), generator=g).double(),
                           torch.randint(0, 720, (n_pts,), generator=g).double(),
                           (torch.rand(n_pts, generator=g, dtype=torch.float64) * 90).float().double()], 1)
        for tests in (True, False):
            got, want = native_plane_counts(coef, pts, tol, tests=tests), torch_plane_counts(coef, pts, tol,
                                                                                             tests=tests)
            assert got is not None
            for a, b in zip(got, want, strict=True):
                assert (a is None and b is None) or torch.equal(a, b), (n_pts, tol, tests)
        counted += torch.stack([t.sum() for t in torch_plane_counts(coef, pts, tol)])
    assert bool((counted > 0).all())  # points in the bands, above them and beneath: counts compared


def test_points_on_the_band_s_edges_count_as_torch_counts_them(kernel):
    # points placed exactly at pred ± tol and one float32 step either side: the comparisons are
    # float32 ones, the band a float32 number (0.1 is not), the prediction rounded step by step
    g = torch.Generator().manual_seed(1)
    coef = _hypotheses(50, g)
    xs = torch.randint(0, 640, (200,), generator=g).double()
    ys = torch.randint(0, 480, (200,), generator=g).double()
    for tol in (0.1, 0.5, 1 / 3, 2.0):
        c = coef[7].float()
        pred = c[0] * xs.float() + c[1] * ys.float() + c[2]
        t = torch.tensor(tol, dtype=torch.float32)
        edges = torch.cat([pred + t, pred - t, torch.nextafter(pred + t, pred), torch.nextafter(pred - t, pred),
                           torch.nextafter(pred + t, pred + 2 * t), torch.nextafter(pred - t, pred - 2 * t)])
        pts = torch.stack([xs.repeat(6), ys.repeat(6), edges.double()], 1)
        got, want = native_plane_counts(coef, pts, tol), torch_plane_counts(coef, pts, tol)
        assert all(torch.equal(a, b) for a, b in zip(got, want, strict=True)), tol
        assert 0 < int(want[0][7]) < pts.shape[0]  # some edge points in, some out


def test_the_kernel_declines_what_it_cannot_serve(kernel, monkeypatch):
    coef = torch.zeros(3, 3, dtype=torch.float64)
    assert native_plane_counts(coef, torch.zeros(5, 2), 0.5) is None  # not (x, y, z) rows
    assert native_plane_counts(torch.zeros(3, 4), torch.zeros(5, 3), 0.5) is None
    monkeypatch.setenv("SOMTORCH_NATIVE", "0")
    assert native_plane_counts(coef, torch.zeros(5, 3), 0.5) is None


def test_a_share_as_count_over_n_is_torchs_mean_of_the_comparisons():
    # the ground fit reads each hypothesis's share of sampled pixels as count / N in float32; the
    # mean of the (I, N) 0 / 1 comparisons it replaced gives the same bits for every count
    for n in (1, 3, 97, 1000, 4999, 5000):
        m = torch.arange(n)[None, :] < torch.arange(n + 1)[:, None]  # row c: c ones
        assert torch.equal(m.float().mean(1), m.sum(1).float() / n), n


def _same_band(coef, z, ok, tol):
    got, want = native_plane_band(coef, z, ok, tol), torch_plane_band(coef, z, ok, tol)
    assert got is not None
    assert torch.equal(got[0], want[0]) and got[1:] == want[1:], (coef, tol)
    return want


def test_the_native_band_is_torchs_on_random_maps(kernel):
    g = torch.Generator().manual_seed(2)
    counted = [0, 0, 0]
    for h, w, tol in ((1, 1, 0.5), (3, 200, 0.1), (120, 7, 2.3), (97, 131, 0.75), (240, 320, 1e-3)):
        for _ in range(4):
            coef = tuple(float(v) for v in _hypotheses(1, g)[0])
            z = (torch.rand(h, w, generator=g) * 90).float()
            z[torch.rand(h, w, generator=g) < 0.05] = float("nan")  # compared as torch compares NaN: never
            ok = torch.rand(h, w, generator=g) < 0.8
            for i, n in enumerate(_same_band(coef, z, ok, tol)[1:]):
                counted[i] += n
    assert all(n > 0 for n in counted)  # pixels in the bands, in view and behind: counts compared


def test_pixels_on_the_band_s_edges_are_in_it_as_torch_has_them(kernel):
    # maps placed exactly at plane ± tol and one float32 step either side: the plane and the
    # comparisons in float64, the map widened from float32
    g = torch.Generator().manual_seed(3)
    h, w = 60, 80
    ys = torch.arange(h, dtype=torch.float64)[:, None]
    xs = torch.arange(w, dtype=torch.float64)[None, :]
    ok = torch.ones(h, w, dtype=torch.bool)
    for tol in (0.1, 0.5, 1 / 3, 2.0):
        coef = tuple(float(v) for v in _hypotheses(1, g)[0])
        p = coef[0] * xs + coef[1] * ys + coef[2]
        for z in ((p + tol).float(), (p - tol).float(), torch.nextafter((p + tol).float(), p.float()),
                  torch.nextafter((p - tol).float(), p.float())):
            _, n_in, n_seen, n_behind = _same_band(coef, z, ok, tol)
            assert 0 <= n_in <= h * w and n_behind <= n_seen
    # a map whose pixels straddle the band's upper edge: some in, some out (the test bites)
    coef = (0.01, 0.05, 30.0)
    p = coef[0] * xs + coef[1] * ys + coef[2]
    z = torch.where(torch.rand(h, w, generator=g) < 0.5, torch.nextafter((p + 0.5).float(), p.float()),
                    torch.nextafter((p + 0.5).float(), (p + 1).float()))
    n_in = _same_band(coef, z, ok, 0.5)[1]
    assert 0 < n_in < h * w
    # a plane and band of dyadic numbers: the map exactly on the edge, |p - z| == tol, is outside
    # (the test fails if "<" becomes "<="); half the band inside; in view everywhere, behind nowhere
    coef = (0.5, 0.25, 30.0)
    p = coef[0] * xs + coef[1] * ys + coef[2]
    assert _same_band(coef, (p + 0.5).float(), ok, 0.5)[1:] == (0, h * w, 0)
    assert _same_band(coef, (p - 0.5).float(), ok, 0.5)[1:] == (0, h * w, 0)  # the edge beneath: not behind
    assert _same_band(coef, (p - 0.25).float(), ok, 0.5)[1:] == (h * w, h * w, 0)
    assert _same_band(coef, (p - 0.75).float(), ok, 0.5)[1:] == (0, h * w, h * w)


def test_plane_band_takes_the_torch_path_where_the_kernel_declines(kernel, monkeypatch):
    z, ok = torch.rand(4, 5) * 10, torch.ones(4, 5, dtype=torch.bool)
    assert native_plane_band((0.1, 0.2, 3.0), z.double(), ok, 0.5) is None  # not a float32 map
    assert native_plane_band((0.1, 0.2, 3.0), z, ok.float(), 0.5) is None  # not a bool mask
    assert native_plane_band((0.1, 0.2, 3.0), z, ok[:3], 0.5) is None  # shapes differ
    monkeypatch.setenv("SOMTORCH_NATIVE", "0")
    assert native_plane_band((0.1, 0.2, 3.0), z, ok, 0.5) is None
    band, *counts = plane_band((0.1, 0.2, 3.0), z, ok, 0.5)
    want = torch_plane_band((0.1, 0.2, 3.0), z, ok, 0.5)
    assert torch.equal(band, want[0]) and tuple(counts) == want[1:]
