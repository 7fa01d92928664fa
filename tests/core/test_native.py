"""The fused native BMU kernel against brute force, and its fallbacks.

The reference is the kernel's own definition — ``Σ_d (x_d − w_d)²`` summed left to right in the input
precision, argmin with the first index on ties — computed with plain torch element-wise ops, so the
comparison is exact (bitwise) for float32 and float64; float32 is also checked against float64
distances (equal up to near ties within float32 rounding).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import pytest
import torch

from somtorch.core import native
from somtorch.core.distance import bmu_search
from somtorch.core.native import native_accumulate, native_bmu
from somtorch.core.training import accumulate


@pytest.fixture(autouse=True)
def _kernel_enabled(monkeypatch):
    """Test the kernel even when the suite runs with ``SOMTORCH_NATIVE=0``."""
    monkeypatch.delenv(native.ENV_SWITCH, raising=False)


def _sqdist(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """``Σ_d (x_d − w_d)²`` left to right in the input dtype: x ``(N, D)``/``(E, N, D)``, w ``(E, K, D)``
    → ``(E, N, K)``."""
    xe = x.expand(w.shape[0], -1, -1) if x.ndim == 2 else x
    diff = xe[:, :, None, :] - w[:, None, :, :]  # (E, N, K, D)
    acc = diff[..., 0] * diff[..., 0]
    for d in range(1, w.shape[-1]):
        acc = acc + diff[..., d] * diff[..., d]
    return acc


def _top2(dist: torch.Tensor) -> torch.Tensor:
    """Two smallest, ties by index: ``(E, N, K)`` → ``(E, N, 2)``."""
    return torch.sort(dist, dim=-1, stable=True).indices[..., :2]


def _data(e, n, k, d, dtype, member, seed=0, ints=False):
    g = torch.Generator().manual_seed(seed)
    if ints:  # small integers: exact ties everywhere
        w = torch.randint(0, 3, (e, k, d), generator=g).to(dtype)
        x = torch.randint(0, 3, (e, n, d) if member else (n, d), generator=g).to(dtype)
    else:
        w = torch.randn(e, k, d, generator=g, dtype=dtype)
        x = torch.randn((e, n, d) if member else (n, d), generator=g, dtype=dtype)
    return x, w


SHAPES = [(28, 3), (1, 1), (1, 3), (5, 1), (3, 2), (9, 4), (28, 7), (40, 5), (2, 16)]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("member", [False, True], ids=["shared", "member"])
@pytest.mark.parametrize("k,d", SHAPES, ids=[f"K{k}-D{d}" for k, d in SHAPES])
def test_equals_brute_force(kernel, k, d, member, dtype):
    for n in (1, 17, 203):  # 203: no multiple of any tile (8 or 16 samples)
        x, w = _data(3, n, k, d, dtype, member, seed=k * 100 + d + n)
        dist = _sqdist(x, w)
        got = native_bmu(x, w)
        assert got.shape == (3, n) and got.dtype == torch.long
        assert torch.equal(got, dist.argmin(-1))
        if k >= 2:
            got2 = native_bmu(x, w, k=2)
            assert got2.shape == (3, n, 2)
            assert torch.equal(got2, _top2(dist))


def test_float32_equals_float64_distances_up_to_near_ties(kernel):
    x, w = _data(4, 3000, 28, 3, torch.float32, False, seed=1)
    got = native_bmu(x, w)
    dist = _sqdist(x.double(), w.double())
    chosen = torch.gather(dist, -1, got[..., None])[..., 0]
    best = dist.min(-1).values
    assert float((chosen - best).max()) <= 1e-6 * float(best.max())
    assert float((got == dist.argmin(-1)).double().mean()) > 0.999


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("member", [False, True], ids=["shared", "member"])
def test_ties_pick_the_first_index(kernel, dtype, member):
    x, w = _data(3, 301, 28, 3, dtype, member, ints=True)
    w[:, 20] = w[:, 4]  # duplicate neurons: 4 must win over 20
    dist = _sqdist(x, w)
    assert int((dist == dist.min(-1, keepdim=True).values).sum(-1).max()) > 1  # ties do occur
    assert torch.equal(native_bmu(x, w), dist.argmin(-1))
    assert torch.equal(native_bmu(x, w, k=2), _top2(dist))
    assert not bool((native_bmu(x, w) == 20).any())


def test_threads_chunks_and_members_do_not_change_the_result(kernel):
    x, w = _data(5, 20011, 28, 3, torch.float32, False, seed=2)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = native_bmu(x, w)
        torch.set_num_threads(2)
        two = native_bmu(x, w)
        solo = torch.cat([native_bmu(x, w[e:e + 1]) for e in range(5)])  # member e == solo map e
        split = torch.cat([native_bmu(x[:7777], w), native_bmu(x[7777:], w)], dim=1)
        per_member = native_bmu(x.expand(5, -1, -1), w)
    finally:
        torch.set_num_threads(before)
    for other in (two, solo, split, per_member):
        assert torch.equal(one, other)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("member", [False, True], ids=["shared", "member"])
@pytest.mark.parametrize("k,d", [(28, 3), (1, 2), (6, 1), (9, 7)], ids=["K28-D3", "K1-D2", "K6-D1", "K9-D7"])
def test_accumulate_equals_the_torch_accumulation_bitwise(kernel, k, d, member, dtype, monkeypatch):
    x, w = _data(3, 1003, k, d, dtype, member, seed=k + d)
    sums, counts = native_accumulate(x, w)
    monkeypatch.setenv(native.ENV_SWITCH, "0")  # accumulate() would call the kernel itself
    want_sums, want_counts = accumulate(x, w, chunk_elements=997)  # BMUs + index_add_ in sample order
    assert sums.dtype == counts.dtype == dtype and sums.shape == (3, k, d) and counts.shape == (3, k)
    assert torch.equal(sums, want_sums) and torch.equal(counts, want_counts)
    assert int(counts.sum()) == 3 * 1003


def test_accumulate_threads_and_members_do_not_change_the_result(kernel):
    x, w = _data(5, 20011, 28, 3, torch.float32, False, seed=4)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = native_accumulate(x, w)
        torch.set_num_threads(2)
        two = native_accumulate(x, w)
        solo = [native_accumulate(x, w[e:e + 1]) for e in range(5)]
    finally:
        torch.set_num_threads(before)
    for i in range(2):
        assert torch.equal(one[i], two[i])
        assert torch.equal(one[i], torch.cat([s[i] for s in solo]))


def test_bmu_search_dispatches_to_the_kernel(kernel, monkeypatch):
    calls = []

    def spy(x, w, k=1):
        calls.append(k)
        return native_bmu(x, w, k=k)

    import somtorch.core.distance as distance

    monkeypatch.setattr(distance, "native_bmu", spy)
    x, w = _data(2, 50, 6, 3, torch.float64, False)
    assert torch.equal(bmu_search(x, w), _sqdist(x, w).argmin(-1))
    assert torch.equal(bmu_search(x, w, k=2), _top2(_sqdist(x, w)))
    assert torch.equal(bmu_search(x, w, k=3)[..., :2], _top2(_sqdist(x, w)))  # k = 3: torch path only
    assert calls == [1, 2]


def test_no_samples(kernel):
    _, w = _data(2, 1, 4, 3, torch.float32, False)
    assert native_bmu(torch.empty(0, 3), w).shape == (2, 0)
    assert native_bmu(torch.empty(2, 0, 3), w, k=2).shape == (2, 0, 2)
    sums, counts = native_accumulate(torch.empty(0, 3), w)
    assert not sums.any() and not counts.any()


def test_unsupported_calls_return_none(kernel):
    x, w = _data(2, 10, 4, 3, torch.float32, False)
    assert native_bmu(x.half(), w.half()) is None
    assert native_bmu(x.double(), w) is None
    assert native_bmu(x, w, k=3) is None
    assert native_bmu(x, w[:, :1], k=2) is None
    w_nan = w.clone()
    w_nan[0, 1, 2] = float("nan")
    assert native_bmu(x, w_nan) is None
    assert native_accumulate(x, w_nan) is None and native_accumulate(x.half(), w.half()) is None
    assert torch.equal(bmu_search(x, w_nan)[1], bmu_search(x, w)[1])  # the torch path serves it


def test_build_failure_falls_back_with_one_warning(monkeypatch, tmp_path, caplog):
    monkeypatch.setattr(native, "_lib", None)
    monkeypatch.setattr(native, "_failed", None)
    monkeypatch.setattr(native, "_noted", set())
    monkeypatch.setenv("CXX", "false")  # a "compiler" that always fails
    monkeypatch.setenv(native.ENV_CACHE, str(tmp_path))
    x, w = _data(2, 10, 4, 3, torch.float32, False)
    with caplog.at_level(logging.WARNING, logger="somtorch.core.native"):
        assert native_bmu(x, w) is None
        assert native_bmu(x, w) is None
        assert bmu_search(x, w).shape == (2, 10)
    warnings = [r for r in caplog.records if "unavailable" in r.getMessage()]
    assert len(warnings) == 1 and "building csrc/bmu.cpp failed" in warnings[0].getMessage()
    assert not list(tmp_path.glob("*.so"))


def test_env_switch_disables_the_kernel():
    code = (
        "import logging, torch\n"
        "logging.basicConfig(level=logging.INFO, format='%(message)s')\n"
        "from somtorch.core import native\n"
        "from somtorch.core.distance import bmu_search\n"
        "x, w = torch.rand(9, 3), torch.rand(2, 4, 3)\n"
        "assert native.native_bmu(x, w) is None and not native.available()\n"
        "assert native._lib is None  # not even built\n"
        "print(bmu_search(x, w).shape)\n"
    )
    env = {**os.environ, native.ENV_SWITCH: "0"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "torch.Size([2, 9])" in proc.stdout
    assert "SOMTORCH_NATIVE=0" in proc.stderr


@pytest.mark.slow
def test_concurrent_first_builds_share_one_library(kernel, tmp_path):
    """Two processes building into an empty cache at once (as two xdist workers may) both get the
    kernel; one compiles under the file lock, the other waits and loads it; no temporary files stay."""
    code = (
        "import torch\n"
        "from somtorch.core import native\n"
        "assert native.library() is not None, native._failed\n"
        "x, w = torch.rand(50, 3), torch.rand(2, 5, 3)\n"
        "print(native.native_bmu(x, w).shape)\n"
    )
    env = {**os.environ, native.ENV_CACHE: str(tmp_path)}
    env.pop(native.ENV_SWITCH, None)
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        assert "torch.Size([2, 50])" in out
    assert len(list(tmp_path.glob("*.so"))) == 1
    assert not list(tmp_path.glob("*.tmp*"))


def _online_torch(weight, xs, coef, log_lr, grid_d2):
    """The torch formulation of the gaussian online rule (training.online_block's loop), step by step."""
    w = weight.clone()
    for s in range(xs.shape[1]):
        x_t = xs[:, s] if xs.shape[0] > 1 else xs[0, s].expand(w.shape[0], -1)
        diff = x_t.unsqueeze(1) - w
        c = diff.square().sum(-1).argmin(-1)
        h = torch.exp(log_lr[s].unsqueeze(-1) + grid_d2[c] * coef[s].unsqueeze(-1))
        w += h.unsqueeze(-1) * diff
    return w


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-6), (torch.float64, 1e-14)], ids=["f32", "f64"])
@pytest.mark.parametrize("member", [False, True], ids=["shared", "member"])
@pytest.mark.parametrize("k,d", [(28, 3), (1, 2), (9, 7), (256, 3)], ids=["K28-D3", "K1-D2", "K9-D7", "K256-D3"])
def test_online_rule_equals_the_torch_formulation(kernel, k, d, member, dtype, tol):
    g = torch.Generator().manual_seed(k * 10 + d)
    e, s = 3, 200
    w0 = torch.rand(e, k, d, generator=g, dtype=dtype)
    xs = torch.rand(e if member else 1, s, d, generator=g, dtype=dtype)
    sigma = torch.linspace(2.0, 0.5, s, dtype=dtype)[:, None].expand(s, e).contiguous()
    coef = -0.5 / sigma ** 2
    log_lr = torch.log(torch.linspace(0.5, 0.01, s, dtype=dtype))[:, None].expand(s, e).contiguous()
    grid_d2 = torch.randint(0, 30, (k, k), generator=g).to(dtype)
    grid_d2 = (grid_d2 + grid_d2.T).fill_diagonal_(0)
    w = w0.clone()
    assert native.native_online(w, xs, coef, log_lr, grid_d2)
    ref = _online_torch(w0, xs, coef, log_lr, grid_d2)
    assert torch.allclose(w, ref, rtol=0, atol=tol), (w - ref).abs().max()
    assert not torch.equal(w, w0)
    # a member computed alone gives the same bits as in the ensemble (threads take whole members)
    solo = w0[1:2].clone()
    assert native.native_online(solo, xs[1:2] if member else xs, coef[:, 1:2].contiguous(),
                                log_lr[:, 1:2].contiguous(), grid_d2)
    assert torch.equal(solo[0], w[1])


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-6), (torch.float64, 1e-14)], ids=["f32", "f64"])
@pytest.mark.parametrize("e", [2, 5, 11, 19])
@pytest.mark.parametrize("data", ["shared", "member"])
@pytest.mark.parametrize("grid", ["grid", "arbitrary"])
def test_online_lanes_equal_solo_runs_bitwise(kernel, dtype, tol, e, data, grid):
    """Members in vector lanes (E >= 2; 8 float32 / 4 float64 per vector, partly filled last block):
    every member equals its solo run (E = 1, one member at a time) bit for bit, with steps where the
    members share α and σ (one exponential table) and steps where each member has its own, an index
    stream per member into shared or per-member data, and ties in the distances (grid-valued data)."""
    g = torch.Generator().manual_seed(e)
    k, d, s, n = 12, 3, 300, 40
    x = torch.randint(0, 4, (e, n, d) if data == "member" else (n, d), generator=g).to(dtype) / 3
    idx = torch.randint(0, n, (e, s), generator=g)
    w0 = torch.randint(0, 4, (e, k, d), generator=g).to(dtype) / 3  # the first steps have exact ties
    sigma = torch.linspace(2.0, 0.5, s, dtype=dtype)[:, None].repeat(1, e)
    lr = torch.linspace(0.5, 0.01, s, dtype=dtype)[:, None].repeat(1, e)
    sigma[s // 3: 2 * s // 3] *= torch.linspace(0.8, 1.2, e, dtype=dtype)  # a stretch of per-member radii
    coef, log_lr = -0.5 / sigma ** 2, torch.log(lr)
    rows, cols = torch.meshgrid(torch.arange(3), torch.arange(4), indexing="ij")
    pos = torch.stack([rows.reshape(-1), cols.reshape(-1)], 1).to(dtype)
    grid_d2 = ((pos[:, None] - pos[None]) ** 2).sum(-1)
    if grid == "arbitrary":  # 66 distinct values > 4 K: the kernel fills only the exps its rows need
        grid_d2 = torch.rand(k, k, generator=g, dtype=dtype) * 9
        grid_d2 = (grid_d2 + grid_d2.T).fill_diagonal_(0)
    w = w0.clone()
    assert native.native_online(w, x, coef, log_lr, grid_d2, idx)
    for m in range(e):
        solo = w0[m:m + 1].clone()
        xm = x[m:m + 1] if data == "member" else x
        assert native.native_online(solo, xm, coef[:, m:m + 1].contiguous(), log_lr[:, m:m + 1].contiguous(),
                                    grid_d2, idx[m:m + 1])
        assert torch.equal(solo[0], w[m]), (m, (solo[0] - w[m]).abs().max())
    xs = torch.stack([(x[m] if data == "member" else x)[idx[m]] for m in range(e)])  # (E, S, D)
    ref = _online_torch(w0, xs, coef, log_lr, grid_d2)
    assert torch.allclose(w, ref, rtol=0, atol=tol), (w - ref).abs().max()


def test_online_rule_refuses_nan_weights_and_foreign_dtypes(kernel):
    w = torch.rand(1, 4, 3)
    w[0, 2, 1] = float("nan")
    xs, c, lr, g = torch.rand(1, 5, 3), -torch.ones(5, 1), torch.zeros(5, 1), torch.zeros(4, 4)
    before = w.clone()
    assert not native.native_online(w, xs, c, lr, g)  # the torch path decides what NaN does
    assert torch.equal(w.nan_to_num(), before.nan_to_num())
    assert not native.native_online(torch.rand(1, 4, 3, dtype=torch.float16), xs.half(), c, lr, g)


@pytest.mark.parametrize("ensemble", [1, 3])
def test_online_fit_on_the_torch_path_agrees_with_the_compiled_loop(kernel, monkeypatch, ensemble):
    # the torch path is what a CUDA device runs: it must give the same map up to rounding
    from somtorch import SOM

    x = torch.rand(2000, 3, generator=torch.Generator().manual_seed(3))
    fast = SOM(4, 7, 3, ensemble=ensemble, seed=2).fit(x, mode="online", epochs=2, progress=False)
    monkeypatch.setenv(native.ENV_SWITCH, "0")
    slow = SOM(4, 7, 3, ensemble=ensemble, seed=2).fit(x, mode="online", epochs=2, progress=False)
    assert torch.allclose(fast.weight, slow.weight, rtol=0, atol=1e-5)
    assert not torch.equal(fast.weight, SOM(4, 7, 3, ensemble=ensemble, seed=2).initialize(x, "random").weight)
