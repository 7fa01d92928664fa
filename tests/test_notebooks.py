"""Every notebook in notebooks/ executes top to bottom in a real Jupyter kernel (nbclient) exactly
as a reader runs it — its cells assert results that can fail, and nothing skips them — and is stored
with its outputs (figures included) so that a reader on GitHub sees them.

The one setting the suite changes is a papermill-style parameter: a cell tagged ``parameters`` is
followed by an injected cell (``RUNS = 5`` in tables.ipynb), as ``papermill -p RUNS 5`` does.
Regenerate the stored outputs with ``jupyter nbconvert --to notebook --execute --inplace
notebooks/*.ipynb`` (the README's notebooks section)."""

from __future__ import annotations

from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
PARAMETERS = {"tables": "RUNS = 5"}  # the suite's shorter run count; assertions unchanged


def test_the_four_notebooks_are_there():
    assert {p.stem for p in NOTEBOOKS} >= {"quickstart", "tables", "differentiable_som", "your_own_data"}


def test_no_notebook_reads_a_test_switch():
    """A notebook behaves the same in the suite and for a reader: no environment switch."""
    for path in NOTEBOOKS:
        text = path.read_text()
        assert "os.environ" not in text and "NOTEBOOK_TEST" not in text, path.name


def _inject(nb, source: str) -> None:
    import nbformat

    (i,) = [k for k, c in enumerate(nb.cells) if "parameters" in c.get("metadata", {}).get("tags", [])]
    cell = nbformat.v4.new_code_cell(source)
    cell.metadata["tags"] = ["injected-parameters"]
    nb.cells.insert(i + 1, cell)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes_in_a_kernel(path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is in the test extra")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend (headless) shows the figures
    nb = nbformat.read(path, as_version=4)
    if path.stem in PARAMETERS:
        _inject(nb, PARAMETERS[path.stem])
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()  # raises CellExecutionError (with the cell and its traceback) on any failure
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs), "the notebook draws a figure"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_stored_notebook_has_its_outputs(path):
    import json

    nb = json.loads(path.read_text())
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    assert code and all(c.get("execution_count") for c in code), "executed, in order"
    assert [c["execution_count"] for c in code] == list(range(1, len(code) + 1)), "executed top to bottom"
    assert any("image/png" in o.get("data", {}) for c in code for o in c.get("outputs", []))
    assert path.stat().st_size < 1_000_000  # small outputs
