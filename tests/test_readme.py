"""Every ```python block of README.md runs exactly as printed, each in a fresh interpreter started
in an empty folder; a ``print(...)`` line whose comment shows its output must print that."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(), re.M | re.S)


def test_the_readme_has_python_blocks():
    assert len(BLOCKS) >= 2


@pytest.mark.slow
@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_readme_block_runs_as_printed(code, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}  # this checkout's somtorch, as an editable install gives
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    for line in code.splitlines():
        m = re.match(r"^print\(.*\)\s+#\s*(.+)$", line)
        if m:
            assert m.group(1).strip() in proc.stdout, (line, proc.stdout)
    assert not list(tmp_path.iterdir()), "a README snippet that says it writes no files wrote some"
