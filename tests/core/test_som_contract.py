"""The contract every training mode keeps: determinism, learning, ensemble = solo runs, persistence,
callbacks and silence."""

from __future__ import annotations

import json
import time

import pytest
import torch

from somtorch import SOM, StepInfo
from somtorch.core import MODES

ROWS, COLS, D = 4, 5, 3
FIT = {"online": {"epochs": 2}, "batch": {"epochs": 6}, "minibatch": {"epochs": 3, "batch_size": 40}}


def fit_kw(mode: str, **extra) -> dict:
    return {"mode": mode, "progress": False, **FIT[mode], **extra}


def test_modes_are_the_three_trainers():
    assert set(MODES) == {"online", "batch", "minibatch"}


@pytest.mark.parametrize("mode", MODES)
def test_same_seed_gives_bitwise_identical_weights(mode, x3):
    a = SOM(ROWS, COLS, D, ensemble=2, seed=5).fit(x3, **fit_kw(mode))
    b = SOM(ROWS, COLS, D, ensemble=2, seed=5).fit(x3, **fit_kw(mode))
    assert torch.equal(a.weight, b.weight)
    c = SOM(ROWS, COLS, D, ensemble=2, seed=6).fit(x3, **fit_kw(mode))
    assert not torch.equal(a.weight, c.weight)


@pytest.mark.parametrize("mode", MODES)
def test_same_seed_same_weights_with_two_threads_and_across_thread_counts(mode, x3):
    torch.set_num_threads(2)  # the autouse fixture restores the setting afterwards
    a = SOM(ROWS, COLS, D, ensemble=2, seed=5).fit(x3, **fit_kw(mode))
    b = SOM(ROWS, COLS, D, ensemble=2, seed=5).fit(x3, **fit_kw(mode))
    assert torch.equal(a.weight, b.weight)
    torch.set_num_threads(1)
    c = SOM(ROWS, COLS, D, ensemble=2, seed=5).fit(x3, **fit_kw(mode))
    assert torch.equal(a.weight, c.weight)


@pytest.mark.parametrize("mode", MODES)
def test_fit_returns_self_and_initialises(mode, x3):
    som = SOM(ROWS, COLS, D, seed=0)
    assert not som.initialized
    assert som.fit(x3, **fit_kw(mode)) is som
    assert som.initialized


@pytest.mark.parametrize("mode", MODES)
def test_training_lowers_quantization_error(mode, x3):
    som = SOM(ROWS, COLS, D, ensemble=2, seed=0).initialize(x3, "random")
    before = som.quantization_error(x3)
    w0 = som.weight.detach().clone()
    som.fit(x3, **fit_kw(mode))
    assert not torch.equal(som.weight, w0)  # the initialisation was kept and trained, not redone
    after = som.quantization_error(x3)
    assert bool((after < 0.5 * before).all()), (before, after)


@pytest.mark.parametrize("mode", MODES)
def test_ensemble_member_equals_solo_run(mode, x3):
    ens = SOM(ROWS, COLS, D, ensemble=3, seed=10).fit(x3, **fit_kw(mode))
    for e in range(3):
        solo = SOM(ROWS, COLS, D, seed=10 + e).fit(x3, **fit_kw(mode))
        assert solo.seeds == [10 + e] == [ens.seeds[e]]
        assert torch.equal(ens.weight[e], solo.weight[0]), e
    assert torch.equal(ens.member(2).weight[0], ens.weight[2]) and ens.member(2).seeds == [12]


@pytest.mark.parametrize("mode", ["batch", "online"])
def test_large_grid_ensemble_member_equals_solo_run(mode, x3):
    # 16 x 16: the batch target is one batched product per member; the online rule one compiled loop
    kw = {"epochs": 3} if mode == "batch" else {"iterations": 500}
    ens = SOM(16, 16, D, ensemble=5, seed=40).fit(x3, mode=mode, progress=False, **kw)
    for e in (0, 4):
        solo = SOM(16, 16, D, seed=40 + e).fit(x3, mode=mode, progress=False, **kw)
        assert torch.equal(ens.weight[e], solo.weight[0]), e
    assert not torch.equal(ens.weight[0], ens.weight[4])


@pytest.mark.parametrize("mode", MODES)
def test_ensemble_with_per_member_hyper_parameters_equals_solo_runs(mode, x3):
    lr = torch.tensor([0.6, 0.3, 0.1])
    sigma = torch.tensor([2.5, 1.5, 0.8])
    decays = ["asymptotic", "linear", "exponential"]
    ens = SOM(ROWS, COLS, D, ensemble=3, seed=20).fit(x3, lr=lr, sigma=sigma, sigma_decay=decays,
                                                      **fit_kw(mode))
    for e in range(3):
        solo = SOM(ROWS, COLS, D, seed=20 + e).fit(x3, lr=float(lr[e]), sigma=float(sigma[e]),
                                                   sigma_decay=decays[e], **fit_kw(mode))
        assert torch.equal(ens.weight[e], solo.weight[0]), e
    # the members really differ (so equality above is not trivial)
    assert not torch.equal(ens.weight[0], ens.weight[1])


@pytest.mark.parametrize("mode", MODES)
def test_ensemble_with_per_member_data_equals_solo_runs(mode, x3):
    xm = torch.stack([x3, x3.flip(0) * 0.5, x3 ** 2])  # (E, N, D)
    ens = SOM(ROWS, COLS, D, ensemble=3, seed=30).fit(xm, **fit_kw(mode))
    for e in range(3):
        solo = SOM(ROWS, COLS, D, seed=30 + e).fit(xm[e], **fit_kw(mode))
        assert torch.equal(ens.weight[e], solo.weight[0]), e


