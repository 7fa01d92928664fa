"""Bad input fails at the public boundary with a ValueError/TypeError naming the argument, before any work.

"Before any work" is checked three ways after each failing call: the weights are unchanged, the
``initialized`` flag is unchanged, and a following good ``fit`` gives exactly what a fresh map with the
same seed gives (so no random numbers were drawn either).
"""

from __future__ import annotations

import re

import pytest
import torch

from somtorch import SOM, DataFileError
from somtorch.core import DECAYS, MODES, NEIGHBORHOODS
from somtorch.core.init import INITS
from somtorch.core.som import ORDERS

R, C, D, E = 3, 4, 3, 2
GOOD = {"mode": "minibatch", "epochs": 1, "batch_size": 16, "progress": False}  # draws random numbers


@pytest.fixture
def x() -> torch.Tensor:
    return torch.rand(60, D, generator=torch.Generator().manual_seed(0))


def new_som(**kw) -> SOM:
    return SOM(R, C, D, ensemble=E, seed=3, **kw)


def assert_rejected(som: SOM, x: torch.Tensor, exc: type[Exception], words: list[str], call) -> str:
    """``call()`` raises ``exc`` whose message holds every word (as whole words); ``som`` is unchanged."""
    before = som.weight.detach().clone()
    was_init = som.initialized
    with pytest.raises(exc) as info:
        call()
    msg = str(info.value)
    for w in words:  # as a whole word: "x" must not be found inside "expected"
        assert re.search(rf"(?<!\w){re.escape(w)}(?!\w)", msg), (w, msg)
    assert torch.equal(som.weight.detach(), before)
    assert som.initialized == was_init
    if not was_init:  # untouched generators: the next good fit equals a fresh map's
        assert torch.equal(som.fit(x, **GOOD).weight, new_som().fit(x, **GOOD).weight)
    return msg


# ------------------------------------------------------------------------------ the data x
@pytest.mark.parametrize("shape,word", [((D,), "dimensions"), ((1, E, 5, D), "dimensions"),
                                        ((10, D + 1), "last dimension"), ((E + 1, 10, D), "ensemble size")])
def test_x_of_wrong_shape(x, shape, word):
    som = new_som()
    bad = torch.rand(*shape)
    assert_rejected(som, x, ValueError, ["x", word, str(tuple(shape))], lambda: som.fit(bad, progress=False))
    som.initialize(x)
    for method in (som.bmu, som.quantization_error, som.topographic_error, som.forward, som.loss):
        assert_rejected(som, x, ValueError, ["x"], lambda: method(bad))


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_x_with_non_finite_values(x, value):
    som = new_som()
    bad = x.clone()
    bad[7, 1] = value
    msg = assert_rejected(som, x, ValueError, ["x", "non-finite", "(7, 1)"],
                          lambda: som.fit(bad, progress=False))
    assert "1 non-finite" in msg
    assert_rejected(som, x, ValueError, ["x"], lambda: som.initialize(bad))
    som.initialize(x)
    assert_rejected(som, x, ValueError, ["x"], lambda: som.quantization_error(bad))


@pytest.mark.parametrize("shape", [(0, D), (E, 0, D)])
def test_x_with_zero_rows(x, shape):
    som = new_som()
    assert_rejected(som, x, ValueError, ["x", "empty"], lambda: som.fit(torch.zeros(shape), progress=False))


def test_x_of_other_dtype_or_not_a_tensor(x):
    som = new_som()
    assert_rejected(som, x, TypeError, ["x", "float64", "float32"],
                    lambda: som.fit(x.double(), progress=False))
    assert_rejected(som, x, TypeError, ["x", "floating"], lambda: som.fit((x * 10).long(), progress=False))
    assert_rejected(som, x, TypeError, ["x", "torch.Tensor"], lambda: som.fit(x.numpy(), progress=False))
    s64 = SOM(R, C, D, dtype=torch.float64, seed=0)
    with pytest.raises(TypeError, match="x has dtype torch.float32"):
        s64.bmu(x)


