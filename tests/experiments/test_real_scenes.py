"""The real-scene scoring experiment: composes, runs on two shared scenes, writes consistent tables."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from experiments.real_scenes import DEFAULT_SCENES, ScenesConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("preset", [None, "paper", "robust"])
def test_config_composes_with_each_preset(preset):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("real_scenes", overrides=[f"+preset={preset}"] if preset else [])
    obj = OmegaConf.to_object(cfg)
    assert isinstance(obj, ScenesConfig)
    assert obj.scenes == DEFAULT_SCENES
    if preset == "paper":
        assert (obj.som.rows, obj.som.cols, obj.objects.select, obj.ground.enabled) == (4, 7, "nearest", False)
        assert obj.label == "paper"


def test_two_scenes_run_and_tables_agree(shared_data, tmp_path):
    scenes = "[eth3d/terrace,kitti2015/devkit_demo]"
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.real_scenes", f"hydra.run.dir={tmp_path}", "ensemble=2",
         "train.epochs=3", f"scenes={scenes}", f"paths.data_dir={shared_data}"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads((tmp_path / "results.json").read_text())
    assert [r["scene"] for r in res["rows"]] == ["eth3d/terrace", "kitti2015/devkit_demo"]
    for r in res["rows"]:
        assert r["runs"] == 2
        assert 0 <= r["useful_hits"] <= r["identified_95"] <= r["runs"]
        assert r["identified_100"] <= r["identified_95"]
        assert set(r["per_object"]) and all(0 <= o["mean_identified_fraction"] <= 1 for o in r["per_object"].values())
    assert res["rows"][0]["x_opt"] == pytest.approx(94.3, abs=0.05)
    md = (tmp_path / "results.md").read_text()
    assert md.count("| eth3d/terrace |") == 1 + 3  # one scene row + three object rows
    assert "car_silver_opel_left" in md


def test_missing_scene_folder_fails_before_work(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.real_scenes", f"hydra.run.dir={tmp_path}", "ensemble=1",
         "scenes=[no/such_scene]", f"paths.data_dir={tmp_path}"],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "no/such_scene" in proc.stderr
    assert not (tmp_path / "results.json").exists() and not (tmp_path / "results.md").exists()
