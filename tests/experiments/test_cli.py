"""Overrides are checked before Hydra: unknown keys and options get a "did you mean"."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from experiments.cli import check_overrides
from experiments.real_scenes import ScenesConfig
from experiments.schema import RunConfig
from experiments.study import StudyConfig
from experiments.validate import ValidateConfig
from experiments.video import VideoConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("args, expect", [
    (["objects.simlarity=0.1"], "did you mean 'objects.similarity'"),
    (["train.epoch=3"], "did you mean 'train.epochs'"),
    (["objects=robst"], "did you mean 'robust'"),
    (["data=kitti"], "did you mean 'kitti2015'"),
    (["som=grid8x9"], "did you mean 'grid8x8'"),
    (["ensemble=2", "reduction.tolerance_imag=0.1"], "did you mean 'reduction.tolerance_image'"),
])
def test_typos_are_named_with_the_nearest_key(args, expect):
    err = check_overrides(args, RunConfig)
    assert err is not None and expect in err


@pytest.mark.parametrize("args", [
    ["ensemble=3", "objects.similarity=0.1", "objects=paper", "data=kitti2015", "+preset=paper",
     "hydra.run.dir=/tmp/x", "~output.maps", "++foo=1", "data.sgbm.numDisparities=64", "-m",
     "objects.similarity=0.01,0.05", "hydra/launcher=joblib", "train=online,batch"],
])
def test_valid_overrides_pass(args):
    assert check_overrides(args, RunConfig) is None


@pytest.mark.parametrize("name, schema", [("run", RunConfig), ("study", StudyConfig), ("validate", ValidateConfig),
                                          ("real_scenes", ScenesConfig), ("video", VideoConfig)])
def test_every_composed_key_is_known(name, schema):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(name)
    flat = []

    def walk(node, prefix=""):
        for k, v in node.items():
            if isinstance(v, dict) and v:
                walk(v, f"{prefix}{k}.")
            else:
                # (a list as a list: its value is checked too)
                flat.append(f"{prefix}{k}={json.dumps(v) if not isinstance(v, dict) else 0}")

    walk(OmegaConf.to_container(cfg, resolve=False))
    assert check_overrides(flat, schema) is None


def test_the_command_line_stops_in_one_line():
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "objects.simlarity=0.1"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "error: unknown config key 'objects.simlarity': did you mean 'objects.similarity'? (--cfg job prints every key)"]


@pytest.mark.parametrize("module", ["run", "study", "validate", "real_scenes", "video"])
def test_help_is_instant_and_lists_groups_and_keys(module):
    proc = subprocess.run([sys.executable, "-m", f"experiments.{module}", "--help"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert f"python -m experiments.{module}" in out and re.search(r"objects: paper, robust\b", out)
    assert "objects.similarity=0.05" in out and "train.epochs=10" in out
    assert "scene_lists" not in out


@pytest.mark.parametrize("module, schema", [("run", RunConfig), ("study", StudyConfig),
                                            ("validate", ValidateConfig), ("video", VideoConfig)])
def test_help_describes_every_key(module, schema):
    """Every config key a newcomer can set (every leaf of the experiment's schema: data.*, device,
    baseline.* included) is listed with its default and a description."""
    from experiments.cli import field_types
    from experiments.help import help_text

    text = help_text(module)
    keys = [line for line in text.splitlines() if re.match(r"^  [a-z_.]+(<name>)?=", line)]
    assert len(keys) > 40
    bare = [line.split("=")[0].strip() for line in keys if " — " not in line]
    assert not bare, f"keys without a description in --help: {bare}"
    listed = {line.split("=")[0].strip() for line in keys}
    missing = [k for k in field_types(schema) if k not in listed and not k.startswith("data.sgbm.")]
    assert not missing, f"keys missing from --help: {missing}"
    assert "data.sgbm.<name>=" not in text and "  data.sgbm.<name>  — " in text
    for key in ("data.source", "data.left", "data.right", "data.calibration", "data.frame",
                "data.disparity_scale", "device"):
        assert key in listed
    assert "default_factory" not in text  # a list default reads as the list it makes
    if module == "validate":
        assert "  frame_shifts=[0, 5]  — " in text
        assert "  baselines=['plane_components', 'uv_disparity']  — " in text


def test_help_names_the_command_that_was_typed():
    from experiments.help import help_text, prog

    assert prog("run", "/home/u/.venv/bin/somtorch-run") == "somtorch-run"
    assert prog("run", "/repo/experiments/run.py") == "python -m experiments.run"
    assert help_text("study", "somtorch-study").startswith("somtorch-study [group=option")


def test_the_8bit_png_advice_is_a_key_the_command_line_takes(tmp_path):
    import cv2
    import numpy as np

    from somtorch.disparity import read_disparity
    from somtorch.validation import DataFileError

    path = tmp_path / "vis.png"
    cv2.imwrite(str(path), np.full((4, 5), 7, np.uint8))
    with pytest.raises(DataFileError) as info:
        read_disparity(path)
    advice = re.search(r"(data\.\w+=\S+)", str(info.value)).group(1)
    assert advice == "data.disparity_scale=1.0"
    assert check_overrides(["data=file", f"data.source={path}", advice], RunConfig) is None


def test_help_does_not_import_torch():  # what makes it instant (0.17 s here against 5.5 s with torch)
    code = "import sys; from experiments.help import help_text; help_text('run'); print('torch' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "False", proc.stderr


@pytest.mark.parametrize("args, expect", [
    (["train.epochs=abc"], "train.epochs=abc: expected an int"),
    (["objects.similarity=x"], "expected a float"),
    (["output.maps=maybe"], "expected a bool"),
    (["ensemble=2.5"], "ensemble=2.5: expected an int"),
    (["train.epochs=3,abc"], "train.epochs=abc"),  # each value of a sweep
])
def test_values_of_the_wrong_type_are_named(args, expect):
    err = check_overrides(args, RunConfig)
    assert err is not None and expect in err


def test_a_list_key_given_no_list_is_named_in_one_line():
    """Hydra's own message for a scalar given to a list key is five lines; ours is one."""
    from experiments.validate import ValidateConfig

    for arg in ("frame_shifts=5", "transforms=flip"):
        key, value = arg.split("=")
        assert check_overrides([arg], ValidateConfig) == f"{arg}: expected a list, e.g. {key}=[{value}]"
    assert check_overrides(["datasets=oakd"], ValidateConfig) == (
        "datasets=oakd: expected a list, e.g. datasets=[oakd] or null")
    for arg in ("frame_shifts=[a]", "frame_shifts=[0, 2.5]", "frame_shifts=[true]"):
        assert check_overrides([arg], ValidateConfig) == f"{arg}: expected a list of whole numbers"
    # what Hydra reads as a list passes
    assert check_overrides(["frame_shifts=[0]", "frame_shifts=[0,5]", "transforms=[]",
                            'transforms=["shift:5"]', "datasets=null", "frames=[kitti,oakd_toy]",
                            "baselines=[]"], ValidateConfig) is None


def test_values_of_the_right_type_pass():
    assert check_overrides(["train.sigma=null", "train.sigma=2", "objects.similarity=1", "object_id=null",
                            "output.maps=false", "train.epochs=range(1,4)"], RunConfig) is None


def test_the_suite_runs_without_plugin_warnings():
    """pytest's own output is clean: dash's testing plugin (installed with open3d) registers an
    old-style hook that warned on every run; pyproject.toml disables it (-p no:dash)."""
    proc = subprocess.run([sys.executable, "-m", "pytest", "--co", "-q", "-p", "no:cacheprovider",
                           "tests/test_atomic.py"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert "warnings summary" not in proc.stdout and "PytestRemovedIn" not in proc.stdout + proc.stderr
