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
    # by default the fresh pass reads a grid 3 px beyond the protocol's last (0 and 5 px): 8 px
    assert got["seeds"] == [5, 6] and got["choice"] == choice and got["shift"] == 8
    assert got["shift"] == max(cfg.frame_shifts) + cfg.fresh_shift
    # the rates are those of the seeds after the chosen-on ones, on the frames shifted by 8 px, computed
    # directly
    fresh_base = replace(cfg, seed=5)
    for spec in specs:
        given = load_frame(spec, shared_data)
        scene = shifted_frame(spec, Path(shared_data), 8)
        assert scene.disparity.shape == (given.height - 8, given.width - 8)
        assert torch.equal(scene.disparity, given.disparity[8:, 8:])
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
    assert "seeds 5–6, each frame on a pixel grid shifted by 8 px (`shift:8`" in md
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
         "frame_shifts=[0]",
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


def test_validate_command_decides_on_two_grids_and_reads_the_fresh_seeds_on_a_third(shared_data, tmp_path):
    args = [sys.executable, "-m", "experiments.validate", "ensemble=2", "train.epochs=3", "n_boot=200",
            f"frames=[{','.join(FRAMES)}]", f"paths.data_dir={shared_data}", "~grid", "~neutral",
            "baselines=[plane_components]"]
    runs = {}
    for name, extra in (("on", []), ("off", ["fresh_seeds=false", f"scores_out={tmp_path / 'two.json'}"]),
                        ("given", ["fresh_seeds=false", "frame_shifts=[0]", 'transforms=["shift:5"]']),
                        ("seed2", ["seed=2", "fresh_seeds=false", "frame_shifts=[0]",
                                   'transforms=["shift:8"]', "baselines=[]"])):
        proc = subprocess.run(args + [f"hydra.run.dir={tmp_path / name}"] + extra, cwd=ROOT,
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs[name] = (json.loads((tmp_path / name / "validate.json").read_text()), proc.stdout + proc.stderr)
    rep, log_text = runs["on"]
    assert rep["rule"]["frame_shifts"] == [0, 5]  # the protocol's default grids
    # each frame's scores are its runs on the frames as given plus its runs on the grid shifted by 5 px
    # (the shift:5 transform's), the baseline's likewise: the protocol decides on both grids at once
    given = runs["given"][0]
    moved = given["robustness"]["shift:5"]
    for row, one in zip(rep["rows"], given["rows"]):
        assert row["frame"] == one["frame"]
        d, sc = row["default"], moved[row["frame"]]
        assert d["runs"] == 4 and d["useful_hits"] == one["default"]["useful_hits"] + sc["useful_hits"]
        assert d["all_objects_hits"] == one["default"]["all_objects_hits"] + sc["all_objects_hits"]
        assert d["x_opt"] == pytest.approx((one["default"]["x_opt"] + sc["x_opt"]) / 2)
        assert d["n_objects"] == one["default"]["n_objects"]
        pc = row["baselines"]["plane_components"]
        assert pc["runs"] == 2
        assert pc["useful_hits"] == (one["baselines"]["plane_components"]["useful_hits"]
                                     + sc["baselines"]["plane_components"]["useful_hits"])
    on0 = rep["grids"]["0"]["macro_real"]
    assert on0 == pytest.approx(given["summary"]["macro_real"]["default_useful_hits"])
    assert rep["summary"]["macro_real"]["default_useful_hits"] == pytest.approx(
        (on0 + rep["grids"]["5"]["macro_real"]) / 2)  # one frame a dataset: the macro is the grids' mean
    said = (tmp_path / "on" / "validate.md").read_text()
    assert "Every frame read on the pixel grids shifted by 0, 5 px (`frame_shifts`" in said
    assert f"0 px: real {100 * on0:.1f} %" in said
    for d, x in given["summary"]["datasets"].items():  # each grid per dataset: as given, and shifted 5 px
        assert rep["grids"]["0"]["datasets"][d] == pytest.approx(x["default_useful_hits"])
        five = [moved[r["frame"]] for r in given["rows"] if r["dataset"] == d]
        assert rep["grids"]["5"]["datasets"][d] == pytest.approx(
            sum(m["useful_hits"] / m["runs"] for m in five) / len(five))
        assert (f"| {d} | {100 * x['default_useful_hits']:.1f} | "
                f"{100 * rep['grids']['5']['datasets'][d]:.1f} |") in said
    fresh = rep["fresh_seeds"]
    assert fresh["seeds"] == [2, 3] and fresh["confirmed"] is None  # no choice adopted on no grid
    # the fresh pass's figures are what a run on those seeds reads on the frames shifted by 8 px (one
    # frame per dataset: the dataset's rate is its frame's)
    shifted = runs["seed2"][0]["robustness"]["shift:8"]
    dataset = {f.name: f.dataset for f in frames(names=FRAMES)}
    assert fresh["shift"] == 8 and set(shifted) == set(FRAMES)
    for name, sc in shifted.items():
        want = sc["useful_hits"] / sc["runs"]
        assert fresh["datasets"][dataset[name]]["default_useful_hits"] == pytest.approx(want)
    want = (f"on fresh seeds (2-3, grid shifted 8 px): real macro useful-hit rate of the defaults "
            f"{100 * fresh['macro_real']['default_useful_hits']:.1f} % "
            f"({100 * rep['summary']['macro_real']['default_useful_hits']:.1f} % on the seeds chosen on)")
    assert want in log_text + "".join(p.read_text() for p in (tmp_path / "on").glob("*.log"))
    assert "On fresh seeds" in said and "of the frames on the grids shifted by 0, 5 px" in said
    off = runs["off"][0]
    assert off["fresh_seeds"] is None
    assert "On fresh seeds" not in (tmp_path / "off" / "validate.md").read_text()
    assert off["summary"] == rep["summary"]  # the fresh pass changes nothing of the main tables
    # the scores file keeps each grid's scores apart and resumes only a run on the same grids
    two = json.loads((tmp_path / "two.json").read_text())
    assert two["__frame_shifts__"] == [0, 5] and {f"{f}@5" for f in FRAMES} <= set(two)
    assert two["oakd_toy@5"]["default"]["useful_hits"] == moved["oakd_toy"]["useful_hits"]
    with pytest.raises(ValueError, match=r"frame_shifts=\[0, 5\], this run reads frame_shifts=\[0\]"):
        evaluate(replace(_cfg(seed=2, fresh_seeds=False, frame_shifts=[0]), resume=str(tmp_path / "two.json"),
                         paths=replace(_cfg().paths, data_dir=str(shared_data))))


def test_a_grid_shift_the_frames_cannot_take_fails_before_any_work(shared_data, tmp_path):
    for name, bads in (("fresh_shift", (-1, 2.5, True)), ("frame_shifts", ([0, -1], [2.5], [True]))):
        for bad in bads:
            with pytest.raises(ValueError, match=f"{name}: .*whole number of px, 0 or more"):
                evaluate(_cfg(**{name: bad}))
    for bad in ([], [0, 5, 0]):
        with pytest.raises(ValueError, match=r"frame_shifts=.*give each grid once, at least one"):
            evaluate(_cfg(frame_shifts=bad))
    # too large for the frames: named by the check that reads every frame before any training (the
    # fresh pass itself, after the main one, would fail with add_junk's message alone)
    cfg = replace(_cfg(fresh_shift=10_000), paths=replace(_cfg().paths, data_dir=str(shared_data)))
    with pytest.raises(ValueError, match=r"fresh_shift: a shift of 10005 px on frame '\w+'.*half its"):
        evaluate(cfg)
    cfg = replace(cfg, fresh_shift=5, frame_shifts=[0, 9_990])  # checked before the fresh pass (9995 px)
    with pytest.raises(ValueError, match=r"frame_shifts: a shift of 9990 px on frame '\w+'.*half its"):
        evaluate(cfg)
    with pytest.raises(ValueError, match=r"frame_shifts=\[5\] with an sgbm: transform"):
        evaluate(replace(cfg, frame_shifts=[5], transforms=["sgbm:raw"]))
