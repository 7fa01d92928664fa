"""Config fuzzing: every value a field's declared constraint accepts must either run the pipeline
or be refused with a one-line ``ValueError`` naming the problem — never a raw ``IndexError``,
``RuntimeError`` or a crash deep in the object step (``objects.map_stride=100000`` once was one)."""

from __future__ import annotations

import random

import pytest
import torch

from somtorch.config import PipelineConfig, with_overrides
from somtorch.constraints import Choice, Flag, Interval, OneOf
from somtorch.disparity.resize import resize_scene
from somtorch.disparity import load_scene
from somtorch.pipeline import run_pipeline

GROUPS = ("features", "som", "train", "ground", "objects", "reduction")
SKIP = {"train.parallel", "features.color_weight"}  # needs a process group / an image: own tests


@pytest.fixture(scope="module")
def small():
    """A small real map and the same with an invalid left band and top row (as OAK-D maps have)."""
    from dataclasses import replace

    scene = resize_scene(load_scene("motorcycle"), 96, 64)
    valid = scene.valid.clone()
    valid[:, :20] = False
    valid[0, :] = False
    return [scene, replace(scene, valid=valid, name="banded")]


def _fields() -> list[tuple[str, object]]:
    base = PipelineConfig()
    out = []
    for g in GROUPS:
        cfg = getattr(base, g)
        for name, con in getattr(type(cfg), "_constraints", {}).items():
            key = f"{g}.{name}"
            if key not in SKIP:
                out.append((key, con))
    return out


def _value(con, rng: random.Random):
    if isinstance(con, Flag):
        return rng.random() < 0.5
    if isinstance(con, OneOf):
        return rng.choice(list(con.values))
    if isinstance(con, Choice):
        return rng.choice(sorted(con.names()))
    if isinstance(con, Interval):
        if con.optional and rng.random() < 0.15:
            return None
        lo = 0.0 if con.lo is None else float(con.lo)
        hi = (lo + rng.choice([1.0, 10.0, 1000.0])) if con.hi is None else float(con.hi)
        pick = rng.random()
        if pick < 0.2:
            v = lo
        elif pick < 0.35:
            v = hi
        elif pick < 0.5:
            v = lo + (hi - lo) * 1e-6
        else:
            v = rng.uniform(lo, hi)
        if con.integer:
            v = int(round(v))
            v = v + 1 if con.open_lo and con.lo is not None and v <= con.lo else v
            if con.hi is None:  # keep the runs small, but try absurd strides / counts now and then
                return 100_000 if rng.random() < 0.05 else min(v, 64)
            return v
        if con.open_lo and con.lo is not None and v <= con.lo:
            v = con.lo + 1e-3 * max(1.0, abs(hi - lo))
        if con.open_hi and con.hi is not None and v >= con.hi:
            v = con.hi - 1e-3 * max(1.0, abs(hi - lo))
        return v
    raise AssertionError(f"no generator for {con!r}")


def _case(i: int, small, fields) -> None:
    rng = random.Random(i)
    picks = dict(rng.sample(fields, k=rng.randint(1, 4)))
    overrides = {k: _value(c, rng) for k, c in picks.items()}
    overrides.setdefault("train.epochs", 2)
    overrides["train.epochs"] = min(int(overrides["train.epochs"]), 3)
    try:
        cfg = with_overrides(PipelineConfig(), overrides)
    except (ValueError, TypeError):
        return  # refused when the config is built (a relation between fields): fine
    scene = small[i % len(small)]
    try:
        res = run_pipeline(scene, cfg, metrics=False)
    except ValueError as exc:
        assert str(exc).strip() and "\n" not in str(exc).strip(), (overrides, exc)
        return
    except Exception as exc:  # noqa: BLE001 - the point of the test
        raise AssertionError(f"case {i} {overrides}: {type(exc).__name__}: {exc}") from exc
    m = res.members[0]
    assert m.kept, overrides  # something is always kept (the whole map at worst)
    h, w = scene.disparity.shape
    for a in m.kept:
        x0, y0, x1, y1 = a.box
        assert 0 <= x0 <= x1 < w and 0 <= y0 <= y1 < h, (overrides, a.box)
    assert 0.0 <= m.reduction.reduction_union <= 100.0


def test_pipeline_survives_random_valid_configs(small):
    torch.manual_seed(0)
    fields = _fields()
    assert {"objects.map_stride", "objects.max_areas", "objects.keep_budget"} <= {k for k, _ in fields}
    for i in range(60):
        _case(i, small, fields)


@pytest.mark.fuzz
def test_pipeline_survives_2000_random_valid_configs(small):
    fields = _fields()
    for i in range(2000):
        _case(10_000 + i, small, fields)
