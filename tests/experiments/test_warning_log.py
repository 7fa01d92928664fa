"""experiments.warning_log: the pipeline's per-run warnings go to one file (this process and real
worker processes), and the console gets one line counting them."""

from __future__ import annotations

import logging

from experiments.warning_log import warnings_to_file, worker_start
from somtorch.interrupt import worker_pool


def _warn(text: str) -> int:
    logging.getLogger("somtorch.pipeline").warning("scene %s: the kept areas cover the whole map", text)
    return 1


def test_the_runs_warnings_go_to_the_file_and_one_line_counts_them(tmp_path, capsys, caplog):
    path = tmp_path / "runs.log"
    with caplog.at_level(logging.WARNING):
        with warnings_to_file(path, "validate"):
            for i in range(3):
                _warn(f"here{i}")
            with worker_pool(2, worker_start, (str(path),)) as pool:  # real spawned workers
                assert sum(pool.map(_warn, [f"worker{i}" for i in range(4)])) == 4
            logging.getLogger("somtorch.validate").warning("a frame left out")  # not a run's warning
        _warn("after")  # the block is over: back to the usual handlers
    text = path.read_text()
    assert all(f"scene {w}:" in text for w in ("here0", "here2", "worker0", "worker3"))
    assert "after" not in text and "left out" not in text
    err = capsys.readouterr().err
    assert err.splitlines() == [f"validate: 7 warning(s) of the scored runs (maps kept whole, no object, maps that "
                                f"disagree, strides adjusted) in {path}"]
    seen = [r.getMessage() for r in caplog.records]
    assert "a frame left out" in seen and any("after" in m for m in seen)
    assert not any("here" in m for m in seen)


def test_no_warning_no_line(tmp_path, capsys):
    with warnings_to_file(tmp_path / "runs.log", "validate"):
        pass
    assert capsys.readouterr().err == "" and not (tmp_path / "runs.log").exists()


def test_an_interrupted_block_leaves_the_one_line_to_the_interrupt(tmp_path, capsys):
    import pytest

    with pytest.raises(KeyboardInterrupt):
        with warnings_to_file(tmp_path / "runs.log", "validate"):
            _warn("before the signal")
            raise KeyboardInterrupt
    assert capsys.readouterr().err == ""
    assert "before the signal" in (tmp_path / "runs.log").read_text()
    assert logging.getLogger("somtorch.pipeline").propagate  # the routing is undone
