"""SIGINT / SIGTERM from the first instruction of a command: one line, 130 / 143, never a traceback.

A real command is started and signalled as soon as its start-up handler is in place (the kernel
says so: ``SigCgt`` of ``/proc/PID/status`` lists SIGTERM, which Python itself does not catch),
and again later during its imports and Hydra's composition, or inside the job.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from .test_interrupt import _wait_for

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")


def _catches_sigterm(pid: int) -> bool:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    except OSError:
        pass
    return False


def _signalled(args: list[str], sig: int, after: str, tmp_path: Path) -> tuple[int, list[str]]:
    """Start ``python args``, send ``sig`` once its handler is in (``after="handler"``) or once it has
    created its output folder (``after="folder"``): (exit status, stderr lines)."""
    folder = tmp_path / "out"
    p = subprocess.Popen([sys.executable, *args, f"hydra.run.dir={folder}", "output.tensorboard=false"], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert _wait_for(lambda: _catches_sigterm(p.pid), 60), "the command never installed its handler"
        if after == "folder":
            assert _wait_for(lambda: folder.is_dir() or p.poll() is not None, 300)
        p.send_signal(sig)
        _, err = p.communicate(timeout=300)
    finally:
        p.kill()
    return p.returncode, [ln for ln in err.splitlines() if ln.strip()]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("args", [["-m", "experiments.run"],  # as in a clone
                                  ["-c", "from experiments.entry import study; study()"]],  # as the console script
                         ids=["run", "study-entry"])
def test_a_signal_during_the_imports_gives_one_line(tmp_path, sig, args):
    code, lines = _signalled(args, sig, "handler", tmp_path)
    assert code == 128 + sig
    assert lines == [f"interrupted ({signal.Signals(sig).name}) during start-up"]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_once_hydra_made_the_folder_gives_one_line(tmp_path, sig):
    # the library's handler by then (start-up or the job itself): still one line, no traceback
    code, lines = _signalled(["-m", "experiments.run", "train.epochs=100000"], sig, "folder", tmp_path)
    assert code == 128 + sig, lines
    assert len(lines) == 1 and lines[0].startswith(f"interrupted ({signal.Signals(sig).name})"), lines
