"""Every notebook in notebooks/ runs top to bottom on small settings (code cells executed in order)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    monkeypatch.setenv("SOMTORCH_NOTEBOOK_TEST", "1")
    nb = json.loads(path.read_text())
    assert nb["nbformat"] == 4
    code = [("".join(c["source"]), i) for i, c in enumerate(nb["cells"]) if c["cell_type"] == "code"]
    assert code, f"{path.name} has no code cell"
    ns: dict = {"__name__": "__main__"}
    for src, i in code:
        exec(compile(src, f"{path.name}[cell {i}]", "exec"), ns)  # noqa: S102 - our own notebook
    import matplotlib.pyplot as plt

    assert plt.get_fignums(), "the notebook draws its figures"
    plt.close("all")
    assert os.environ["SOMTORCH_NOTEBOOK_TEST"] == "1"
