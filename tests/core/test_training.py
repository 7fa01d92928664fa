"""The training engine's update rules and sample orders against naive re-implementations."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from somtorch import SOM
from somtorch.core.grid import grid_sqdist
from somtorch.core.neighborhood import bubble, gaussian
from somtorch.core import order
from somtorch.core.order import Order
from somtorch.core.training import _blocks, accumulate, batch_target, fixed_order_bmm, online_block

ROWS, COLS, D = 3, 4, 2
K = ROWS * COLS


@pytest.fixture
def setup():
    g = torch.Generator().manual_seed(9)
    x = torch.rand(50, D, generator=g, dtype=torch.float64)
    w = torch.rand(2, K, D, generator=g, dtype=torch.float64)
    return x, w, grid_sqdist(ROWS, COLS, dtype=torch.float64)


def _naive_online(w, xs, lr, sigma, d2, h_fn):
    w = w.clone()
    for t in range(xs.shape[0]):
        for e in range(w.shape[0]):
            c = int(((xs[t] - w[e]) ** 2).sum(-1).argmin())
            h = h_fn(d2[c], sigma[t, e]) * lr[t, e]
            w[e] += h[:, None] * (xs[t] - w[e])
    return w


@pytest.mark.parametrize("h_fn", [gaussian, bubble], ids=["gaussian", "bubble"])
@pytest.mark.parametrize("members", [1, 2])
def test_online_rule_equals_kohonen_formula(setup, h_fn, members):
    x, w, d2 = setup
    w = w[:members]
    s = 30
    lr = torch.linspace(0.5, 0.1, s, dtype=torch.float64)[:, None].expand(s, members).contiguous()
    sigma = torch.linspace(2.0, 0.5, s, dtype=torch.float64)[:, None].expand(s, members).contiguous()
    got = w.clone()
    online_block(got, x[:s][None], lr, sigma, d2, h_fn)
    assert torch.allclose(got, _naive_online(w, x[:s], lr, sigma, d2, h_fn), atol=1e-12)


def test_accumulate_counts_and_sums(setup):
    x, w, _ = setup
    sums, counts = accumulate(x, w, chunk_elements=5)
    bmu = torch.cdist(x.expand(2, -1, -1), w).argmin(-1)
    for e in range(2):
        for k in range(K):
            mask = bmu[e] == k
            assert int(counts[e, k]) == int(mask.sum())
            assert torch.allclose(sums[e, k], x[mask].sum(0), atol=1e-12)
    assert torch.equal(counts.sum(-1), torch.full((2,), 50.0, dtype=torch.float64))


def test_batch_target_is_neighbourhood_weighted_mean(setup):
    x, w, d2 = setup
    sigma = torch.tensor([0.7, 1.5], dtype=torch.float64)
    sums, counts = accumulate(x, w)
    target, den = batch_target(sums, counts, sigma, d2, gaussian)
    bmu = torch.cdist(x.expand(2, -1, -1), w).argmin(-1)
    for e in range(2):
        h = gaussian(d2[bmu[e]], sigma[e])  # (N, K): h_{c(n) k}
        want = (h.T @ x) / h.sum(0)[:, None]
        assert torch.allclose(target[e], want, atol=1e-12)
        assert torch.allclose(den[e], h.sum(0), atol=1e-12)


def test_batch_mode_one_epoch_is_one_batch_map_step(setup):
    x, w, d2 = setup
    som = SOM(ROWS, COLS, D, ensemble=2, dtype=torch.float64, seed=0)
    som.weight = w
    som.fit(x, mode="batch", epochs=1, sigma=1.2, progress=False)
    bmu = torch.cdist(x.expand(2, -1, -1), w).argmin(-1)
    for e in range(2):
        h = gaussian(d2[bmu[e]], torch.tensor(1.2, dtype=torch.float64))
        assert torch.allclose(som.weight[e], (h.T @ x) / h.sum(0)[:, None], atol=1e-12)


def test_units_no_sample_reaches_keep_their_weights():
    x = torch.tensor([[0.0, 0.0], [0.1, 0.0]], dtype=torch.float64)
    som = SOM(1, 5, 2, dtype=torch.float64, seed=0)
    w0 = torch.tensor([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0]], dtype=torch.float64)
    som.weight = w0
    som.fit(x, mode="batch", epochs=1, sigma=0.5, neighborhood="bubble", progress=False)
    assert torch.allclose(som.weight[0, 0], x.mean(0))  # the winner moves to its samples' mean
    assert torch.equal(som.weight[0, 1:], w0[1:])  # the others are out of the bubble: untouched


def test_minibatch_of_all_data_with_unit_rate_equals_batch(setup):
    x, w, _ = setup
    kw = {"epochs": 4, "sigma": 1.5, "progress": False}
    a = SOM(ROWS, COLS, D, dtype=torch.float64, seed=0)
    a.weight = w[0]
    a.fit(x, mode="batch", **kw)
    b = SOM(ROWS, COLS, D, dtype=torch.float64, seed=0)
    b.weight = w[0]
    b.fit(x, mode="minibatch", batch_size=x.shape[0], lr=1.0, lr_decay="constant", order="sequential", **kw)
    assert torch.allclose(a.weight, b.weight, atol=1e-12)


def test_random_order_is_a_fresh_permutation_per_epoch_and_member():
    gens = [torch.Generator().manual_seed(s) for s in (0, 1)]
    order = Order("random", 10, 2, gens, torch.device("cpu"))
    idx = torch.cat([order.indices(0, 7), order.indices(7, 20), order.indices(20, 30)], dim=1)  # (2, 30)
    assert idx.shape == (2, 30)
    for e in range(2):
        for ep in range(3):
            assert sorted(idx[e, ep * 10:(ep + 1) * 10].tolist()) == list(range(10))
        assert not torch.equal(idx[e, :10], idx[e, 10:20])
    assert not torch.equal(idx[0], idx[1])
    seq = Order("sequential", 10, 2, gens, torch.device("cpu")).indices(5, 25)
    assert seq.shape == (1, 20) and torch.equal(seq[0], torch.arange(5, 25) % 10)


def test_random_order_is_the_same_drawn_on_threads_and_in_int32(monkeypatch):
    # the (E, N) table of permutations: int32 rows on worker threads = torch.randperm per generator
    monkeypatch.setattr(order, "PERM_THREAD_ELEMENTS", 1)
    monkeypatch.setattr(order, "kernel_threads", lambda: 2)
    gens = [torch.Generator().manual_seed(s) for s in range(5)]
    idx = Order("random", 1000, 5, gens, torch.device("cpu")).indices(0, 1000)
    want = torch.stack([torch.randperm(1000, generator=torch.Generator().manual_seed(s)) for s in range(5)])
    assert idx.dtype == torch.long and torch.equal(idx, want)


def test_blocks_cover_all_steps_and_cut_at_callback_multiples():
    blocks = list(_blocks(23, 10, 4))
    assert blocks[0][0] == 0 and blocks[-1][1] == 23
    assert all(a[1] == b[0] for a, b in zip(blocks, blocks[1:]))
    stops = {b for _, b in blocks}
    assert {4, 8, 12, 16, 20, 10, 20, 23} <= stops
    assert all(b - a <= 10 for a, b in blocks)


# ----------------------------------------------------------------------------- partial_fit
@pytest.mark.parametrize("mode, order", [("batch", "sequential"), ("online", "sequential"), ("online", "random"),
                                         ("minibatch", "random")])
def test_partial_fit_continues_the_schedule_bitwise(mode, order):
    from somtorch.core.som import SOM

    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(0))
    whole = SOM(3, 4, 3, seed=5, ensemble=2).fit(x, mode=mode, epochs=4, order=order, progress=False)
    parts = SOM(3, 4, 3, seed=5, ensemble=2)
    for epochs in (1, 2, 1):
        parts.partial_fit(x, total_epochs=4, epochs=epochs, mode=mode, order=order, progress=False)
    assert parts.epochs_done == 4
    assert torch.equal(whole.weight, parts.weight)
    restart = SOM(3, 4, 3, seed=5, ensemble=2)
    for _ in range(4):  # four fresh schedules of one epoch each: what partial_fit is for avoiding
        restart.fit(x, mode=mode, epochs=1, order=order, progress=False)
    assert not torch.equal(whole.weight, restart.weight)


def test_partial_fit_guards_its_schedule():
    from somtorch.core.som import SOM

    x = torch.rand(100, 3, generator=torch.Generator().manual_seed(1))
    som = SOM(3, 3, 3, seed=0)
    som.partial_fit(x, total_epochs=3, progress=False)
    with pytest.raises(ValueError, match="run past"):
        som.partial_fit(x, total_epochs=3, epochs=3, progress=False)
    with pytest.raises(ValueError, match="would change it"):
        som.partial_fit(x, total_epochs=5, progress=False)
    som.partial_fit(x, total_epochs=3, epochs=2, progress=False)
    som.partial_fit(x, total_epochs=2, progress=False)  # the schedule ended: a new one starts
    assert som.epochs_done == 1
    som.fit(x, epochs=1, progress=False)
    assert som.epochs_done == 0


@pytest.mark.parametrize("mode", ["online", "batch"])
def test_a_training_without_a_bar_logs_its_progress(mode, monkeypatch, caplog):
    """Issue 34: a long run into a log file printed nothing while it worked (the bar is for a terminal)."""
    import logging

    import somtorch.core.training as training

    monkeypatch.setattr(training, "HEARTBEAT_S", 0.0)  # every block (every epoch of the batch map)
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(0))
    with caplog.at_level(logging.INFO, logger="somtorch.core.training"):
        SOM(3, 3, 3, seed=0).fit(x, mode=mode, epochs=4, progress=False)
    beats = [r.getMessage() for r in caplog.records if "s so far" in r.getMessage()]
    assert beats and beats[-1].startswith("SOM") and " of 4, " in beats[-1], beats
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="somtorch.core.training"):
        SOM(3, 3, 3, seed=0).fit(x, mode=mode, epochs=4, progress=True)  # a bar: no log lines
    assert not [r for r in caplog.records if "s so far" in r.getMessage()]


def _tree_sum(values: list) -> "np.float32":
    """The balanced tree of :func:`fixed_order_bmm`, written out on numpy scalars."""
    while len(values) > 1:
        half = len(values) // 2
        values = [values[i] + values[half + i] for i in range(half)] + values[2 * half:]
    return values[0]


@pytest.mark.parametrize("j", [1, 2, 5, 8, 13])
def test_fixed_order_bmm_sums_in_its_documented_order(j):
    # every term rounded once, added as first half + second half level by level: the bits of a
    # numpy float32 tree; no BLAS order, no chunking or thread count changes them
    g = torch.Generator().manual_seed(j)
    a = torch.rand(2, 3, j, generator=g) * 7
    b = torch.rand(2, j, 4, generator=g) * 1e3
    got = fixed_order_bmm(a, b)
    an, bn = a.numpy(), b.numpy()
    for e, i, c in itertools.product(range(2), range(3), range(4)):
        want = _tree_sum([np.float32(an[e, i, t]) * np.float32(bn[e, t, c]) for t in range(j)])
        assert got[e, i, c].item() == float(want)
    assert torch.equal(fixed_order_bmm(a, b, chunk_elements=1), got)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert torch.equal(fixed_order_bmm(a, b), got)
    finally:
        torch.set_num_threads(threads)
    assert torch.allclose(got, torch.bmm(a, b), rtol=1e-5)


def test_fixed_order_bmm_is_exact_where_the_sums_are():
    a = torch.randint(-50, 50, (3, 40, 40), generator=torch.Generator().manual_seed(0)).double()
    b = torch.randint(-50, 50, (3, 40, 4), generator=torch.Generator().manual_seed(1)).double()
    assert torch.equal(fixed_order_bmm(a, b, chunk_elements=500), torch.bmm(a, b))
