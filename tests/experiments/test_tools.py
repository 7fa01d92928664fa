"""The two report tools as Hydra entry points: ``experiments.ground_report`` and
``experiments.synth_gallery`` (real processes, real data and generated frames)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.tool_configs import GroundReportConfig, SynthGalleryConfig
from experiments.train_baseline_config import TrainBaselineConfig

ROOT = Path(__file__).resolve().parents[2]


def _run(module: str, *overrides: str, cwd: Path = ROOT, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run([sys.executable, "-m", f"experiments.{module}", *overrides], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_ground_report_prints_one_row_per_frame(shared_data):
    proc = _run("ground_report", "frames=[kitti,oakd_toy]", "after.support_frac=0.5",
                "before.rule=none", f"paths.data_dir={shared_data}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert lines[0] == "before: rule=none; after: rule=support support_frac=0.5"
    rows = [ln for ln in lines if ln.startswith("| ") and not ln.startswith("| frame")]
    assert [r.split(" | ")[0] for r in rows] == ["| kitti", "| oakd_toy"]
    for r in rows:  # before: no plane looked for; after: found or not, with its share
        cells = [c.strip() for c in r.strip("|").split("|")]
        assert cells[1] == "no" and cells[3] == "–" and re.fullmatch(r"no|yes \(\d+%\)", cells[2])


@pytest.mark.parametrize("module, bad, said", [
    ("ground_report", "after.bogus=1", "unknown config key 'after.bogus'"),
    ("ground_report", "frames=[nope]", "unknown frame(s) 'nope'"),
    ("ground_report", "before.rule=sideways", "rule"),
    ("synth_gallery", "families=[stair]", "families='stair' is not known"),
    ("synth_gallery", "scale=0", "scale"),
])
def test_bad_input_is_one_line_before_any_work(module, bad, said, tmp_path):
    proc = _run(module, bad, f"out={tmp_path}" if module == "synth_gallery" else "paths.data_dir=/nonexistent")
    assert proc.returncode == 2
    assert said in proc.stderr and "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_synth_gallery_draws_one_picture_per_family(tmp_path):
    import matplotlib.image as mpimg

    proc = _run("synth_gallery", "families=[stairs,garden]", "seeds=[0]", "scale=0.25", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["synth_garden.png", "synth_stairs.png"]
    img = mpimg.imread(tmp_path / "synth_stairs.png")
    assert img.shape[1] == 1600 and img[..., :3].std() > 0.05  # four panels, not blank


@pytest.mark.parametrize("module, schema", [("ground_report", GroundReportConfig),
                                            ("synth_gallery", SynthGalleryConfig),
                                            ("train_baseline", TrainBaselineConfig)])
def test_help_lists_every_key_without_torch(module, schema):
    from experiments.cli import field_types

    code = (f"import sys; from experiments.help import help_text; t = help_text({module!r}); "
            "print('torch' in sys.modules); print(t)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    first, *text = proc.stdout.splitlines()
    assert first == "False", proc.stderr
    keys = {ln.split("=")[0].strip(): ln for ln in text if re.match(r"^  [a-z_.]+=", ln)}
    assert set(field_types(schema)) == set(keys)
    assert all(" — " in ln for ln in keys.values())
    if module == "ground_report":  # the configured default of a nested config, not its class default
        from somtorch.config import GroundConfig

        assert keys["after.rule"].startswith("  after.rule='support'")
        assert keys["before.rule"].startswith(f"  before.rule={GroundConfig().rule!r}")
