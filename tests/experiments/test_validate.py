"""The leave-one-dataset-out protocol: the registry, the adoption rule on tables whose answer is
known, the segmentation cache, and the command end to end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from experiments.datasets import datasets, frames, load_frame
from experiments.protocol import FrameTable, decide, non_inferior
from experiments.validate_report import verdict
from experiments.validate import SceneCache
from somtorch.config import with_overrides
from somtorch.config import PipelineConfig

ROOT = Path(__file__).resolve().parents[2]


def _table(sizes, real):
    ds, groups, rl = [], [], []
    for (name, n), r in zip(sizes.items(), real):
        for i in range(n):
            ds.append(name)
            groups.append(f"{name}/{i}")
            rl.append(r)
    return FrameTable(ds, groups, rl, n_boot=2000, seed=0)


def test_a_fix_for_one_failure_class_that_harms_none_is_adopted():
    # three real datasets of 10 frames; the candidate gains 0.6 on 4 frames of one, changes nothing else
    t = _table({"a": 10, "b": 10, "c": 10}, [True, True, True])
    base = np.full(30, 0.4)
    cand = base.copy()
    cand[[0, 1, 2, 3]] += 0.6
    d = decide(t, cand, base, cand, base)
    assert d.adopt and d.useful[0] == pytest.approx(0.08) and d.useful[1] > 0, d
    # the same gain on two frames only is not evidence (a resample without both is too likely)
    cand[[2, 3]] = 0.4
    d = decide(t, cand, base, cand, base)
    assert not d.adopt and d.useful[1] == 0.0 and d.non_inferior, d


def test_a_gain_carried_by_two_frames_against_losses_elsewhere_is_not_adopted():
    t = _table({"a": 10, "b": 10, "c": 10}, [True, True, True])
    base = np.full(30, 0.6)
    cand = base.copy()
    cand[[0, 1]] += 0.4  # two frames gain 0.4 ...
    cand[[10, 13, 16, 20, 25]] -= 0.2  # ... five lose 0.2 in the other datasets
    d = decide(t, cand, base, cand, base)
    assert not d.adopt and d.useful[1] < 0 < d.useful[2], d


def test_a_dataset_losing_more_than_the_margin_blocks_adoption_even_with_a_clear_macro_gain():
    t = _table({"a": 10, "b": 10, "syn": 10}, [True, True, False])
    base = np.full(30, 0.5)
    cand = base.copy()
    cand[:20] += 0.3  # every real frame gains ...
    cand[20:] -= 0.2  # ... the synthetic dataset loses 0.2 > 0.10
    d = decide(t, cand, base, cand, base)
    assert d.useful[1] > 0 and not d.adopt and d.worst == ("syn", pytest.approx(-0.2)), d
    assert any("syn loses" in r for r in d.reasons)


def test_a_loss_of_exactly_the_margin_is_not_more_than_it_after_float_rounding():
    # 6 of 60 runs lost in a 12-frame dataset: the mean of the per-frame differences reads
    # -0.10000000000000002, which is a loss of 10 points, not more than the 10-point margin
    t = _table({"a": 12, "syn": 12}, [True, False])
    base = np.full(24, 0.6)
    cand = base.copy()
    cand[12:18] -= 0.2  # 6 frames of 5 runs lose one run each
    loss = t.per_dataset(cand - base)["syn"]
    assert loss < -0.1 and loss == pytest.approx(-0.1)  # the rounding this test is about
    d = decide(t, cand, base, cand, base)
    assert d.non_inferior and not any("loses" in r for r in d.reasons), d
    cand[18] -= 0.2  # one run more is more than the margin
    d = decide(t, cand, base, cand, base)
    assert not d.non_inferior and any("syn loses" in r for r in d.reasons), d


def test_a_gain_in_one_frame_of_a_one_scene_dataset_is_not_certain():
    # dataset "k" holds one scene in two versions (one group): its frames become the units
    t = FrameTable(["k", "k"] + ["m"] * 10, ["s", "s"] + [f"m{i}" for i in range(10)], [True] * 12, n_boot=2000)
    base = np.full(12, 0.5)
    cand = base.copy()
    cand[0] += 0.2
    d = decide(t, cand, base, cand, base)
    assert d.useful[0] == pytest.approx(0.05) and d.useful[1] == 0.0 and not d.adopt, d


def test_synthetic_gains_decide_only_where_no_real_frame_changes():
    t = _table({"a": 10, "syn": 10}, [True, False])
    base = np.full(20, 0.5)
    cand = base.copy()
    cand[10:] += 0.4  # the real frames are untouched: the evidence decides
    d = decide(t, cand, base, cand, base)
    assert d.adopt and d.useful == (0.0, 0.0, 0.0) and d.useful_all[0] == pytest.approx(0.2)
    cand[0] -= 0.2  # one real frame loses: the real data can tell, and the macro gain is not there
    d = decide(t, cand, base, cand, base)
    assert not d.adopt


def test_non_inferior_on_real_and_superior_on_all_is_adopted_by_the_second_path():
    # two real datasets: the candidate wins one frame and loses one (no real gain to show, no real
    # loss either); the synthetic datasets gain on 4 of 10 frames each: adopted by the second path
    t = _table({"a": 10, "b": 10, "s1": 10, "s2": 10}, [True, True, False, False])
    base = np.full(40, 0.5)
    cand = base.copy()
    cand[0] += 0.1
    cand[12] -= 0.1
    cand[[20, 21, 22, 23, 30, 31, 32, 33]] += 0.5
    d = decide(t, cand, base, cand, base)
    assert d.adopt and d.path == "all" and d.useful[1] > -0.02 and d.useful_all[1] > 0, d
    # the same synthetic gain with a real loss beyond the non-inferiority margin is not adopted
    cand[[10, 11, 13, 14, 15]] -= 0.2
    d = decide(t, cand, base, cand, base)
    assert not d.adopt and d.path == "" and d.useful[1] < -0.02, d
    # nor with a synthetic dataset losing more than the per-dataset margin
    cand = base.copy()
    cand[[20, 21, 22, 23, 24, 25, 26, 27]] += 0.5
    cand[30:] -= 0.15
    d = decide(t, cand, base, cand, base)
    assert not d.adopt and d.worst == ("s2", pytest.approx(-0.15)), d
    # the first path still reports itself
    cand = base.copy()
    cand[:20] += 0.3
    assert decide(t, cand, base, cand, base).path == "real"


def test_a_removal_that_costs_over_every_dataset_is_not_taken():
    # a check switched off: no real frame changes (non-inferior on real), but the synthetic datasets
    # lose on 4 of 10 frames each, an all-dataset interval wholly below zero: the wider evidence
    # refutes the removal (the second path's mirror); with the synthetic loss gone it is removable
    t = _table({"a": 10, "b": 10, "s1": 10, "s2": 10}, [True, True, False, False])
    base = np.full(40, 0.5)
    off = base.copy()
    off[[20, 21, 22, 23, 30, 31, 32, 33]] -= 0.2
    d = decide(t, off, base, off, base)
    assert d.non_inferior and d.useful == (0.0, 0.0, 0.0) and d.useful_all[2] < 0, d
    assert not d.removable and not non_inferior(d) and not d.adopt
    assert verdict("k", [{"neutral": True, **d.as_dict()}], {}, {"k": 0.0}) == "keep"
    off = base.copy()
    off[[20, 31]] -= 0.2  # a loss the interval cannot tell from none
    d = decide(t, off, base, off, base)
    assert d.removable and d.useful_all[1] < 0 <= d.useful_all[2], d
    assert verdict("k", [{"neutral": True, **d.as_dict()}], {}, {"k": 0.0}) == "remove"
    # a real loss beyond the margin is no removal, whatever the rest says
    off[[0, 1, 2, 3, 4, 5]] -= 0.3
    assert not decide(t, off, base, off, base).removable


def test_the_all_objects_reading_may_not_drop():
    t = _table({"a": 10, "b": 10}, [True, True])
    base = np.full(20, 0.5)
    d = decide(t, base + 0.2, base, base - 0.05, base)
    assert not d.adopt and any("all-objects" in r for r in d.reasons)


def test_the_macro_average_counts_each_dataset_once_and_groups_move_together():
    t = FrameTable(["a"] * 4 + ["b"], ["s1", "s1", "s2", "s3", "t1"], [True] * 5, n_boot=500)
    v = np.array([1.0, 0.0, 1.0, 1.0, 0.0])
    # a: groups s1 (mean 0.5), s2 (1), s3 (1) -> 5/6; b: 0 -> macro 5/12 whatever the frame counts
    assert t.per_dataset(v) == {"a": pytest.approx(5 / 6), "b": 0.0}
    point, lo, hi = t.macro(v)
    assert point == pytest.approx(5 / 12) and lo <= point <= hi
    assert t.subset(["b"]).names == ["b"]


def test_the_registry_groups_every_frame_by_dataset():
    specs = frames()
    assert len({s.name for s in specs}) == len(specs)
    names = [d.name for d in datasets()]
    for need in ("middlebury2014", "middlebury_2005_2006", "kitti2015", "eth3d", "oakd", "flyingthings3d",
                 "junk", "synth_stairs_oakd", "synth_garden_kitti"):
        assert need in names
    assert {d.name for d in datasets(real=True)} == {"middlebury2014", "middlebury_2005_2006", "kitti2015",
                                                     "eth3d", "oakd"}
    for s in specs:
        if s.disparity == "sgbm":
            assert s.left and s.right and s.ndisp % 16 == 0
        assert s.group, s
    # the GT and SGBM versions of one scene share a group (the bootstrap resamples scenes)
    mb = frames(datasets=["middlebury_2005_2006"])
    assert len(mb) % 2 == 0 and len({s.group for s in mb}) == len(mb) // 2
    with pytest.raises(ValueError, match="unknown frame"):
        frames(names=["nope"])
    with pytest.raises(ValueError, match="unknown dataset"):
        frames(datasets=["nope"])


def test_scene_cache_segments_once_per_upstream_setting(shared_data):
    spec = frames(names=["kitti"])[0]
    cache = SceneCache(spec, load_frame(spec, shared_data), PipelineConfig(ensemble=2))
    base = cache.score({})
    assert base["runs"] == 2 and 0 <= base["useful_hits"] <= 2 and base["x_opt"] > 0
    cache.score({"objects.merge": 0.5})
    assert len(cache._seg) == 1  # an object-step constant reuses the segmentation
    cache.score({"ground.max_below_frac": 1.0})
    assert len(cache._seg) == 2  # a ground constant does not
    assert cache.score({}) is base
    sal = cache.score({}, saliency=True)["saliency"]
    assert 0 <= sal["f_measure"] <= 1 and 0 <= sal["mae"] <= 1 and 0 <= sal["s_measure"] <= 1


@pytest.mark.parametrize("workers", [1, 2])
def test_a_candidate_scored_on_demand_leaves_no_segmentation_in_the_parent(shared_data, workers):
    """The protocol's greedy join asks for a candidate nobody scored up front: it is scored as the
    others were (in the workers), and the parent's caches keep its scores only — one segmentation
    kept per frame and grid outgrew 24 GiB on the corpus (session 43)."""
    from functools import partial
    from types import SimpleNamespace

    from experiments.validate_cache import GridCache, Protocol
    from experiments.validate_fresh import shifted_frame

    specs, shifts, base = frames(names=["kitti", "eth3d_terrace"]), (0, 5), PipelineConfig(ensemble=2)
    caches = [GridCache([SceneCache(s, None, base, loader=partial(shifted_frame, s, shared_data, sh),
                                    ceilings=False) for sh in shifts]) for s in specs]
    proto = Protocol(caches, SimpleNamespace(n_boot=200, seed=0, loss_margin=10.0, ni_margin=2.0,
                                             workers=workers), {}, {})
    cand = {"ground.max_below_frac": 1.0, "objects.merge": 0.5}  # a segmentation of its own
    rates = proto.rates(cand)
    assert all(not g._seg and g.labels is None and g._scene is None for c in caches for g in c.grids)
    ref = [[SceneCache(s, shifted_frame(s, shared_data, sh), base, ceilings=False).score(cand)
            for sh in shifts] for s in specs]
    assert rates.tolist() == [sum(r["useful_hits"] for r in f) / sum(r["runs"] for r in f) for f in ref]


def test_scene_cache_reads_a_noisy_frame_through_the_median_as_run_pipeline_does():
    """The protocol scores what the pipeline runs: a dense sensor's noisy frame is segmented and
    its object step run on the median-filtered map (features.median), in the cache as in
    run_pipeline; with median 0 neither filters."""
    import torch

    from experiments.datasets import FrameSpec
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import run_pipeline

    ys, xs = torch.meshgrid(torch.arange(96.0), torch.arange(128.0), indexing="ij")
    d = 30.0 + 0.02 * xs + 0.01 * ys
    objects = torch.zeros(96, 128, dtype=torch.long)
    d[30:60, 30:70] += 2.5
    objects[30:60, 30:70] = 1
    d = d + 0.5 * torch.randn(96, 128, generator=torch.Generator().manual_seed(3))
    scene = scene_from_arrays(d, torch.ones(96, 128, dtype=torch.bool), objects=objects, name="noisy_floor")
    cfg = PipelineConfig(ensemble=2)
    cache = SceneCache(FrameSpec(name="noisy_floor", dataset="t", real=False, folder="."), scene, cfg)
    for over in ({}, {"features.median": 0}):
        ground, members = cache.members(over)
        ref = run_pipeline(scene, with_overrides(cfg, over), metrics=False)
        assert ref.median == (0 if over else 3)
        assert [[(a.box, a.mean_disparity, a.contrast) for a in m.kept] for m in members] == \
            [[(a.box, a.mean_disparity, a.contrast) for a in m.kept] for m in ref.members]
        assert [m.reduction.reduction_union for m in members] == \
            [m.reduction.reduction_union for m in ref.members]


def test_validate_command_writes_the_left_out_tables(shared_data, tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.validate", f"hydra.run.dir={tmp_path}", "ensemble=2",
         "train.epochs=3", "frames=[kitti,kitti_est,oakd_toy,oakd_cycles,eth3d_terrace_sgbm]",
         f"paths.data_dir={shared_data}", "n_boot=200", "~grid", "~neutral",
         "+grid={objects.merge: [0.0, 0.5], reduction.tolerance_image: [0.03]}", "+neutral={objects.merge: 0.0}",
         "transforms=[flip,sgbm:raw]", f"gallery={tmp_path / 'gallery'}"],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rep = json.loads((tmp_path / "validate.json").read_text())
    assert [r["frame"] for r in rep["rows"]] == ["kitti", "kitti_est", "oakd_toy", "oakd_cycles",
                                                 "eth3d_terrace_sgbm"]
    assert set(rep["folds"]) == {"kitti2015", "oakd", "eth3d"}
    sm = rep["summary"]
    # two frames x two seeds x the protocol's two pixel grids (frame_shifts: as given and 5 px)
    assert sm["datasets"]["kitti2015"]["frames"] == 2 and sm["datasets"]["oakd"]["runs"] == 8
    # the macro average counts each dataset once
    per = [sm["datasets"][d]["default_useful_hits"] for d in ("kitti2015", "oakd", "eth3d")]
    assert sm["macro_real"]["default_useful_hits"] == pytest.approx(sum(per) / 3)
    for r in rep["rows"]:  # the left-out figure uses the choice of the fold without the frame's dataset
        choice = rep["folds"][r["dataset"]]["choice"]
        key = ",".join(f"{k}={choice[k]}" for k in sorted(choice)) or "default"
        assert r["left_out"]["useful_hits"] == rep["candidates"][r["frame"]][key]["useful_hits"]
        d = r["default"]
        assert d["useful_hits"] + sum(d["misses"].values()) == d["runs"], d
        assert 0 <= d["best_area_hits"] <= d["runs"]  # the selection ceiling, the defaults only
        assert d["useful_hits"] <= d["first_place_hits"] <= d["runs"]  # a perfect ranking's ceiling
        assert d["useful_hits"] <= d["best_map_hits"] <= d["runs"]  # a perfect choice among a run's maps
        # the gap: the ceiling's runs that missed, by reason (the ceiling may also count useful runs)
        gap = sum(d["selection_gap"].values())
        assert d["best_area_hits"] - d["useful_hits"] <= gap <= d["runs"] - d["useful_hits"]
    kn = rep["knobs"]["objects.merge"]
    assert kn["verdict"] in ("keep", "remove") or kn["verdict"].startswith("adopt")
    assert [e["value"] for e in kn["values"]] == [0.0, 0.5] and kn["values"][0]["neutral"]
    assert rep["knobs"]["reduction.tolerance_image"]["verdict"] != "remove"  # no neutral value given
    md = (tmp_path / "validate.md").read_text()
    assert "| **macro, real** |" in md and "| objects.merge | 0.75 | 0.0 (neutral) |" in md
    assert list(rep["robustness"]) == ["flip", "sgbm:raw"] and "| flip |" in md
    # sgbm:raw re-matches the one frame whose map is SGBM's, and the table reads it beside that frame as given
    assert list(rep["robustness"]["sgbm:raw"]) == ["eth3d_terrace_sgbm"]
    assert "| sgbm:raw | " in md and "| sgbm:raw: the same frames as given | " in md
    # the probe runs the task baselines on the same transformed frames, and the table reads them
    flip = rep["robustness"]["flip"]
    assert set(flip) == {r["frame"] for r in rep["rows"]}
    for got in flip.values():
        assert list(got["baselines"]) == ["plane_components", "uv_disparity"]
        pc = got["baselines"]["plane_components"]
        assert pc["runs"] == 1 and 0 <= pc["useful_hits"] <= pc["identified_95"] <= 1
    som = 100 * sum(v["useful_hits"] for v in flip.values()) / sum(v["runs"] for v in flip.values())
    pcs = 100 * sum(v["baselines"]["plane_components"]["useful_hits"] for v in flip.values()) / len(flip)
    line = next(ln for ln in md.splitlines() if ln.startswith("| flip |"))
    assert line.split(" | ")[4:6] == [f"{som:.1f}", f"{pcs:.1f}"], line
    assert "| plane_components useful % | uv_disparity useful % |" in md
    assert "Selection ceiling" in md and 0 <= sm["macro_real"]["default_best_area_hits"] <= 1
    assert 0 <= sm["macro_real"]["default_best_grouping_hits"] <= 1 and "best grouping of its segments" in md
    # the closing lines name both ceilings in % (the log goes to the run folder and the terminal)
    log_text = proc.stdout + proc.stderr + "".join(p.read_text() for p in tmp_path.glob("*.log"))
    mr = sm["macro_real"]
    want = (f"a perfect ranking of the candidates {100 * mr['default_first_place_hits']:.1f} %, a perfect "
            f"choice among the areas {100 * mr['default_best_area_hits']:.1f} %, a perfect "
            f"grouping of the segments {100 * mr['default_best_grouping_hits']:.1f} %")
    assert mr["default_useful_hits"] <= mr["default_first_place_hits"] <= 1
    assert "| dataset | default useful | best map of the run | best candidate first | best single area |" \
        in md
    assert f"a perfect choice among each run's maps {100 * mr['default_best_map_hits']:.1f} %" in log_text
    assert want in log_text, log_text[-1500:]
    assert all(0 <= r["default"]["best_grouping_hits"] <= r["default"]["runs"] for r in rep["rows"])
    assert "The selection gap (defaults)" in md and "| **total, real** |" in md
    # how the other runs missed: per dataset the frames' counts summed, and the runs add up
    for d, got in sm["datasets"].items():
        m = got["default_misses"]
        rows_d = [r["default"] for r in rep["rows"] if r["dataset"] == d]
        assert m == {"useful": sum(r["useful_hits"] for r in rows_d),
                     **{k: sum(r["misses"][k] for r in rows_d) for k in ("wrong", "partial", "too_much")}}
        assert sum(m.values()) == got["runs"]
        line = f"| {d} | {got['runs']} | {m['useful']} | {m['wrong']} | {m['partial']} | {m['too_much']} |"
        assert line in md, md
    assert "How the other runs missed (defaults)" in md
    real_m = [g["default_misses"] for g in sm["datasets"].values() if g["real"]]
    tot = {k: sum(m[k] for m in real_m) for k in real_m[0]}
    want = (f"real runs of the defaults: {tot['useful']} useful of {sum(tot.values())}; the others kept < 50 % of "
            f"the main object ({tot['wrong']}), 50-95 % of it ({tot['partial']}), or all of it with too much beside "
            f"it ({tot['too_much']})")
    assert want in log_text, log_text[-1500:]
    assert sm["datasets"]["oakd"]["default_selection_gap"] == {
        k: sum(r["default"]["selection_gap"][k] for r in rep["rows"] if r["dataset"] == "oakd")
        for k in rep["rows"][0]["default"]["selection_gap"]}
    assert sorted(p.name for p in (tmp_path / "gallery").glob("*.png")) == sorted(f"{r['frame']}.png" for r in rep["rows"])
    # the task baselines (default: plane_components, uv_disparity), one run per frame, beside the defaults
    for r in rep["rows"]:
        assert list(r["baselines"]) == ["plane_components", "uv_disparity"]
        for b in r["baselines"].values():
            # one run on each of the two grids
            assert b["runs"] == 2 and 0 <= b["useful_hits"] <= b["identified_95"] <= 2
            assert 0 <= b["saliency"]["mae"] <= 1
            # a useful first box is one of its boxes: the ceiling of a choice among them holds it
            assert b["best_box_hits"] in (0, 1, 2)
            assert b["no_object"] or b["best_box_hits"] >= b["useful_hits"]
    pc = rep["baselines_summary"]["plane_components"]
    per = [pc["datasets"][d]["useful_hits"] for d in ("kitti2015", "oakd", "eth3d")]
    assert pc["macro_real"]["useful_hits"] == pytest.approx(sum(per) / 3)
    assert "| | plane_components |" in md and "| kitti2015 | SOM defaults |" in md
    # either ceiling: per frame the better of the SOM's (its runs) and the baseline's (all or none)
    for d in ("kitti2015", "oakd", "eth3d"):
        x = pc["datasets"][d]
        assert max(x["best_box_hits"], sm["datasets"][d]["default_best_area_hits"]) <= x["either_best"] + 1e-9
        assert x["either_best"] <= x["best_box_hits"] + sm["datasets"][d]["default_best_area_hits"] + 1e-9
    assert "| dataset | method | useful | best single box | either |" in md


def _toy_scene():
    import torch

    from somtorch.disparity.scene import scene_from_arrays

    h, w = 60, 100
    disp = torch.full((h, w), 10.0)
    disp[20:50, 30:70] = 20.0 + torch.arange(40, dtype=torch.float32)[None, :] / 10  # 20 ... 23.9
    objects = torch.zeros(h, w, dtype=torch.long)
    objects[20:50, 30:70] = 1
    image = torch.arange(3 * h * w, dtype=torch.int64).remainder(251).to(torch.uint8).view(3, h, w)
    return scene_from_arrays(disp, image=image, objects=objects, name="toy")


def test_pole_junk_stands_in_front_of_the_object_and_occludes_it():
    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "pole")
    pole = out.disparity != scene.disparity
    cols = pole.any(0).nonzero().flatten()
    assert 2 <= cols.numel() <= 3 and 30 < int(cols.min()) < 70  # 1.5 % of the width, across the object
    rows = pole.any(1).nonzero().flatten()
    assert int(rows.min()) == 10 and int(rows.max()) == 59  # from half-way to the object's top, to the bottom
    d95 = float(torch.quantile(scene.disparity[scene.objects == 1], 0.95))
    assert torch.allclose(out.disparity[pole], torch.tensor(1.25 * d95), atol=0.05)  # nearer than the object
    assert not bool((out.objects[pole] > 0).any())  # what the pole hides is not scored as the object
    hidden = int((pole & (scene.objects > 0)).sum())
    assert hidden > 0 and int((out.objects > 0).sum()) == int((scene.objects > 0).sum()) - hidden


def test_flip_junk_mirrors_every_layer():
    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "flip")
    assert out.disparity[25, 99 - 35] == scene.disparity[25, 35]
    assert bool((out.objects.flip(-1) == scene.objects).all())
    assert bool((out.image.flip(-1) == scene.image).all())
    assert out.camera is None and out.name == "toy+flip"
    with pytest.raises(ValueError, match="unknown junk kind"):
        add_junk(scene, "rotate")


def test_noise_junk_adds_seeded_gaussian_noise_to_every_valid_pixel():
    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "noise:0.5", seed=3)
    step = (out.disparity - scene.disparity)[out.valid]
    assert abs(float(step.std()) - 0.5) < 0.05 and abs(float(step.mean())) < 0.05
    assert torch.equal(out.disparity, add_junk(scene, "noise:0.5", seed=3).disparity)  # seeded
    assert not torch.equal(out.disparity, add_junk(scene, "noise:0.5", seed=4).disparity)
    assert bool((out.disparity[out.valid] > 0).all()) and not bool((out.valid & ~scene.valid).any())
    assert torch.equal(out.objects, scene.objects) and out.name == "toy+noise:0.5"


def test_quantize_junk_rounds_every_valid_disparity_to_whole_steps():
    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "quantize:2")
    d = out.disparity[out.valid]
    assert torch.equal(d, torch.round(d / 2) * 2) and bool((d > 0).all())
    assert float((out.disparity - scene.disparity)[out.valid].abs().max()) <= 1.0 + 1e-6
    assert not bool((out.valid & ~scene.valid).any()) and out.name == "toy+quantize:2"
    with pytest.raises(ValueError, match="positive step"):
        add_junk(scene, "quantize:0")


def test_bowl_junk_bends_every_valid_disparity_by_a_relative_error_growing_to_the_corners():
    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "bowl:0.02")
    gain = out.disparity / scene.disparity
    h, w = scene.disparity.shape
    assert abs(float(gain[0, 0]) - 1.02) < 1e-4 and abs(float(gain[h - 1, w - 1]) - 1.02) < 1e-4  # corners
    assert float(gain[out.valid].min()) >= 0.98 - 1e-6 and float(gain[out.valid].max()) <= 1.02 + 1e-6
    assert float(gain[h // 2, w // 2]) < 0.985  # the centre, nearly 1 − p
    assert torch.equal(out.valid, scene.valid) and out.name == "toy+bowl:0.02"


def test_blotch_junk_adds_noise_correlated_over_several_pixels():
    import torch

    from experiments.scenes import add_junk
    from somtorch.tasks.ground import noise_sigma

    scene = _toy_scene()
    out = add_junk(scene, "blotch:0.5", seed=2)
    step = (out.disparity - scene.disparity)[out.valid]
    assert abs(float(step.std()) - 0.5) < 0.1
    # pixels one and two apart share much of their error (1.2 px of correlation on this 60-px-high
    # toy): the reading sees a fraction of it
    assert noise_sigma(out.disparity - scene.disparity, out.valid) < 0.8 * 0.5
    assert torch.equal(out.disparity, add_junk(scene, "blotch:0.5", seed=2).disparity)  # seeded
    assert not bool((out.valid & ~scene.valid).any()) and out.name == "toy+blotch:0.5"


def test_smear_junk_bleeds_depth_edges_into_ramps_and_leaves_surfaces_alone():
    import dataclasses

    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    hole = torch.zeros_like(scene.valid)
    hole[5:10, 5:10] = True  # no measurement there: it must neither pull nor receive a value
    scene = dataclasses.replace(scene, disparity=torch.where(hole, 0.0, scene.disparity), valid=scene.valid & ~hole)
    out = add_junk(scene, "smear:2")
    assert 10.5 < float(out.disparity[35, 29]) < 19.5 and 10.5 < float(out.disparity[35, 30]) < 19.5  # the edge
    assert abs(float(out.disparity[35, 10]) - 10.0) < 1e-4  # a flat surface stays flat ...
    assert abs(float(out.disparity[35, 50]) - 22.0) < 1e-3  # ... and a slanted one slanted
    assert abs(float(out.disparity[7, 11]) - 10.0) < 1e-4  # beside the hole: not pulled towards its 0
    assert torch.equal(out.valid, scene.valid) and float(out.disparity[7, 7]) == 0.0
    assert out.name == "toy+smear:2"
    with pytest.raises(ValueError, match="positive blur radius"):
        add_junk(scene, "smear:0")


def test_relief_junk_flattens_the_world_towards_its_mean_plane_keeping_planes_planar():
    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "relief:0.5")
    h, w = scene.disparity.shape
    yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    rest = (out.disparity.double() - 0.5 * scene.disparity.double()).flatten()  # half the mean plane
    a = torch.stack([xx.flatten(), yy.flatten(), torch.ones(h * w, dtype=torch.float64)], 1)
    fit = torch.linalg.lstsq(a, rest[:, None]).solution
    assert float((a @ fit - rest[:, None]).abs().max()) < 1e-3  # an affine map of (x, y, d): planes stay planes
    step = float(out.disparity[35, 40] - out.disparity[35, 20])
    assert abs(step - 0.5 * float(scene.disparity[35, 40] - scene.disparity[35, 20])) < 0.1  # half as deep
    assert torch.equal(out.valid, scene.valid) and out.name == "toy+relief:0.5"
    with pytest.raises(ValueError, match="positive factor"):
        add_junk(scene, "relief:0")


def test_offset_junk_adds_a_constant_to_every_valid_disparity_keeping_planes_planar():
    """A rig whose two principal points differ by T px measures d + T (Middlebury's ``doffs``): every
    valid disparity moves by T, steps between surfaces and every plane's slope are kept."""
    import dataclasses

    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    hole = torch.ones_like(scene.valid)
    hole[:5, :10] = False  # missing pixels keep their value and stay missing
    scene = dataclasses.replace(scene, valid=hole)
    out = add_junk(scene, "offset:20")
    assert torch.allclose(out.disparity[scene.valid], scene.disparity[scene.valid] + 20.0)
    assert torch.equal(out.disparity[~scene.valid], scene.disparity[~scene.valid])
    assert torch.equal(out.valid, scene.valid) and out.name == "toy+offset:20"
    with pytest.raises(ValueError, match="positive offset"):
        add_junk(scene, "offset:-5")


def test_sgbm_transform_matches_a_frames_stereo_pair_again_under_another_setting(tmp_path, monkeypatch):
    """``sgbm:NAME`` re-matches the frame's own pair: the corpus's setting unchanged gives its stored
    map bit for bit; ``raw`` (no uniqueness, left-right or speckle filter) gives a map with more
    pixels matched, the objects kept; frames whose map is not SGBM's are skipped (None), and an
    unknown setting fails naming the known ones."""
    import dataclasses

    import torch

    from experiments.datasets import FrameSpec, load_frame
    from experiments.scenes import SGBM_VARIANTS, add_junk, check_junk_kind, rematched
    from somtorch.synth.frame import generate_frame
    from somtorch.synth.store import write_frame

    write_frame(generate_frame("floor", 0, "oakd", scale=0.25), tmp_path / "floor_oakd" / "00000")
    spec = FrameSpec(name="f_sgbm", dataset="f", real=False, folder="floor_oakd/00000",
                     disparity="disp_sgbm.pfm", synthetic=True)
    scene = load_frame(spec, tmp_path, corpus=tmp_path)
    monkeypatch.setitem(SGBM_VARIANTS, "as_stored", {})
    same = rematched(spec, scene, "as_stored", tmp_path, corpus=tmp_path)
    assert torch.equal(same.valid, scene.valid)
    assert torch.equal(same.disparity[same.valid], scene.disparity[scene.valid])
    raw = rematched(spec, scene, "raw", tmp_path, corpus=tmp_path)
    assert int(raw.valid.sum()) > int(scene.valid.sum())  # the filters it drops leave pixels unmatched
    assert torch.equal(raw.objects, scene.objects) and raw.name == "f_sgbm+sgbm:raw"
    # a camera of half the resolution: the pair downsized, then matched; the labels resampled with it
    half = rematched(spec, scene, "half", tmp_path, corpus=tmp_path)
    h, w = scene.disparity.shape
    assert half.disparity.shape == half.objects.shape == (round(h / 2), round(w / 2))
    assert set(half.objects.unique().tolist()) == set(scene.objects.unique().tolist())
    assert int(half.valid.sum()) > 0 and float(half.disparity[half.valid].max()) < float(scene.disparity.max())
    gt = dataclasses.replace(spec, name="f", disparity="gt")
    assert rematched(gt, load_frame(gt, tmp_path, corpus=tmp_path), "raw", tmp_path, corpus=tmp_path) is None
    assert rematched(dataclasses.replace(spec, junk="flip"), scene, "raw", tmp_path, corpus=tmp_path) is None
    with pytest.raises(ValueError, match="sgbm needs a setting of raw, tutorial, half"):
        check_junk_kind("sgbm:nope")
    with pytest.raises(ValueError, match="rematched"):
        add_junk(scene, "sgbm:raw")


def test_wide_junk_shrinks_the_view_into_its_centre_and_continues_the_floor_around_it():
    from experiments.scenes import add_junk

    scene = _toy_scene()  # a flat background at 10 px, an object 20 … 23.9 px at rows 20–49, cols 30–69
    out = add_junk(scene, "wide:0.5")
    h, w = scene.disparity.shape
    assert out.disparity.shape == (h, w) and bool(out.valid.all()) and out.camera is None
    assert abs(float(out.disparity[0, 0]) - 10.0) < 1e-3 and abs(float(out.disparity[h - 1, w - 1]) - 10.0) < 1e-3
    obj = out.objects == 1
    ys, xs = obj.nonzero(as_tuple=True)
    assert (int(ys.min()), int(ys.max()), int(xs.min()), int(xs.max())) == (25, 39, 40, 59)  # half size, centred
    assert float(out.disparity[obj].min()) >= 20.0 - 1e-4 and float(out.disparity[obj].max()) <= 23.9 + 1e-4  # f·B kept
    assert int((out.objects == 0).sum()) == h * w - int(obj.sum()) and out.name == "toy+wide:0.5"
    assert out.image is not None and out.image.shape == scene.image.shape
    for bad in ("wide:0", "wide:1.5"):
        with pytest.raises(ValueError, match=r"factor in \(0, 1\]"):
            add_junk(scene, bad)


def test_shift_junk_cuts_the_first_rows_and_columns_so_the_strided_steps_read_other_pixels():
    import dataclasses

    import torch

    from experiments.scenes import add_junk
    from somtorch.config import FeatureConfig
    from somtorch.disparity.camera import Camera
    from somtorch.disparity.scene import scene_from_arrays

    scene = dataclasses.replace(_toy_scene(), camera=Camera(focal_px=100.0, cx=50.0, cy=40.0, baseline=0.1))
    out = add_junk(scene, "shift:3")
    h, w = scene.disparity.shape
    assert out.disparity.shape == out.valid.shape == out.objects.shape == (h - 3, w - 3)
    assert out.image.shape == (3, h - 3, w - 3) and out.name == "toy+shift:3"
    assert torch.equal(out.disparity, scene.disparity[3:, 3:])
    assert torch.equal(out.objects, scene.objects[3:, 3:])
    assert (out.camera.cx, out.camera.cy) == (47.0, 37.0)  # the same rays: the principal point moves too
    # at the reference size the OR sample of the shifted map is the original's grid at phase (3, 3)
    noise = torch.rand(480, 640, generator=torch.Generator().manual_seed(0))
    big = scene_from_arrays(noise + 1.0, name="big")
    moved = add_junk(big, "shift:3")
    s = FeatureConfig().stride_at(FeatureConfig().train_stride, *moved.valid.shape)
    assert s == FeatureConfig().stride_at(FeatureConfig().train_stride, 480, 640) == 10
    assert torch.equal(moved.disparity[::s, ::s], big.disparity[3::s, 3::s])
    assert not torch.equal(moved.disparity[::s, ::s], big.disparity[:-3:s, :-3:s])
    for bad in ("shift:0", "shift:2.5", "shift:x"):
        with pytest.raises(ValueError, match="positive whole number"):
            add_junk(scene, bad)
    with pytest.raises(ValueError, match="half its shorter side"):
        add_junk(scene, f"shift:{min(h, w) // 2}")


def test_scale_junk_multiplies_every_valid_disparity_as_another_rig_would():
    import torch

    from experiments.scenes import add_junk

    scene = _toy_scene()
    out = add_junk(scene, "scale:0.25")
    assert torch.allclose(out.disparity[out.valid], 0.25 * scene.disparity[scene.valid])
    assert torch.equal(out.valid, scene.valid) and torch.equal(out.objects, scene.objects)
    assert torch.equal(out.disparity[~out.valid], scene.disparity[~scene.valid]) and out.name == "toy+scale:0.25"
    with pytest.raises(ValueError, match="positive factor"):
        add_junk(scene, "scale:-2")


def test_the_noisy_floor_frames_are_the_gt_frames_with_noise_in_their_scene_group():
    noisy = [f for f in frames(datasets=["synth_floor_oakd"]) if f.name.endswith("_noisy")]
    assert len(noisy) == 6 and all(f.junk == "noise:0.5" and f.disparity == "gt" for f in noisy)
    gt = {f.group: f.folder for f in frames(datasets=["synth_floor_oakd"])
          if f.disparity == "gt" and not f.junk}
    assert all(gt[f.group] == f.folder for f in noisy)  # the same scene, resampled together
    assert not any(f.name.endswith("_noisy") for f in frames(datasets=["synth_stairs_oakd"]))


def test_an_unknown_baseline_fails_before_any_work(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.validate", f"hydra.run.dir={tmp_path}", "ensemble=2",
         "baselines=[plane_components,hough]"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    out = proc.stderr + proc.stdout
    assert "hough" in out and "plane_components" in out and "uv_disparity" in out and "Traceback" not in out
    assert not (tmp_path / "validate.json").exists()


def test_an_unknown_transform_fails_before_any_work(tmp_path):
    from experiments.scenes import check_junk_kind

    for ok in ("flip", "pole", "resample:0.5", "noise:0.5", "bowl:0.01", "blotch:0.5", "smear:2", "relief:0.5",
               "wide:0.5", "offset:20", "shift:5", "sgbm:raw", "sgbm:tutorial"):
        check_junk_kind(ok)
    for bad, msg in (("rotate", "unknown junk kind"), ("resample:-2", "positive factor"),
                     ("resample:x", "positive factor"), ("noise:0", "positive standard deviation"),
                     ("bowl:-1", "positive relative error"), ("blotch:x", "positive standard deviation")):
        with pytest.raises(ValueError, match=msg):
            check_junk_kind(bad)
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.validate", f"hydra.run.dir={tmp_path}", "ensemble=2",
         "transforms=[flip,rotate]"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "unknown junk kind 'rotate'" in proc.stderr + proc.stdout
    assert not (tmp_path / "validate.json").exists()


def test_a_fresh_clone_is_told_the_command_that_generates_the_missing_frames(tmp_path, monkeypatch):
    """Issue 34: validate on a fresh clone (no generated corpus) names the exact generator command."""
    from experiments.datasets import missing_corpus
    from experiments.synth_config import SynthConfig

    monkeypatch.setenv("SOMTORCH_CORPUS", str(tmp_path))
    specs = frames()
    line = missing_corpus(specs)
    assert line is not None and "\n" not in line
    assert line.startswith("180 synthetic frame(s) are not generated yet")
    cmd = line.split("`")[1]
    assert cmd == "somtorch-synth 'cameras=[oakd,kitti,middlebury]' n=6"
    cfg = SynthConfig(cameras=["oakd", "kitti", "middlebury"], n=6)  # what those overrides give
    for s in specs:  # every frame the registry wants is one that command writes
        if s.synthetic:
            fam, cam = s.folder.split("/")[0].rsplit("_", 1)
            (tmp_path / s.folder).mkdir(parents=True, exist_ok=True)
            assert fam in cfg.families and cam in cfg.cameras and int(s.folder.split("/")[1]) < cfg.n
    assert missing_corpus(specs) is None
    assert missing_corpus(frames(datasets=["kitti2015"])) is None  # real frames never need it


def test_a_transform_that_leaves_the_object_no_valid_pixel_skips_the_frame(caplog):
    """A robustness transform may take every valid pixel of a frame's object (``quantize:1`` rounds
    a far object's 0.4 px to 0, no measurement): that frame is skipped with a warning naming it, the
    others are scored, and the probe goes on (it used to stop the whole validate run)."""
    import logging

    import torch

    from experiments.datasets import FrameSpec
    from experiments.validate import transformed
    from somtorch.disparity.scene import scene_from_arrays

    caches = []
    for name, obj_d in (("far", 0.4), ("near", 40.0)):
        d = torch.full((96, 128), 20.0)
        objects = torch.zeros(96, 128, dtype=torch.long)
        d[30:60, 30:70], objects[30:60, 30:70] = obj_d, 1
        scene = scene_from_arrays(d, torch.ones(96, 128, dtype=torch.bool), objects=objects, name=name)
        caches.append(SceneCache(FrameSpec(name=name, dataset="t", real=False, folder="."), scene,
                                 PipelineConfig(ensemble=2), ceilings=False))
    with caplog.at_level(logging.WARNING, logger="somtorch.validate"):
        got = transformed(caches, "quantize:1")
    assert list(got) == ["near"] and got["near"]["runs"] == 2
    assert any("far (quantize:1): the main object has no valid pixel left" in r.getMessage() for r in caplog.records)
