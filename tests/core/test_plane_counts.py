"""The native counts of plane hypotheses over sampled points against their torch definition."""

from __future__ import annotations

import torch

from somtorch.core.plane_counts import native_plane_counts, torch_plane_counts


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
