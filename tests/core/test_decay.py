"""Decay schedules: documented end points, agreement with MiniSom's formulas, the schedule helper."""

from __future__ import annotations

import pytest
import torch
from minisom import MiniSom

from somtorch.core.decay import DECAYS, asymptotic, constant, exponential, inverse_time, linear, schedule

T = 200
P0 = torch.tensor([0.5, 2.0, 7.0], dtype=torch.float64)
PEND = torch.tensor([0.01, 0.3, 1.0], dtype=torch.float64)


def f64(v: float) -> torch.Tensor:
    return torch.tensor(float(v), dtype=torch.float64)


@pytest.fixture(scope="module")
def ms() -> MiniSom:
    return MiniSom(4, 6, 2, random_seed=0)


def test_registry_names():
    assert set(DECAYS) == {"asymptotic", "linear", "exponential", "inverse_time", "constant"}


@pytest.mark.parametrize("name", sorted(DECAYS))
def test_every_decay_starts_at_p0(name):
    assert torch.allclose(DECAYS[name](P0, f64(0), T, PEND), P0, rtol=0, atol=1e-15)


def test_asymptotic_reaches_a_third_and_ignores_p_end():
    assert torch.allclose(asymptotic(P0, f64(T), T, PEND), P0 / 3, atol=1e-15)
    assert torch.equal(asymptotic(P0, f64(50), T, PEND),
                       asymptotic(P0, f64(50), T, PEND * 0.5))


@pytest.mark.parametrize("fn", [linear, exponential, inverse_time])
def test_decays_reach_p_end_at_T(fn):
    end = fn(P0, f64(T), T, PEND)
    assert torch.allclose(end, PEND, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("fn", [asymptotic, linear, exponential, inverse_time])
def test_decays_are_strictly_decreasing_when_p_end_below_p0(fn):
    t = torch.arange(T + 1, dtype=torch.float64)[:, None]
    v = fn(P0[None], t, T, PEND[None])  # (T+1, 3)
    assert bool((v[1:] < v[:-1]).all())


def test_constant_is_constant():
    t = torch.arange(T, dtype=torch.float64)[:, None]
    assert torch.equal(constant(P0[None], t, T, PEND[None]), P0.expand(T, 3))


def test_asymptotic_equals_minisom(ms):
    for p0 in (0.5, 1.5, 3.0):
        for t in (0, 1, 17, 199):
            want = ms._asymptotic_decay(p0, t, T)
            # float32 to float32 rounding; float64: the same operations, so exactly equal
            f32 = asymptotic(torch.tensor(p0), torch.tensor(float(t)), T, torch.tensor(1.0))
            assert float(f32) == pytest.approx(want, rel=1e-7)
            assert float(asymptotic(f64(p0), f64(t), T, f64(1))) == want


def test_inverse_time_to_one_equals_minisom_inverse_decay_to_one(ms):
    one = f64(1)
    for sigma in (1.5, 3.0, 6.0):
        for t in (0, 3, 100, 199, 200):
            ours = inverse_time(f64(sigma), f64(t), T, one)
            assert float(ours) == pytest.approx(ms._inverse_decay_to_one(sigma, t, T), rel=1e-14)


def test_linear_to_zero_equals_minisom_linear_decay_to_zero(ms):
    zero = f64(0)
    for lr in (0.1, 0.5, 1.0):
        for t in (0, 3, 100, 199, 200):
            ours = linear(f64(lr), f64(t), T, zero)
            want = ms._linear_decay_to_zero(lr, t, T)
            assert float(ours) == pytest.approx(want, rel=1e-14, abs=1e-16)


def test_linear_to_one_and_inverse_to_zero_equal_minisom(ms):
    # MiniSom's other two schedules are special cases of ours
    for t in (0, 7, 150):
        tt = f64(t)
        s = f64(4)
        assert float(linear(s, tt, T, f64(1))) == pytest.approx(ms._linear_decay_to_one(4.0, t, T), rel=1e-14)
        # MiniSom's inverse_decay_to_zero is inverse_time with p_end = p0/101
        lr = f64(0.5)
        want = ms._inverse_decay_to_zero(0.5, t, T)
        assert float(inverse_time(lr, tt, T, lr / 101.0)) == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("name", sorted(DECAYS))
def test_schedule_shape_dtype_and_blocks_agree(name):
    fn = DECAYS[name]
    p0 = P0.float()
    pend = PEND.float()
    whole = schedule(fn, p0, pend, 0, T, T)
    assert whole.shape == (T, 3) and whole.dtype == torch.float32
    # computed block by block (as the engine does) it is the same, bitwise
    parts = torch.cat([schedule(fn, p0, pend, a, min(a + 37, T), T) for a in range(0, T, 37)])
    assert torch.equal(whole, parts)
    # each member's column is that member's solo schedule
    for e in range(3):
        assert torch.equal(whole[:, e], schedule(fn, p0[e:e + 1], pend[e:e + 1], 0, T, T)[:, 0])
