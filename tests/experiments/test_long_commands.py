"""Every long command answers SIGINT / SIGTERM like ``somtorch-run`` (real processes, real signals):
it first says what it will do (job count, estimate), then a signal gives one line, ``FAILED``,
130 / 143, and no process of its group is left (validate's workers included, no leaked semaphore)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .test_interrupt import _wait_for
from .test_launcher import _group_gone, _workers

ROOT = Path(__file__).resolve().parents[2]
LONG = "train.epochs=100000"  # a cold training long enough to be stopped in
COMMANDS = {
    "validate": ["experiments.validate", "ensemble=20", LONG, "frames=[kitti,kitti_est,oakd_toy,oakd_cycles]",
                 "~grid", "~neutral", "+grid={objects.merge: [0.0, 0.5]}", "+neutral={objects.merge: 0.0}", "workers=2"],
    "scenes": ["experiments.real_scenes", "ensemble=20", LONG, "frames=[kitti,oakd_toy]"],
    "video": ["experiments.video", LONG, "sequence.frames=5"],
}
ANNOUNCED = {"validate": "validate: 4 frames x 3 candidates x 2 grids, 2 workers, estimated ~",
             "scenes": "scenes: 2 scenes x 1 method(s), estimated ~", "video": "video: 5 frames of 1264x720, estimated ~"}


@pytest.mark.slow
@pytest.mark.parametrize("command, sig, group", [
    ("validate", signal.SIGINT, True),    # Ctrl-C in a terminal: the whole process group
    ("validate", signal.SIGINT, False),   # kill -INT <pid>: the command alone, which ends its workers
    ("validate", signal.SIGTERM, False),
    ("scenes", signal.SIGINT, False),
    ("video", signal.SIGTERM, False),
])
def test_a_long_command_stops_on_a_signal_with_one_line(tmp_path, shared_data, command, sig, group):
    folder = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", *COMMANDS[command], f"hydra.run.dir={folder}",
                          f"paths.data_dir={shared_data}"], cwd=ROOT, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, start_new_session=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"})
    try:
        assert p.stderr is not None
        first = p.stderr.readline()  # the job count and the estimate, before the work
        assert first.startswith(ANNOUNCED[command]), first
        if command == "validate":
            assert _wait_for(lambda: len(_workers(p.pid)) == 2, 120), "validate never started its workers"
        time.sleep(2)  # into the work
        assert p.poll() is None
        (os.killpg if group else os.kill)(p.pid, sig)
        _, err = p.communicate(timeout=300)
    finally:
        if not _group_gone(p.pid):
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 128 + sig, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err  # the interrupt's line; no traceback, no "leaked semaphore" warning
    assert lines[0].startswith(f"interrupted ({signal.Signals(sig).name}) "), lines[0]
    assert lines[0].endswith(f"partial results not written; {folder / 'FAILED'}"), lines[0]
    assert (folder / "FAILED").exists() and not (folder / "metrics.json").exists()
    assert not list(folder.glob(".partial-*"))
    assert _wait_for(lambda: _group_gone(p.pid), 30), "a process of the command outlived it"
