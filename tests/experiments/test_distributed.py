"""torchrun launches of the main job: two gloo processes give the single-process results."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _torchrun(tmp_path, *overrides):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "-m", "experiments.distributed", f"paths.output_dir={tmp_path}", "output.pointcloud=false",
           "output.maps=false", "output.tensorboard=false", *overrides]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = list((tmp_path / "distributed").glob("*/metrics.json"))
    assert len(runs) == 1, runs  # rank 1 wrote nothing
    return json.loads(runs[0].read_text())


def _single(*overrides):
    from experiments.distributed import compose_config
    from experiments.run import load_input
    from somtorch.pipeline import run_pipeline

    cfg, _ = compose_config(["train.parallel=none", *overrides])
    return run_pipeline(load_input(cfg), cfg, metrics=False)


@pytest.mark.parametrize("parallel", ["data", "members"])
def test_two_ranks_keep_what_one_process_keeps(tmp_path, parallel):
    m = _torchrun(tmp_path, f"train.parallel={parallel}", "ensemble=3")
    ref = _single("ensemble=3")
    assert len(m["members"]) == 3
    for got, want in zip(m["members"], ref.members):
        assert [tuple(a["box_xyxy"]) for a in got["kept_areas"]] == [tuple(a.box) for a in want.kept]
        assert got["reduction_union"] == pytest.approx(want.reduction.reduction_union, abs=1e-9)


def test_outside_torchrun_the_error_says_how_to_launch():
    proc = subprocess.run([sys.executable, "-m", "experiments.distributed"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, env={k: v for k, v in os.environ.items()
                                                       if k not in ("RANK", "WORLD_SIZE")})
    assert proc.returncode == 2 and "torchrun" in proc.stderr


def test_data_parallel_refuses_the_online_rule():
    from somtorch.config import TrainConfig

    with pytest.raises(ValueError, match="parallel='data'"):
        TrainConfig(mode="online", parallel="data")
    with pytest.raises(ValueError, match="train.parallel"):
        _single("train.parallel=members")  # no process group in this process


def test_srun_style_launch_without_torchrun(tmp_path):
    """What scripts/slurm_distributed.sh does on each task: SLURM's ids, an exported master."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    base = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK")}
    base.update(SLURM_NTASKS="2", MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), OMP_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "experiments.distributed", f"paths.output_dir={tmp_path}", "output.pointcloud=false",
           "output.maps=false", "output.tensorboard=false", "ensemble=2"]
    procs = [subprocess.Popen(cmd, cwd=ROOT, env={**base, "SLURM_PROCID": str(r), "SLURM_LOCALID": str(r)},
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for r in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs[0][1][-2000:] + outs[1][1][-2000:]
    assert len(list((tmp_path / "distributed").glob("*_data_w2/metrics.json"))) == 1


def test_srun_without_a_master_is_refused():
    from experiments.distributed import _from_slurm

    env = {"SLURM_PROCID": "1", "SLURM_NTASKS": "4"}
    with pytest.raises(ValueError, match="MASTER_ADDR"):
        _from_slurm(env)
    env = {"SLURM_PROCID": "1", "SLURM_NTASKS": "4", "MASTER_ADDR": "n1", "MASTER_PORT": "1"}
    _from_slurm(env)
    assert (env["RANK"], env["WORLD_SIZE"], env["LOCAL_RANK"]) == ("1", "4", "0")
