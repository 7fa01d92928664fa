"""The leave-one-scene-out protocol: the choice of each fold never sees the left-out scene."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.scenes import dev_scenes, load_dev_scene
from experiments.validate import SceneCache, choose
from somtorch.config import PipelineConfig

ROOT = Path(__file__).resolve().parents[2]


class _Fixed:
    """A scene whose scores are given (to test the selection rule alone)."""

    def __init__(self, table):
        self.table = table

    def score(self, overrides):
        key = ",".join(f"{k}={v}" for k, v in sorted(overrides.items())) or "default"
        return {"useful_hits": self.table[key], "all_objects_hits": 0}


def test_choose_takes_the_best_value_on_the_given_scenes_and_the_default_on_ties():
    a = _Fixed({"default": 5, "x.y=1": 9, "x.y=2": 5})
    b = _Fixed({"default": 5, "x.y=1": 0, "x.y=2": 5})
    grid, defaults = {"x.y": [1, 2]}, {"x.y": 0}
    assert choose([a], grid, defaults) == {"x.y": 1}
    assert choose([b], grid, defaults) == {}  # value 2 only ties: the default stays
    assert choose([a, b], grid, defaults) == {}  # 9 + 0 < 5 + 5: on both scenes the default wins


def test_every_dev_scene_spec_is_unique_and_the_computed_ones_name_their_source():
    specs = dev_scenes()
    assert len({s.name for s in specs}) == len(specs) >= 12
    for s in specs:
        if s.disparity == "sgbm":
            assert s.left and s.right and s.ndisp % 16 == 0
    with pytest.raises(ValueError, match="unknown scene"):
        dev_scenes(["nope"])


def test_scene_cache_segments_once_per_upstream_setting(shared_data):
    spec = dev_scenes(["kitti"])[0]
    cache = SceneCache(spec, load_dev_scene(spec, shared_data), PipelineConfig(ensemble=2))
    base = cache.score({})
    assert base["runs"] == 2 and 0 <= base["useful_hits"] <= 2 and base["x_opt"] > 0
    cache.score({"objects.merge": 0.5})
    assert len(cache._seg) == 1  # an object-step constant reuses the segmentation
    cache.score({"ground.max_below_frac": 1.0})
    assert len(cache._seg) == 2  # a ground constant does not
    assert cache.score({}) is base


def test_validate_command_writes_the_left_out_table(shared_data, tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.validate", f"hydra.run.dir={tmp_path}", "ensemble=2",
         "train.epochs=3", "scenes=[kitti,oakd_toy,eth3d_terrace]", f"paths.data_dir={shared_data}",
         "~grid", "+grid={objects.merge: [0.5], reduction.tolerance_image: [0.03]}",
         "transforms=[flip,resample:0.5]"],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rep = json.loads((tmp_path / "validate.json").read_text())
    assert [r["scene"] for r in rep["rows"]] == ["kitti", "oakd_toy", "eth3d_terrace"]
    for part in ("default", "in_sample", "left_out"):
        assert rep["totals"][part]["runs"] == 6
        assert rep["totals"][part]["useful_hits"] == sum(r[part]["useful_hits"] for r in rep["rows"])
    for r in rep["rows"]:  # each fold's choice is the one made on the other two scenes
        others = [c for c in rep["rows"] if c is not r]
        for key, value in r["fold_choice"].items():
            k = f"{key}={value}"
            assert sum(rep["candidates"][o["scene"]][k]["useful_hits"] for o in others) >= \
                sum(rep["candidates"][o["scene"]]["default"]["useful_hits"] for o in others)
    md = (tmp_path / "validate.md").read_text()
    assert "**total**" in md
    for r in rep["rows"]:  # every run is a useful hit or one kind of miss
        d = r["default"]
        assert d["useful_hits"] + sum(d["misses"].values()) == d["runs"], d
    # the robustness checks: every scene transformed, scored with the defaults, in the report
    rob = rep["robustness"]
    assert list(rob) == ["flip", "resample:0.5"]
    for kind in rob:
        assert sorted(rob[kind]) == ["eth3d_terrace", "kitti", "oakd_toy"]
        assert all(v["runs"] == 2 and 0 <= v["useful_hits"] <= 2 for v in rob[kind].values())
    assert rob["resample:0.5"]["kitti"]["x_opt"] != rep["rows"][0]["default"]["x_opt"]  # another map
    assert "| scene | as given | flip | resample:0.5 |" in md
    lines = md.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("| candidate |"))
    assert lines[head + 2].startswith("| default |")  # the candidate table is in one piece
    assert md.index("| scene | as given |") > head
    assert "of 6 |" in lines[-1]  # each column's total says over how many runs


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


def test_an_unknown_transform_fails_before_any_work(tmp_path):
    from experiments.scenes import check_junk_kind

    for ok in ("flip", "pole", "resample:0.5"):
        check_junk_kind(ok)
    for bad, msg in (("rotate", "unknown junk kind"), ("resample:-2", "positive factor"),
                     ("resample:x", "positive factor")):
        with pytest.raises(ValueError, match=msg):
            check_junk_kind(bad)
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.validate", f"hydra.run.dir={tmp_path}", "ensemble=2",
         "transforms=[flip,rotate]"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "unknown junk kind 'rotate'" in proc.stderr + proc.stdout
    assert not (tmp_path / "validate.json").exists()
