"""NaN and infinities are refused in every numeric config field and every spelling, in one line,
exit status 2 (issue 34): on the command line, in a YAML preset, and in a sweep before any job runs."""

from __future__ import annotations

import os
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from experiments.cli import FINITE_HINT, _value_error, check_overrides, field_types
from experiments.real_scenes import ScenesConfig
from experiments.schema import RunConfig
from experiments.study import StudyConfig
from experiments.synth_config import SynthConfig
from experiments.validate import ValidateConfig
from experiments.video import VideoConfig
from somtorch.config.constraints import nonfinite

ROOT = Path(__file__).resolve().parents[2]
# YAML's (.nan, .inf), Python's and Hydra's (nan, inf, Infinity), and a float beyond float64
SPELLINGS = [".nan", ".NaN", ".NAN", "nan", "NaN", ".inf", "+.inf", "-.inf", ".Inf", "-.INF", "inf", "-inf", "+inf",
             "Infinity", "-Infinity", "1e999", "-1e999", "1E400"]
SCHEMAS = [RunConfig, StudyConfig, ValidateConfig, VideoConfig, ScenesConfig, SynthConfig]


def _numeric_keys(schema: type) -> list[str]:
    keys = []
    for key, t in field_types(schema).items():
        if typing.get_origin(t) is list:  # a list of numbers (frame_shifts): not a number
            continue
        args = typing.get_args(t)
        base = next((a for a in args if a is not type(None)), t) if args else t
        if base in (int, float):
            keys.append(key)
    return keys


@pytest.mark.parametrize("schema", SCHEMAS, ids=lambda s: s.__name__)
def test_every_numeric_field_refuses_every_spelling(schema):
    types = field_types(schema)
    keys = _numeric_keys(schema)
    assert len(keys) >= 4
    for key in keys:
        for v in SPELLINGS:
            for value in (v, f"1,{v}"):  # alone, or in a sweep
                err = _value_error(key, value, types[key])
                assert err == f"{key}={v}: expected a finite number ({FINITE_HINT})", (key, value, err)
    # the whole check, as the command line runs it: plain, forced (++) and swept
    key = keys[-1]
    for arg in (f"{key}=.nan", f"++{key}=-.inf", f"{key}=1,1e999"):
        assert "expected a finite number" in (check_overrides([arg], schema) or ""), arg


def test_finite_values_still_pass():
    assert check_overrides(["train.lr=0.5", "data.focal_px=1e3", "ensemble=2", "objects.similarity=0.1,0.2"],
                           StudyConfig) is None


def test_nonfinite_names_the_first_bad_key():
    assert nonfinite({"a": {"b": [1.0, float("-inf")]}, "c": float("nan")}) == ("a.b[1]", float("-inf"))
    assert nonfinite({"a": 1, "b": [0.5, "inf"], "c": None}) is None  # a string is not a number


