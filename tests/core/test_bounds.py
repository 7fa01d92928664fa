"""Bound-accelerated BMU search: exact (the unbounded BMUs and sums, bitwise, ties included)."""

from __future__ import annotations

import pytest
import torch

from somtorch import SOM
from somtorch.core import bounds as bounds_mod
from somtorch.core import native, training
from somtorch.core.bounds import BmuBounds
from somtorch.disparity import load_scene
from somtorch.disparity.features import make_features

pytestmark = pytest.mark.skipif(not native.available(), reason="the bounds run in the native kernel")


@pytest.fixture(scope="module")
def motorcycle():
    scene = load_scene("motorcycle")
    return make_features(scene.disparity, scene.valid, d_weight=2.0).subsample(2).x  # (N, 3), N ≈ 86k


def _trajectory(x, ensemble=1, epochs=12, **kw):
    """Weights before every epoch of a batch-map run ``[(E, K, D)]``."""
    seen = []
    som = SOM(8, 8, x.shape[-1], ensemble=ensemble, seed=0)
    som.initialize(x)
    seen.append(som.weight.detach().clone())
    som.fit(x, mode="batch", epochs=epochs, progress=False, callback=lambda i: seen.append(i.weight.clone()), **kw)
    return seen


def _check_every_epoch(x, weights):
    b = BmuBounds()
    skipped = []
    for w in weights:
        got = b.accumulate(x, w)
        want = native.native_accumulate(x, w)
        assert torch.equal(b.bmu, native.native_bmu(x, w))
        assert torch.equal(got[0], want[0]) and torch.equal(got[1], want[1])
        skipped.append(b.skipped)
    return skipped


def test_bounded_search_is_the_unbounded_one_on_a_real_map(motorcycle):
    weights = _trajectory(motorcycle, epochs=30)
    # the late epochs move the units less than the gaps: those searches are skipped
    for w_prev, w in zip(weights[:-1], weights[1:]):
        b = BmuBounds()
        b.accumulate(motorcycle, w_prev)
        got = b.accumulate(motorcycle, w)
        want = native.native_accumulate(motorcycle, w)
        assert torch.equal(b.bmu, native.native_bmu(motorcycle, w))
        assert torch.equal(got[0], want[0]) and torch.equal(got[1], want[1])
    assert b.skipped > 0.3


def test_ensembles_and_per_member_samples(motorcycle):
    x = motorcycle[::4]
    weights = _trajectory(x, ensemble=3, epochs=8, sigma=torch.tensor([4.0, 2.0, 1.0]))
    _check_every_epoch(x, weights)
    xe = torch.stack([x, x.flip(0), x * 0.5])  # (E, N, D)
    _check_every_epoch(xe, [w.clone() for w in weights])


def test_ties_and_moves_at_the_rounding_level():
    """Integer data (exact ties between units), and units moved by one ulp: the bounds must not
    decide what rounding could flip; the lowest index wins as without them."""
    g = torch.Generator().manual_seed(0)
    x = torch.randint(0, 5, (6000, 3), generator=g).float()
    w = torch.randint(0, 5, (2, 25, 3), generator=g).float() + 0.5  # midpoints: many equal distances
    w[:, 1] = w[:, 0]  # duplicated units: a tie on every sample of unit 0
    moves = [w, w, torch.nextafter(w, w + 1), w, w + 1e-7, torch.nextafter(w, w - 1), w * (1 + 2 ** -23)]
    _check_every_epoch(x, moves)
    for dt in (torch.float64,):
        _check_every_epoch(x.to(dt), [m.to(dt) for m in moves])


def test_fit_with_bounds_forced_on_gives_the_same_weights(motorcycle, monkeypatch):
    x = motorcycle[::2]
    plain = SOM(8, 8, 3, ensemble=2, seed=1)
    monkeypatch.setattr(training, "USE_BOUNDS", False)
    plain.fit(x, mode="batch", epochs=15, progress=False)
    monkeypatch.setattr(training, "USE_BOUNDS", True)
    monkeypatch.setattr(bounds_mod, "START_SHARE", 0.0)
    monkeypatch.setattr(bounds_mod, "START_EPOCHS", 0)
    monkeypatch.setattr(bounds_mod, "STOP_SHARE", 0.0)
    bounded = SOM(8, 8, 3, ensemble=2, seed=1).fit(x, mode="batch", epochs=15, progress=False)
    assert torch.equal(plain.weight, bounded.weight)
    assert len(bounded.skipped) == 15 and bounded.skipped[0] == 0.0 and max(bounded.skipped) > 0.0


def test_the_default_job_keeps_the_fused_kernel(motorcycle):
    """On the default schedule the units move more per epoch than the gaps: the probe keeps the
    bounds off (measured: docs/scaling.md), and the stats say so."""
    som = SOM(8, 8, 3, seed=0).fit(motorcycle, mode="batch", progress=False)
    assert som.skipped == [0.0] * 10


def test_the_probe_predicts_the_skipped_share(motorcycle):
    """The probe's share (the last epoch's drift assumed again) is what the bounds then skip."""
    w = SOM(8, 8, 3, seed=0).fit(motorcycle, mode="batch", progress=False).weight.detach().clone()
    dirs = torch.randn(w.shape, generator=torch.Generator().manual_seed(1))
    dirs /= dirs.norm(dim=-1, keepdim=True)
    for step, lo, hi in ((1e-4, 0.9, 1.0), (0.05, 0.0, 0.1)):
        probe, real = BmuBounds(), BmuBounds()
        probe.predict(motorcycle, w - step * dirs)
        predicted = probe.predict(motorcycle, w)  # the units moved by `step` in the last epoch
        real.accumulate(motorcycle, w)
        real.accumulate(motorcycle, w + step * dirs)
        assert lo <= predicted <= hi and abs(predicted - real.skipped) < 0.1
