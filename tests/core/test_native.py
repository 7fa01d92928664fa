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
from somtorch.core.native import native_bmu


@pytest.fixture(autouse=True)
def _kernel_enabled(monkeypatch):
    """Test the kernel even when the suite runs with ``SOMTORCH_NATIVE=0``; skip if it cannot build."""
    monkeypatch.delenv(native.ENV_SWITCH, raising=False)
    if native.library() is None:
        pytest.skip(f"the native BMU kernel could not be built or loaded ({native._failed}); "
                    "bmu_search uses the torch path")


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
def test_equals_brute_force(k, d, member, dtype):
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


def test_float32_equals_float64_distances_up_to_near_ties():
    x, w = _data(4, 3000, 28, 3, torch.float32, False, seed=1)
    got = native_bmu(x, w)
    dist = _sqdist(x.double(), w.double())
    chosen = torch.gather(dist, -1, got[..., None])[..., 0]
    best = dist.min(-1).values
    assert float((chosen - best).max()) <= 1e-6 * float(best.max())
    assert float((got == dist.argmin(-1)).double().mean()) > 0.999


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("member", [False, True], ids=["shared", "member"])
def test_ties_pick_the_first_index(dtype, member):
    x, w = _data(3, 301, 28, 3, dtype, member, ints=True)
    w[:, 20] = w[:, 4]  # duplicate neurons: 4 must win over 20
    dist = _sqdist(x, w)
    assert int((dist == dist.min(-1, keepdim=True).values).sum(-1).max()) > 1  # ties do occur
    assert torch.equal(native_bmu(x, w), dist.argmin(-1))
    assert torch.equal(native_bmu(x, w, k=2), _top2(dist))
    assert not bool((native_bmu(x, w) == 20).any())


def test_threads_chunks_and_members_do_not_change_the_result():
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


def test_bmu_search_dispatches_to_the_kernel(monkeypatch):
    calls = []

    def spy(x, w, k=1):
        calls.append(k)
        return native_bmu(x, w, k=k)

    monkeypatch.setattr(native, "native_bmu", spy)
    x, w = _data(2, 50, 6, 3, torch.float64, False)
    assert torch.equal(bmu_search(x, w), _sqdist(x, w).argmin(-1))
    assert torch.equal(bmu_search(x, w, k=2), _top2(_sqdist(x, w)))
    assert torch.equal(bmu_search(x, w, k=3)[..., :2], _top2(_sqdist(x, w)))  # k = 3: torch path only
    assert calls == [1, 2]


def test_unsupported_calls_return_none():
    x, w = _data(2, 10, 4, 3, torch.float32, False)
    assert native_bmu(x.half(), w.half()) is None
    assert native_bmu(x.double(), w) is None
    assert native_bmu(x, w, k=3) is None
    assert native_bmu(x, w[:, :1], k=2) is None
    w_nan = w.clone()
    w_nan[0, 1, 2] = float("nan")
    assert native_bmu(x, w_nan) is None
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
