"""The salient-object metrics against their definitions and the pysodmetrics package."""

from __future__ import annotations

import numpy as np
import pytest

from somtorch.saliency_metrics import f_measure, mae, s_measure, saliency_scores


def _masks(rng, h, w):
    out = []
    for _ in range(2):
        m = np.zeros((h, w), bool)
        y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
        m[y0:y0 + rng.integers(2, h // 2), x0:x0 + rng.integers(2, w // 2)] = True
        out.append(m)
    return out


def test_perfect_and_inverted_predictions():
    rng = np.random.default_rng(1)
    _, gt = _masks(rng, 40, 50)
    assert saliency_scores(gt, gt) == pytest.approx({"f_measure": 1.0, "mae": 0.0, "s_measure": 1.0})
    inv = saliency_scores(~gt, gt)
    assert inv["f_measure"] == pytest.approx(0.0) and inv["mae"] == pytest.approx(1.0) and inv["s_measure"] < 0.1
    with pytest.raises(ValueError, match="same 2-D shape"):
        mae(gt[:5], gt)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        f_measure(gt * 2.0, gt)


def test_matches_pysodmetrics():
    sod = pytest.importorskip("py_sod_metrics", reason="pysodmetrics (the oracle) not installed")
    rng = np.random.default_rng(0)
    for _ in range(30):
        h, w = (int(v) for v in rng.integers(10, 90, 2))
        pred, gt = _masks(rng, h, w)
        p8, g8 = pred.astype(np.uint8) * 255, gt.astype(np.uint8) * 255
        sm, fm, am = sod.Smeasure(), sod.Fmeasure(), sod.MAE()
        for m in (sm, fm, am):
            m.step(p8, g8)
        assert s_measure(pred, gt) == pytest.approx(sm.get_results()["sm"], abs=1e-9)
        assert f_measure(pred, gt) == pytest.approx(fm.get_results()["fm"]["adp"], abs=1e-9)
        assert mae(pred, gt) == pytest.approx(am.get_results()["mae"], abs=1e-12)