# ------------------------------------------------------------------------------ constructor
@pytest.mark.parametrize("kw,exc,word", [
    ({"rows": 0}, ValueError, "rows"), ({"rows": -2}, ValueError, "rows"), ({"cols": 0}, ValueError, "cols"),
    ({"rows": 2.5}, TypeError, "rows"), ({"cols": "4"}, TypeError, "cols"),
    ({"rows": True}, TypeError, "rows"),
    ({"dim": 0}, ValueError, "dim"), ({"ensemble": 0}, ValueError, "ensemble"),
    ({"topology": "triangular"}, ValueError, "hexagonal, rectangular"),
    ({"toroidal": 1}, TypeError, "toroidal"),
    ({"dtype": torch.int32}, TypeError, "dtype"), ({"seed": 1.5}, TypeError, "seed"),
    ({"seeds": [1, 2, 3]}, ValueError, "seeds"), ({"seed": 1, "seeds": [1, 2]}, ValueError, "seeds"),
])
def test_constructor_arguments(kw, exc, word):
    args = {"rows": R, "cols": C, "dim": D, "ensemble": E, **kw}
    with pytest.raises(exc, match=re.escape(word)):
        SOM(args.pop("rows"), args.pop("cols"), args.pop("dim"), **args)


# ------------------------------------------------------------------------------ hyper-parameters of fit
@pytest.mark.parametrize("name", ["lr", "sigma", "lr_final", "sigma_final"])
@pytest.mark.parametrize("value", [0.0, -0.5, float("nan"), float("inf"), torch.tensor([0.1, -0.1])])
def test_non_positive_rates_and_radii(x, name, value):
    som = new_som()
    assert_rejected(som, x, ValueError, [name], lambda: som.fit(x, **{**GOOD, name: value}))


@pytest.mark.parametrize("name", ["lr", "sigma", "lr_final", "sigma_final"])
def test_per_member_tensor_of_wrong_length(x, name):
    som = new_som()
    bad = torch.tensor([0.1, 0.2, 0.3])
    assert_rejected(som, x, ValueError, [name, f"[{E}]", "(3,)"], lambda: som.fit(x, **{**GOOD, name: bad}))
    assert_rejected(som, x, ValueError, [name], lambda: som.fit(x, **{**GOOD, name: torch.ones(E, 1)}))


def test_hyper_parameter_of_wrong_type(x):
    som = new_som()
    assert_rejected(som, x, TypeError, ["lr"], lambda: som.fit(x, **{**GOOD, "lr": "0.5"}))
    assert_rejected(som, x, TypeError, ["sigma"], lambda: som.fit(x, **{**GOOD, "sigma": [1.0, 2.0]}))
    assert_rejected(som, x, TypeError, ["batch_size"], lambda: som.fit(x, **{**GOOD, "batch_size": 8.0}))
    assert_rejected(som, x, ValueError, ["epochs"], lambda: som.fit(x, **{**GOOD, "epochs": 0}))
    assert_rejected(som, x, ValueError, ["iterations"], lambda: som.fit(x, mode="online", iterations=0))
    assert_rejected(som, x, TypeError, ["callback"], lambda: som.fit(x, **GOOD, callback=3))
    assert_rejected(som, x, ValueError, ["callback_every"], lambda: som.fit(x, **GOOD, callback=print,
                                                                           callback_every=0))


@pytest.mark.parametrize("arg,registry", [("lr_decay", DECAYS), ("sigma_decay", DECAYS),
                                          ("neighborhood", NEIGHBORHOODS), ("mode", MODES),
                                          ("order", ORDERS), ("init", INITS)])
def test_unknown_option_names_list_the_valid_ones(x, arg, registry):
    som = new_som()
    kw = {**GOOD, arg: "nonsense"}
    msg = assert_rejected(som, x, ValueError, [arg, "'nonsense'", *registry], lambda: som.fit(x, **kw))
    assert "valid names" in msg


def test_per_member_decay_list_of_wrong_length_or_with_a_bad_name(x):
    som = new_som()
    assert_rejected(som, x, ValueError, ["sigma_decay", str(E)],
                    lambda: som.fit(x, **GOOD, sigma_decay=["linear"] * (E + 1)))
    assert_rejected(som, x, ValueError, ["lr_decay", "asymptotic"],
                    lambda: som.fit(x, **GOOD, lr_decay=["linear", "fast"]))


