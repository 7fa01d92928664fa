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
         "~grid", "+grid={objects.merge: [0.5], reduction.tolerance_image: [0.03]}"],
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
    assert "**total**" in (tmp_path / "validate.md").read_text()
