"""``somtorch-train-baseline`` as the user runs it (real processes, generated frames, a temporary cache)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TINY = ["model.widths=[8,16]", "model.height=32", "model.width=48", "data.families=[garden]", "data.cameras=[oakd]",
        "data.frames=2", "data.held_out=1", "data.scale=0.1", "fit.epochs=1", "workers=1"]


def _run(tmp_path: Path, *overrides: str, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "SOMTORCH_CACHE": str(tmp_path / "cache")}
    env.pop("HYDRA_FULL_ERROR", None)
    env.pop("SOMTORCH_CORPUS", None)
    return subprocess.run([sys.executable, "-m", "experiments.train_baseline", *overrides], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("overrides, said", [
    (["fit.epochs=100000"], "over budget_minutes=15"),
    (["budget_minutes=1000000.0", "max_memory_frac=0.000000001"], "over max_memory_frac=1e-09"),
    (["model.height=30"], "height=30 and width=96 must divide by 2"),
    (["fit.epochs=0"], "fit.epochs must be an integer in [1, inf)"),
])
def test_refuses_in_one_line_before_any_work(tmp_path, overrides, said):
    proc = _run(tmp_path, *overrides, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and said in lines[0] and "Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.safetensors"))


def test_refuses_a_corpus_under_the_real_data(tmp_path, shared_data):
    proc = _run(tmp_path, f"paths.data_dir={shared_data}", f"corpus={shared_data}/synth", *TINY, timeout=120)
    assert proc.returncode == 2 and "lies under the real data" in proc.stderr, proc.stderr[-2000:]
    assert not (shared_data / "synth").exists()


def test_trains_saves_and_then_reuses_the_model(tmp_path):
    first = _run(tmp_path, *TINY)
    assert first.returncode == 0, first.stderr[-3000:]
    assert "estimated: 1 model(s), 3 frame(s) to render" in first.stdout
    (sidecar,) = (tmp_path / "cache" / "learned").glob("*/model.json")
    doc = json.loads(sidecar.read_text())
    assert doc["format"] == "somtorch.learned/1" and len(doc["data_hash"]) == 16
    assert doc["data"]["cameras"] == ["oakd"] and doc["train_frames"] == 4 and doc["held_out_metrics"]["frames"] == 2
    assert any((sidecar.parent / "tb").iterdir())
    weights = sidecar.with_suffix(".safetensors").read_bytes()
    again = _run(tmp_path, *TINY)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "1 model(s) (1 cached), 0 frame(s) to render" in again.stdout
    assert sidecar.with_suffix(".safetensors").read_bytes() == weights  # reused, not retrained


def test_a_collapsed_network_is_a_one_line_error_and_is_not_cached(tmp_path):
    proc = _run(tmp_path, *TINY, "fit.lr=10.0", "fit.epochs=3")
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "above its output bias" in proc.stderr and "fit.lr" in proc.stderr, proc.stderr[-3000:]
    assert not any((tmp_path / "cache").rglob("*.safetensors"))


def test_frames_carry_the_camera_of_their_fold():
    from experiments.datasets import datasets

    cams = {d.name: {f.camera for f in d.frames} for d in datasets()}
    assert cams["kitti2015"] == {"kitti"} and cams["oakd"] == {"oakd"}
    assert cams["middlebury2014"] == cams["middlebury_2005_2006"] == {"middlebury"}
    assert cams["eth3d"] == {None} and cams["synth_garden_kitti"] == {"kitti"}


def test_a_trained_baseline_runs_its_fold_on_a_left_out_camera():
    """run_baseline(..., left_out=camera) calls the function of the fold without that camera."""
    import torch

    from experiments.real_scenes import run_baseline
    from somtorch.config import ReductionConfig
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.tasks.baselines import TASK_BASELINES, Obstacle, register_task_baseline

    calls = []

    def boxes_of(tag):
        def fn(disparity, valid, camera=None):
            calls.append(tag)
            return [Obstacle((0, 0, 3, 3), 1.0, 16)]
        return fn

    register_task_baseline("fold_probe", boxes_of("all"), left_out=lambda cam: boxes_of(f"without {cam}"))
    try:
        d = torch.ones(8, 8)
        scene = scene_from_arrays(d.numpy(), torch.ones(8, 8, dtype=torch.bool).numpy(), name="probe")
        run_baseline("fold_probe", scene, ReductionConfig())
        run_baseline("fold_probe", scene, ReductionConfig(), left_out="kitti")
    finally:
        TASK_BASELINES.pop("fold_probe")
    assert calls == ["all", "without kitti"]


def test_real_scenes_summary_is_the_protocol_macro_with_its_interval():
    from experiments.real_scenes import macro_summary

    rows = [{"method": m, "dataset": ds, "group": g, "real": real, "runs": 2, "useful_hits": h}
            for m, ds, g, real, h in [("learned", "a", "a1", True, 2), ("learned", "a", "a2", True, 0),
                                      ("learned", "b", "b1", True, 1), ("learned", "b", "b1", True, 1),
                                      ("learned", "s", "s1", False, 0)]]
    got = macro_summary(rows, n_boot=200)["learned"]
    assert got["datasets"] == {"a": 0.5, "b": 0.5, "s": 0.0} and got["frames"] == 5
    m = got["macro_real"]
    assert m["useful"] == 0.5 and 0.0 <= m["lo"] <= 0.5 <= m["hi"] <= 1.0 and m["lo"] < m["hi"]


def test_the_composed_config_is_the_library_default():
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    import experiments.train_baseline  # noqa: F401  (registers the schema)
    from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = OmegaConf.to_object(compose("train_baseline"))
    assert cfg.model == LearnedModelConfig() and cfg.data == LearnedDataConfig() and cfg.fit == LearnedFitConfig()


def test_validate_refuses_a_missing_fold_model_before_any_work(tmp_path, shared_data):
    env = {**os.environ, "SOMTORCH_CACHE": str(tmp_path)}
    env.pop("HYDRA_FULL_ERROR", None)
    proc = subprocess.run([sys.executable, "-m", "experiments.validate", "datasets=[kitti2015]", "baselines=[learned]",
                           f"paths.data_dir={shared_data}", f"hydra.run.dir={tmp_path / 'run'}"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "somtorch-train-baseline 'data.cameras=[oakd,middlebury]'" in lines[0]