def test_iterations_only_for_online(x):
    som = new_som()
    for mode in ("batch", "minibatch"):
        assert_rejected(som, x, ValueError, ["iterations", mode],
                        lambda: som.fit(x, mode=mode, iterations=100, progress=False))


# ------------------------------------------------------------------------------ explicit orders
def test_explicit_order_out_of_range_wrong_length_or_type(x):
    som = new_som()
    n = x.shape[0]
    online = {"mode": "online", "iterations": 100, "progress": False}
    ok = torch.arange(100) % n
    too_big = ok.clone()
    too_big[50] = n
    negative = ok.clone()
    negative[3] = -1
    assert_rejected(som, x, ValueError, ["order", f"[0, {n})", f"max {n}"],
                    lambda: som.fit(x, order=too_big, **online))
    assert_rejected(som, x, ValueError, ["order", "min -1"], lambda: som.fit(x, order=negative, **online))
    assert_rejected(som, x, ValueError, ["order", "(100,)", "(99,)"],
                    lambda: som.fit(x, order=ok[:99], **online))
    assert_rejected(som, x, ValueError, ["order", f"({E}, 100)"],
                    lambda: som.fit(x, order=ok.expand(E + 1, -1), **online))
    assert_rejected(som, x, TypeError, ["order", "integer"], lambda: som.fit(x, order=ok.float(), **online))
    assert_rejected(som, x, ValueError, ["order", "batch"],
                    lambda: som.fit(x, mode="batch", order=torch.arange(n), progress=False))
    # minibatch: steps * batch_size entries (1 epoch of 60 at 16 -> 3 steps -> 48)
    assert_rejected(som, x, ValueError, ["order", "(48,)"],
                    lambda: som.fit(x, **GOOD, order=torch.arange(60)))
    solo = SOM(R, C, D, seed=3)
    solo.fit(x, **GOOD, order=torch.arange(48))  # the right length is accepted
    assert solo.initialized


# ------------------------------------------------------------------------------ weights and other methods
def test_setting_weight_of_wrong_shape(x):
    som = new_som().initialize(x)
    for shape in [(R * C, D + 1), (E + 1, R * C, D), (R * C + 1, D), (D,), (1, 1, R * C, D)]:
        assert_rejected(som, x, ValueError, ["weight"], lambda: setattr(som, "weight", torch.rand(*shape)))
    bad = torch.rand(R * C, D)
    bad[0, 0] = float("nan")
    assert_rejected(som, x, ValueError, ["weight", "non-finite"], lambda: setattr(som, "weight", bad))
    ints = torch.ones(R * C, D, dtype=torch.long)
    assert_rejected(som, x, TypeError, ["weight"], lambda: setattr(som, "weight", ints))
    som.weight = torch.zeros(R * C, D)  # the right shapes still work and broadcast to all members
    assert torch.equal(som.weight, torch.zeros(E, R * C, D))


def test_initialize_options(x):
    som = new_som()
    assert_rejected(som, x, ValueError, ["method", "pca, random, sample"],
                    lambda: som.initialize(x, "kmeans"))
    one = SOM(2, 2, 1, seed=0)
    with pytest.raises(ValueError, match="pca"):
        one.initialize(torch.rand(10, 1), "pca")
    assert not one.initialized


def test_loss_and_soft_assign_arguments(x):
    som = new_som().initialize(x)
    assert_rejected(som, x, ValueError, ["sigma"], lambda: som.loss(x, sigma=0.0))
    assert_rejected(som, x, ValueError, ["neighborhood", "gaussian"],
                    lambda: som.loss(x, neighborhood="flat"))
    assert_rejected(som, x, ValueError, ["temperature"], lambda: som.soft_assign(x, temperature=-1.0))


def test_member_index_out_of_range():
    with pytest.raises(IndexError, match="member 2"):
        new_som().member(2)


# ------------------------------------------------------------------------------ files
def test_load_non_safetensors_and_missing_files(tmp_path):
    junk = tmp_path / "weights.safetensors"
    junk.write_text("this is text, not a safetensors file")
    with pytest.raises(DataFileError, match=re.escape(str(junk))):
        SOM.load(junk)
    with pytest.raises(FileNotFoundError, match="missing.safetensors"):
        SOM.load(tmp_path / "missing.safetensors")
