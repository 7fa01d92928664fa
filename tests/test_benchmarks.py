"""The benchmarks run end to end (--quick smoke mode) and report every targeted row."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("script", ["bench_core.py", "bench_pipeline.py", "bench_learned.py"])
def test_benchmark_quick_run_writes_its_results(script, tmp_path):
    out = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--json", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "PASS" in proc.stdout or "FAIL" in proc.stdout
    res = json.loads(out.read_text())
    assert res["quick"] is True
    assert res["results"], "no result rows"
    assert res["machine"] and res["command"]


def test_bench_core_busy_mode_reports_the_slowdown_and_peer_rows(tmp_path):
    out = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_core.py"), "--quick", "--busy",
                           "--json", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(out.read_text())["results"]
    keys = {r["key"] for r in res["rows"]}
    assert {"bmu", "bmu_read", "bmu_kmeans", "online", "ensemble_batch", "ensemble_large"} <= keys
    names = [row[0] for row in res["busy"]]
    assert names[0].startswith("BMU, ") and names[1:3] == ["batch map E=100, 10 epochs", "online rule, 10 epochs"]
    assert all(float(row[3].rstrip("x")) > 0 for row in res["busy"])  # slowdowns measured
    assert {r["grid"] for r in res["quality"]} == {"4x7", "16x16"}
    assert all(0 < r["qe"] < 1 for r in res["quality"])
    assert "One core busy" in proc.stdout and "Quality at equal epochs" in proc.stdout
    assert "Speed at matched quality" in proc.stdout  # a table, or the line saying no peer is installed