@pytest.mark.parametrize("mode", ["online", "minibatch"])
def test_explicit_order_equals_the_named_order(mode, x3):
    n = x3.shape[0]
    kw = fit_kw(mode, epochs=1)
    stream = n if mode == "online" else (n // kw["batch_size"]) * kw["batch_size"]
    a = SOM(ROWS, COLS, D, seed=1).fit(x3, order="sequential", **kw)
    b = SOM(ROWS, COLS, D, seed=1).fit(x3, order=torch.arange(stream) % n, **kw)
    assert torch.equal(a.weight, b.weight)
    c = SOM(ROWS, COLS, D, seed=1).fit(x3, order=torch.arange(stream).flip(0) % n, **kw)
    assert not torch.equal(a.weight, c.weight)


@pytest.mark.parametrize("mode,order", [
    ("online", "sequential"), ("online", "explicit"), ("online", "explicit-per-member"),
    ("minibatch", "sequential"),
    ("minibatch", "explicit"),
    ("minibatch", "explicit-per-member"),
])
def test_ensemble_with_shared_or_explicit_order_equals_solo_runs(mode, order, x3):
    kw = fit_kw(mode, epochs=1)
    n = x3.shape[0]
    stream = n if mode == "online" else (n // kw["batch_size"]) * kw["batch_size"]
    perms = torch.stack([torch.randperm(n, generator=torch.Generator().manual_seed(e))[:stream]
                         for e in range(3)])  # (3, T)
    orders = {"sequential": ["sequential"] * 3, "explicit": [perms[0]] * 3,
              "explicit-per-member": list(perms)}[order]
    ens_order = {"sequential": "sequential", "explicit": perms[0], "explicit-per-member": perms}[order]
    ens = SOM(ROWS, COLS, D, ensemble=3, seed=50).fit(x3, order=ens_order, **kw)
    for e in range(3):
        solo = SOM(ROWS, COLS, D, seed=50 + e).fit(x3, order=orders[e], **kw)
        assert torch.equal(ens.weight[e], solo.weight[0]), e


@pytest.mark.parametrize("mode", MODES)
def test_save_load_round_trip(mode, x3, tmp_path):
    som = SOM(ROWS, COLS, D, ensemble=2, topology="hexagonal", seed=40).fit(x3, **fit_kw(mode))
    path = som.save(tmp_path / "model")
    assert path == tmp_path / "model.safetensors" and path.is_file()
    assert json.loads((tmp_path / "model.json").read_text())["seeds"] == [40, 41]
    back = SOM.load(path)
    assert torch.equal(back.weight, som.weight)
    assert back.config() == som.config()
    assert back.seeds == [40, 41] and back.initialized
    assert torch.equal(back.bmu(x3), som.bmu(x3))


def _collect(mode: str, x: torch.Tensor, **kw) -> list[StepInfo]:
    calls: list[StepInfo] = []
    SOM(ROWS, COLS, D, ensemble=2, seed=0).fit(x, callback=calls.append, **fit_kw(mode, **kw))
    return calls


@pytest.mark.parametrize("mode", MODES)
def test_callback_once_per_epoch_with_monotone_steps(mode, x3):
    epochs = FIT[mode]["epochs"]  # 240 samples, batch size 40: epochs are whole numbers of steps
    calls = _collect(mode, x3)
    assert len(calls) == epochs
    assert all(isinstance(c, StepInfo) for c in calls)
    steps = [c.step for c in calls]
    assert steps == sorted(set(steps)) and steps[-1] == calls[-1].total
    assert [c.epoch for c in calls] == pytest.approx(list(range(1, epochs + 1)))
    for c in calls:
        assert c.lr.shape == (2,) and c.sigma.shape == (2,) and c.weight.shape == (2, ROWS * COLS, D)
    sig = [float(c.sigma[0]) for c in calls]
    assert sig == sorted(sig, reverse=True) and sig[0] > sig[-1]


@pytest.mark.parametrize("mode,every", [("online", 100), ("batch", 4), ("minibatch", 5)])
def test_callback_every_and_at_the_end(mode, every, x3):
    calls = _collect(mode, x3, callback_every=every)
    total = calls[-1].total
    want = list(range(every, total, every)) + [total]
    assert [c.step for c in calls] == want


def test_minibatch_callback_once_per_epoch_when_batch_size_does_not_divide_n(x3):
    calls: list[StepInfo] = []
    SOM(ROWS, COLS, D, seed=0).fit(x3[:150], mode="minibatch", epochs=4, batch_size=32, progress=False,
                                   callback=calls.append)
    assert len(calls) == 4


def _slow_fit(mode: str, x: torch.Tensor, progress: bool) -> None:
    # a callback that sleeps makes the run last past the progress bar's 0.5 s delay
    kw = {**fit_kw(mode), "epochs": 4, "progress": progress}
    SOM(ROWS, COLS, D, seed=0).fit(x, callback=lambda info: time.sleep(0.25), **kw)


@pytest.mark.parametrize("mode", MODES)
def test_progress_false_prints_nothing(mode, x3, capsys):
    _slow_fit(mode, x3, progress=False)
    out, err = capsys.readouterr()
    assert out == "" and err == ""


def test_progress_true_does_print_on_long_runs(x3, capsys):
    # positive control for the test above: the same run with the bar on writes to stderr
    _slow_fit("batch", x3, progress=True)
    out, err = capsys.readouterr()
    assert out == "" and "SOM batch" in err
