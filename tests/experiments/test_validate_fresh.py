"""The protocol's fresh seeds: the defaults, and an adopted choice, scored again on runs nothing was
chosen on (``experiments.validate.score_fresh_seeds``), and how the report reads them."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from experiments.datasets import frames, load_frame
from experiments.validate import ValidateConfig, evaluate, shifted_frame, score_fresh_seeds
from experiments.validate_cache import SceneCache
from experiments.validate_report import _fresh_markdown

ROOT = Path(__file__).resolve().parents[2]
FRAMES = ["kitti_est", "oakd_toy", "eth3d_terrace_sgbm"]


def _cfg(**kw):
    cfg = ValidateConfig(ensemble=2, workers=1, n_boot=200, frames=FRAMES, **kw)
    return replace(cfg, train=replace(cfg.train, epochs=3))


def test_fresh_seeds_score_the_next_seeds_and_decide_the_choice_there(shared_data):
    cfg = _cfg(seed=3)
    specs = frames(names=FRAMES)
    choice = {"objects.merge": 0.0}
    got = score_fresh_seeds(specs, cfg, {"objects.merge": [0.0]}, {"objects.merge": 0.75}, choice,
                            Path(shared_data))
    assert got["seeds"] == [5, 6] and got["choice"] == choice and got["shift"] == cfg.fresh_shift == 5
    # the rates are those of the seeds after the chosen-on ones, on the frames shifted by 5 px, computed
    # directly
    fresh_base = replace(cfg, seed=5)
    for spec in specs:
        given = load_frame(spec, shared_data)
        scene = shifted_frame(spec, Path(shared_data), 5)
        assert scene.disparity.shape == (given.height - 5, given.width - 5)
        assert torch.equal(scene.disparity, given.disparity[5:, 5:])
        assert shifted_frame(spec, Path(shared_data), 0).disparity.shape == given.disparity.shape
        cache = SceneCache(spec, scene, fresh_base, ceilings=False)
        for part, ov in (("default", {}), ("in_sample", choice)):
            s = cache.score(ov)
            assert s["runs"] == 2 and [m.seed for m in cache.members(ov)[1]] == [5, 6]
            assert got["datasets"][spec.dataset][f"{part}_useful_hits"] == pytest.approx(s["useful_hits"] / 2)
        assert "first_place_hits" not in cache.score({})  # no ceilings on the fresh seeds
    # one frame per dataset: the macro is the mean over the three real datasets
    per = [got["datasets"][d]["default_useful_hits"] for d in ("kitti2015", "oakd", "eth3d")]
    assert got["macro_real"]["default_useful_hits"] == pytest.approx(sum(per) / 3)
    dec = got["decision"]
    assert got["confirmed"] is bool(dec["adopt"]) and len(dec["useful"]) == 3
    want = sum(got["datasets"][d]["in_sample_useful_hits"] - got["datasets"][d]["default_useful_hits"]
               for d in ("kitti2015", "oakd", "eth3d")) / 3
    assert dec["useful"][0] == pytest.approx(want)  # the paired difference of the fresh runs
    # the report: both seed sets side by side, and the verdict on the choice
    report = {"rule": {"seed": 3, "ensemble": 2}, "fresh_seeds": got,
              "summary": {"datasets": {d: dict(v) for d, v in got["datasets"].items()},
                          "macro_real": dict(got["macro_real"]), "macro_all": dict(got["macro_all"])}}
    md = "\n".join(_fresh_markdown(report))
    assert "seeds 5–6, each frame on a pixel grid shifted by 5 px (`shift:5`" in md
    assert "chose on seeds 3–4" in md
    assert ("| dataset | default useful | **fresh seeds** | default all-obj | **fresh seeds** | "
            "in-sample useful |") in md
    assert ("**confirmed**" if got["confirmed"] else "**not confirmed**") in md
    got["choice"], got["decision"], got["confirmed"] = {}, None, None
    assert "in-sample" not in "\n".join(_fresh_markdown(report))  # no choice: the defaults only


def test_an_adopted_choice_is_decided_again_on_fresh_seeds_and_its_verdict_says_how(shared_data, tmp_path):
    """On Middlebury 2005/2006's GT frames, a base whose margins swallow every reduction (tolerance 0.1
    of the diagonal) against the default margin: the protocol adopts the default on the seeds chosen on; the fresh seeds decide it
    again, by the same rule, and the knob's verdict and validate.md read that decision. One map per
    run (the protocol's mechanics, not the pipeline's defaults, are under test: 14 s instead of 83)."""
    gt = [f.name for f in frames(["middlebury_2005_2006"]) if not f.name.endswith("_sgbm")]  # 20 frames
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.validate", f"hydra.run.dir={tmp_path}", "ensemble=2", "consensus=1",
         "train.epochs=3", f"frames=[{','.join(gt)}]", f"paths.data_dir={shared_data}", "n_boot=500",
         "~grid", "~neutral", "reduction.tolerance_image=0.1", "+grid={reduction.tolerance_image: [0.015]}",
         "baselines=[]"],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rep = json.loads((tmp_path / "validate.json").read_text())
    assert rep["in_sample_choice"] == {"reduction.tolerance_image": 0.015}
    fresh = rep["fresh_seeds"]
    assert fresh["seeds"] == [2, 3] and fresh["choice"] == rep["in_sample_choice"]
    dec = fresh["decision"]
    assert fresh["confirmed"] is dec["adopt"] and (dec["adopt"] or dec["reasons"])
    d = fresh["datasets"]["middlebury_2005_2006"]
    assert dec["useful"][0] == pytest.approx(d["in_sample_useful_hits"] - d["default_useful_hits"])
    verdict = rep["knobs"]["reduction.tolerance_image"]["verdict"]
    assert verdict == "adopt reduction.tolerance_image=0.015" + ("" if fresh["confirmed"] else
                                                                 " (not confirmed on fresh seeds)")
    md = (tmp_path / "validate.md").read_text()
    said = "**confirmed** (adopted again)" if fresh["confirmed"] else "**not confirmed**: not adopted there ("
    assert said in md
    line = f"in-sample choice {'is' if fresh['confirmed'] else 'is NOT'} confirmed there"
    assert line in proc.stdout + proc.stderr


def test_validate_command_reads_the_fresh_seeds_and_skips_them_when_asked(shared_data, tmp_path):
    args = [sys.executable, "-m", "experiments.validate", "ensemble=2", "train.epochs=3", "n_boot=200",
            f"frames=[{','.join(FRAMES)}]", f"paths.data_dir={shared_data}", "~grid", "~neutral",
            "baselines=[]"]
    runs = {}
    for name, extra in (("on", []), ("off", ["fresh_seeds=false"]),
                        ("seed2", ["seed=2", "fresh_seeds=false", 'transforms=["shift:5"]']),
                        ("moved", ["seed=2", "fresh_seeds=false", "frame_shift=5",
                                   f"scores_out={tmp_path / 'moved.json'}"])):
        proc = subprocess.run(args + [f"hydra.run.dir={tmp_path / name}"] + extra, cwd=ROOT,
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs[name] = (json.loads((tmp_path / name / "validate.json").read_text()), proc.stdout + proc.stderr)
    rep, log_text = runs["on"]
    fresh = rep["fresh_seeds"]
    assert fresh["seeds"] == [2, 3] and fresh["confirmed"] is None  # no choice adopted on no grid
    # the fresh pass's figures are what a run on those seeds reads on the frames shifted by 5 px (one
    # frame per dataset: the dataset's rate is its frame's)
    shifted = runs["seed2"][0]["robustness"]["shift:5"]
    dataset = {f.name: f.dataset for f in frames(names=FRAMES)}
    assert fresh["shift"] == 5 and set(shifted) == set(FRAMES)
    for name, sc in shifted.items():
        want = sc["useful_hits"] / sc["runs"]
        assert fresh["datasets"][dataset[name]]["default_useful_hits"] == pytest.approx(want)
    want = (f"on fresh seeds (2-3, grid shifted 5 px): real macro useful-hit rate of the defaults "
            f"{100 * fresh['macro_real']['default_useful_hits']:.1f} % "
            f"({100 * rep['summary']['macro_real']['default_useful_hits']:.1f} % on the seeds chosen on)")
    assert want in log_text + "".join(p.read_text() for p in (tmp_path / "on").glob("*.log"))
    assert "On fresh seeds" in (tmp_path / "on" / "validate.md").read_text()
    off = runs["off"][0]
    assert off["fresh_seeds"] is None
    assert "On fresh seeds" not in (tmp_path / "off" / "validate.md").read_text()
    assert off["summary"] == rep["summary"]  # the fresh pass changes nothing of the main tables
    # the whole protocol on a shifted grid: its defaults are the shift:5 transform's scores
    moved = runs["moved"][0]
    assert moved["rule"]["frame_shift"] == 5
    assert {r["frame"]: r["default"]["useful_hits"] for r in moved["rows"]} == \
        {name: sc["useful_hits"] for name, sc in shifted.items()}
    said = (tmp_path / "moved" / "validate.md").read_text()
    assert "Every frame read on a pixel grid shifted by 5 px" in said
    # its scores resume only a run on the same grid
    with pytest.raises(ValueError, match="frame_shift=5, this run reads frame_shift=0"):
        evaluate(replace(_cfg(seed=2, fresh_seeds=False), resume=str(tmp_path / "moved.json"),
                         paths=replace(_cfg().paths, data_dir=str(shared_data))))


def test_a_grid_shift_the_frames_cannot_take_fails_before_any_work(shared_data, tmp_path):
    for name in ("fresh_shift", "frame_shift"):
        for bad in (-1, 2.5, True):
            with pytest.raises(ValueError, match=f"{name}=.*whole number of px, 0 or more"):
                evaluate(_cfg(**{name: bad}))
    # too large for the frames: named by the check that reads every frame before any training (the
    # fresh pass itself, after the main one, would fail with add_junk's message alone)
    cfg = replace(_cfg(fresh_shift=10_000), paths=replace(_cfg().paths, data_dir=str(shared_data)))
    with pytest.raises(ValueError, match=r"fresh_shift: a shift of 10000 px on frame '\w+'.*half its"):
        evaluate(cfg)
    cfg = replace(cfg, fresh_shift=5, frame_shift=9_995)  # the fresh pass reads both shifts
    with pytest.raises(ValueError, match=r"frame_shift: a shift of 9995 px on frame '\w+'.*half its shorter"):
        evaluate(cfg)
    with pytest.raises(ValueError, match=r"frame_shift=5 with an sgbm: transform"):
        evaluate(replace(cfg, frame_shift=5, transforms=["sgbm:raw"]))
