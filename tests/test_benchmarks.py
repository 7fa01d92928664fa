"""The benchmarks run end to end (--quick smoke mode) and report every targeted row."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("script", ["bench_core.py", "bench_pipeline.py"])
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
