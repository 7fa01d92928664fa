"""The resource estimate against the measured peak memory of small real runs, the memory probe,
and the refusal of absurd runs before any work."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from somtorch.resources import Estimate, ResourceError, available_memory, check, estimate

ROOT = Path(__file__).resolve().parents[1]
FACTOR = 2.5  # the estimate is an upper bound of the measured increase and at most FACTOR times it

_PEAK = textwrap.dedent("""
    import json, sys
    import torch
    def kib(field):  # this process's own figures (its VmHWM starts afresh at exec, unlike ru_maxrss)
        with open('/proc/self/status') as f:
            return next(int(l.split()[1]) for l in f if l.startswith(field + ':'))
    case = sys.argv[1]
    if case == "train":
        from somtorch.core import SOM
        from somtorch.resources import estimate
        x = torch.rand(2000, 3, generator=torch.Generator().manual_seed(0))
        SOM(4, 4, 3, ensemble=2, seed=0).fit(x, mode="batch", epochs=1, progress=False)  # warm-up
        run = lambda: SOM(32, 32, 3, ensemble=100, seed=0).fit(x, mode="batch", epochs=2, progress=False)
        est = lambda: estimate(height=1, width=2000, valid=2000, train=2000, units=1024, members=100, epochs=2)
    else:
        from somtorch.config import with_overrides
        from somtorch.disparity import load_scene
        from somtorch.pipeline import PipelineConfig, resource_estimate, run_pipeline
        scene = load_scene("motorcycle")
        cfg = with_overrides(PipelineConfig(), json.loads(case))
        run_pipeline(scene, with_overrides(cfg, {"ensemble": 1, "train.epochs": 1}))  # warm-up
        run = lambda: run_pipeline(scene, cfg)
        est = lambda: resource_estimate(scene, cfg)
    with open('/proc/self/clear_refs', 'w') as f:
        f.write('5')  # the peak (VmHWM) starts again at the current RSS
    base = kib('VmRSS')
    run()
    print(json.dumps({"measured": 1024 * (kib('VmHWM') - base), "estimate": est().peak_bytes}))
