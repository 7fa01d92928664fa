"""Every notebook in notebooks/ executes top to bottom in a real Jupyter kernel (nbclient), on the
short settings of ``SOMTORCH_NOTEBOOK_TEST`` (its cells assert results that can fail), and is
stored with its outputs (figures included) so that a reader on GitHub sees them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_the_four_notebooks_are_there():
    assert {p.stem for p in NOTEBOOKS} >= {"quickstart", "tables", "differentiable_som", "your_own_data"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes_in_a_kernel(path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is in the test extra")
    monkeypatch.setenv("SOMTORCH_NOTEBOOK_TEST", "1")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend (headless) shows the figures
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()  # raises CellExecutionError (with the cell and its traceback) on any failure
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs), "the notebook draws a figure"
    assert os.environ["SOMTORCH_NOTEBOOK_TEST"] == "1"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_stored_notebook_has_its_outputs(path):
    import json

    nb = json.loads(path.read_text())
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert code and all(c.get("execution_count") for c in code), "executed, in order"
    assert any("image/png" in o.get("data", {}) for c in code for o in c.get("outputs", []))
    assert path.stat().st_size < 1_000_000  # small outputs
