"""Two studies into one output root (two real processes): each job runs once; the other study waits
for it and skips it (experiments.study.execute holds the job's folder, somtorch.locks)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SEEDS = (0, 1, 2)


@pytest.mark.slow
def test_a_second_study_into_the_same_root_waits_and_skips_what_the_first_ran(tmp_path):
    cmd = [sys.executable, "-m", "experiments.study", "-m", f"paths.output_dir={tmp_path}", "study=c", "ensemble=4",
           "train.epochs=500", "output.maps=false", "output.tensorboard=false", f"seed={','.join(map(str, SEEDS))}",
           "hydra.launcher.n_jobs=1"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    procs = [subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for _ in range(2)]  # the same command twice, at once
    outs = [p.communicate(timeout=900)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    ran = sum(line.endswith(" s") and "motorcycle OR: 4 runs" in line for out in outs for line in out.splitlines())
    skipped = sum("skipping " in line for out in outs for line in out.splitlines())
    assert (ran, skipped) == (len(SEEDS), len(SEEDS)), outs  # every job once, and once skipped by the other
    jobs = sorted((tmp_path / "studies" / "c").glob("*seed=*"))
    assert len(jobs) == len(SEEDS)
    assert sorted(json.loads((j / "metrics.json").read_text())["runs"]["seed"][0] for j in jobs) == list(SEEDS)
    for job in jobs:
        assert not (job / "FAILED").exists() and not list(job.glob(".partial-*")) and not list(job.glob(".lock*"))