""")


@pytest.mark.slow
@pytest.mark.parametrize("case", ["train", '{"ensemble": 400}', '{"ensemble": 40, "features.train_stride": 1}'])
def test_estimate_bounds_the_measured_peak(case):
    """Peak RSS increase of a real run (fresh process, after a warm-up) ≤ estimate ≤ FACTOR × it.
    The peak is the process's own ``VmHWM`` (reset after the warm-up through ``clear_refs``, as
    ``benchmarks/bench_learned.py`` does), not ``ru_maxrss``: on Linux a child keeps the high-water
    mark of the memory it shared with its parent before ``exec`` — an xdist worker grown large in a
    whole-suite run — so the same run measured 739, 808 and 864 MB there and 360-390 MB from a
    small parent (session 10)."""
    out = subprocess.run([sys.executable, "-c", _PEAK, case], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout.strip().splitlines()[-1])
    if case == "train":
        # the batch engine of 2026-12-02 (one shared (K, K) neighbourhood table; the BMU bounds'
        # (E, K, K) float64 unit distances only in some epochs) measured 43-290 MB here against the
        # model's three (E, K, K) tables (1.4 GB): an upper bound only, until the model follows it
        assert r["measured"] <= r["estimate"], r
        return
    assert r["measured"] > 150 << 20, r  # big enough for the stage to dominate the allocator's slack
    assert r["measured"] <= r["estimate"] <= FACTOR * r["measured"], r


def test_estimate_scales_with_members_and_epochs():
    one = estimate(height=480, width=640, valid=300_000, train=3_000)
    many = estimate(height=480, width=640, valid=300_000, train=3_000, members=1_000_000)
    assert many.peak_bytes > 1000 * one.peak_bytes
    long = estimate(height=480, width=640, valid=300_000, train=3_000, epochs=10 ** 9)
    assert long.peak_bytes == one.peak_bytes and long.seconds > 1e8 * one.train_s
    online = estimate(height=480, width=640, valid=300_000, train=300_000, mode="online", units=28, members=100)
    # the paper preset on every pixel, 100 members: measured 7-18 s a job (table1 study), not minutes or days
    assert 3 < online.seconds < 60


def test_check_refuses_in_one_line():
    est = estimate(height=480, width=640, valid=300_000, train=3_000, members=1_000_000)
    with pytest.raises(ResourceError) as e:
        check(est, available=(16 << 30, "MemAvailable"))
    msg = str(e.value)
    assert "\n" not in msg and "resources.max_memory_frac=" in msg and "resources.check=false" in msg
    assert "GiB peak" in msg
    check(Estimate(1 << 30, 0, 0, 1 << 30, 1.0, 0, 0), available=(2 << 30, "x"))  # within 0.8 x 2 GiB
    with pytest.raises(ResourceError, match="time budget of 1 h"):
        check(Estimate(0, 0, 0, 0, 7200.0, 0, 0), max_hours=1, available=(2 << 30, "x"))


def _fake_tree(tmp_path, meminfo_kb, files):
    (tmp_path / "proc").mkdir(parents=True)
    (tmp_path / "proc/meminfo").write_text(f"MemTotal: 99999999 kB\nMemAvailable: {meminfo_kb} kB\n")
    for name, text in files.items():
        p = tmp_path / "sys/fs/cgroup" / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


def test_available_memory_honours_cgroups(tmp_path):
    gib = 1 << 30
    v2 = _fake_tree(tmp_path / "v2", 64 * 1024 * 1024, {"memory.max": f"{8 * gib}\n", "memory.current": f"{3 * gib}\n"})
    assert available_memory(v2) == (5 * gib, "cgroup v2 memory.max - usage")
    unlimited = _fake_tree(tmp_path / "max", 2 * 1024 * 1024, {"memory.max": "max\n", "memory.current": "1\n"})
    assert available_memory(unlimited) == (2 * gib, "MemAvailable")
    v1 = _fake_tree(tmp_path / "v1", 64 * 1024 * 1024, {"memory/memory.limit_in_bytes": f"{4 * gib}",
                                                        "memory/memory.usage_in_bytes": f"{1 * gib}"})
    assert available_memory(v1) == (3 * gib, "cgroup v1 memory.limit_in_bytes - usage")
    v1_none = _fake_tree(tmp_path / "v1n", 1024 * 1024, {"memory/memory.limit_in_bytes": "9223372036854771712",
                                                         "memory/memory.usage_in_bytes": "5"})
    assert available_memory(v1_none) == (gib, "MemAvailable")
    real, source = available_memory()
    assert real > 0 and source != "unknown"


@pytest.mark.parametrize("override", ["ensemble=1000000", "train.epochs=1000000000"])
def test_run_refuses_before_any_work(tmp_path, override):
    """The two runs that were OOM-killed after 80-93 s: refused at once, one line, FAILED marker."""
    out = subprocess.run([sys.executable, "-m", "experiments.run", override, f"hydra.run.dir={tmp_path}/r"],
                         capture_output=True, text=True, cwd=ROOT, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "resources." in lines[0], out.stderr
    assert "Traceback" not in out.stderr
    folder = tmp_path / "r"
    assert (folder / "FAILED").exists() and not (folder / ".lock").exists()
    assert not list(folder.glob(".partial-*")) and not (folder / "metrics.json").exists()
    log_lines = (folder / "run.log").read_text().strip().splitlines()
    assert len(log_lines) == 1 and "ResourceError" in log_lines[0]  # nothing ran before the refusal


def test_the_torch_path_is_estimated_at_its_own_cost(monkeypatch):
    """Issue 34: without the compiled kernels (no compiler, SOMTORCH_NATIVE=0) 1000 online epochs took
    57 s where the estimate said 0.3 s; the torch path has its own per-step costs now."""
    from somtorch.config import PipelineConfig, with_overrides
    from somtorch.disparity import load_scene
    from somtorch.pipeline import resource_estimate

    sizes = dict(height=500, width=741, valid=343_274, train=2_800, units=64, epochs=1000)
    for mode in ("online", "batch"):
        fast, slow = (estimate(**sizes, mode=mode, native=n).train_s for n in (True, False))
        assert slow > (20 if mode == "online" else 5) * fast, mode  # (a batch epoch has fixed costs too)
    assert 30 < estimate(**sizes, mode="online", native=False).train_s < 120  # measured: 57 s

    scene = load_scene("motorcycle")
    online = with_overrides(PipelineConfig(), {"train.mode": "online", "train.epochs": 1000})
    monkeypatch.setenv("SOMTORCH_NATIVE", "0")
    off = resource_estimate(scene, online).train_s
    monkeypatch.setenv("SOMTORCH_NATIVE", "1")
    bubble = resource_estimate(scene, with_overrides(online, {"train.neighborhood": "bubble"})).train_s
    assert off == bubble  # the online loop is compiled for the Gaussian only
    gpu = resource_estimate(scene, with_overrides(online, {"device": "cuda"})).train_s
    assert gpu < off / 20  # a GPU is not charged the CPU's torch loop