def _cli(*args: str, config_dir: Path | None = None, module: str = "run") -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("HYDRA_FULL_ERROR", None)
    extra = ["--config-dir", str(config_dir)] if config_dir else []
    return subprocess.run([sys.executable, "-m", f"experiments.{module}", *extra, *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("value", [".nan", "-.inf", "1e999"])
def test_the_command_line_refuses_a_nonfinite_value_in_one_line(value, tmp_path):
    p = _cli(f"train.lr={value}", f"hydra.run.dir={tmp_path}")
    assert p.returncode == 2, p.stderr
    assert p.stderr.strip() == (f"error: train.lr={value}: expected a finite number (NaN and infinities are not "
                                "config values, in any spelling)")


def test_a_nonfinite_value_in_a_yaml_preset_is_refused_in_one_line(tmp_path):
    (tmp_path / "preset").mkdir()
    (tmp_path / "preset" / "hostile.yaml").write_text("# @package _global_\ndata:\n  focal_px: .inf\n")
    p = _cli("+preset=hostile", f"hydra.run.dir={tmp_path / 'run'}", config_dir=tmp_path)
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: data.focal_px=inf: expected a finite number"), p.stderr
    assert not (tmp_path / "run" / "metrics.json").exists()


@pytest.mark.slow
@pytest.mark.parametrize("bad", ["yaml", "rule"])
def test_a_hostile_table1_sweep_is_refused_before_any_job_runs(tmp_path, bad):
    # the paper's 32-job sweep with a NaN in a preset (YAML) or a value its rules refuse (command line)
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "hostile.yaml").write_text(
        "# @package _global_\ndefaults:\n  - table1\n  - _self_\ntrain:\n  lr: .nan\n")
    args = ["+experiment=hostile"] if bad == "yaml" else ["+experiment=table1", "objects.map_stride=0"]
    p = _cli(*args, f"paths.output_dir={tmp_path / 'out'}", config_dir=tmp_path, module="study")
    assert p.returncode == 2, p.stderr
    errors = [line for line in p.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in p.stderr, p.stderr
    why = "train.lr=nan: expected a finite number" if bad == "yaml" else "objects.map_stride must be an integer"
    assert errors[0].startswith("error: job #0 (") and why in errors[0], errors
    assert "31 more job(s) refused too (#1, #2, #3, #4, #5, #6, #7, #8, #9, #10, ...); no job of the sweep was run" \
        in errors[0]
    sweep = tmp_path / "out" / "studies" / "table1"
    assert not [d for d in sweep.iterdir() if d.is_dir()] if sweep.exists() else True  # no job folder


def test_a_bad_job_refuses_a_basic_launcher_sweep_before_any_job_runs(tmp_path):
    # another launcher than somtorch's: the study's callback checks every job's config first
    p = _cli("-m", "hydra/launcher=basic", f"paths.output_dir={tmp_path}", "study=l", "ensemble=2",
             "output.maps=false", "output.tensorboard=false", "train.epochs=3,0", module="study")
    assert p.returncode == 2, p.stderr
    errors = [line for line in p.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in p.stderr, p.stderr
    assert errors[0].startswith("error: job #1 (") and "train.epochs must be an integer" in errors[0], errors
    assert "no job of the sweep was run" in errors[0]
    assert not list(tmp_path.glob("studies/l/*/metrics.json")) and not list(tmp_path.glob("studies/l/*/FAILED"))


@pytest.mark.parametrize("launcher", ["somtorch", "basic"])
def test_a_sweep_with_a_frame_no_run_can_score_is_refused_before_any_job_runs(tmp_path, launcher):
    """A generated SGBM frame may leave its main object without one valid pixel (garden frames of the
    Table 1 family): a study of it is refused in one line naming the job and the scene, before any
    job runs, instead of the job failing minutes into the sweep. Two labelled frames on disk, the
    second with its main object's disparity removed (``inf``: invalid in a PFM); the somtorch launcher
    and, through the study's callback, Hydra's basic one."""
    from dataclasses import replace as dc_replace

    from somtorch.synth.frame import generate_frame
    from somtorch.synth.store import write_frame

    frame = generate_frame("floor", 0, "oakd", sgbm=False)
    good = write_frame(frame, tmp_path / "good")
    gap = frame.disparity.clone()
    gap[frame.objects == 1] = float("inf")
    write_frame(dc_replace(frame, disparity=gap), tmp_path / "gap")
    p = _cli("--multirun", "data=file", f"data.source={good},{tmp_path / 'gap'}", "ensemble=1",
             f"paths.output_dir={tmp_path / 'out'}", "study=unscorable", f"hydra/launcher={launcher}",
             module="study")
    assert p.returncode == 2, p.stderr
    errors = [line for line in p.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in p.stderr, p.stderr
    assert errors[0].startswith("error: job #1 (") and "scene 'gap': the main object has no pixel with a valid " \
        "disparity, so no run of it can be scored" in errors[0] and "no job of the sweep was run" in errors[0], errors
    sweep = tmp_path / "out" / "studies" / "unscorable"
    assert not [d for d in sweep.iterdir() if d.is_dir()] if sweep.exists() else True  # no job folder
