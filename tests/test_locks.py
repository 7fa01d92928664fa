"""Tests of somtorch.locks with real processes: a live owner keeps its folder, a killed one's lock heals."""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from somtorch.locks import FolderLocked, exclusive_folder, owner_alive, process_start

ROOT = Path(__file__).resolve().parents[1]
HOLDER = ("import sys, time\nfrom somtorch.locks import exclusive_folder\n"
          "with exclusive_folder(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(600)\n")


def _holder(folder: Path) -> subprocess.Popen:
    """A real process that holds ``folder``'s lock until it is killed."""
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], cwd=ROOT, stdout=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert p.stdout is not None and p.stdout.readline().strip() == "held"
    return p


def test_the_lock_names_its_owner_and_goes_with_it(tmp_path):
    with exclusive_folder(tmp_path) as lock:
        owner = json.loads(lock.read_text())
        assert owner == {"pid": os.getpid(), "start": process_start(os.getpid()), "host": socket.gethostname()}
    assert not lock.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary file left beside it


def test_a_live_owner_keeps_its_folder(tmp_path):
    p = _holder(tmp_path)
    try:
        with pytest.raises(FolderLocked, match=f"being written by the run of PID {p.pid} "):
            with exclusive_folder(tmp_path):
                pass
        assert json.loads((tmp_path / ".lock").read_text())["pid"] == p.pid  # the refusal touched nothing
    finally:
        p.kill()
        p.wait()


def test_the_lock_of_a_process_killed_with_sigkill_is_taken_over(tmp_path, caplog):
    p = _holder(tmp_path)
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert p.returncode == -signal.SIGKILL
    assert json.loads((tmp_path / ".lock").read_text())["pid"] == p.pid  # kill -9 left it behind
    with caplog.at_level(logging.WARNING, logger="somtorch.locks"):
        with exclusive_folder(tmp_path) as lock:
            assert json.loads(lock.read_text())["pid"] == os.getpid()
    said = [r.getMessage() for r in caplog.records]
    assert said == [f"{tmp_path}: took over the lock of PID {p.pid}, which is no longer running"]
    assert list(tmp_path.iterdir()) == []


def test_a_reused_pid_is_not_mistaken_for_the_owner(tmp_path):
    # this PID is alive, but the lock's owner started at another time: it died, its PID was reused
    me = {"pid": os.getpid(), "start": process_start(os.getpid()), "host": socket.gethostname()}
    assert owner_alive(me)
    assert not owner_alive({**me, "start": me["start"] + 1})
    (tmp_path / ".lock").write_text(json.dumps({**me, "start": me["start"] + 1}))
    with exclusive_folder(tmp_path) as lock:
        assert json.loads(lock.read_text()) == me


def test_a_lock_of_another_host_is_never_taken_over(tmp_path):
    (tmp_path / ".lock").write_text(json.dumps({"pid": 1, "start": 1, "host": "another-node"}))
    with pytest.raises(FolderLocked, match="PID 1 on another-node"):
        with exclusive_folder(tmp_path):
            pass
    assert (tmp_path / ".lock").exists()


def test_an_old_lock_holding_a_bare_pid_heals_too(tmp_path):
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # a PID that existed and is gone (reaped)
    (tmp_path / ".lock").write_text(str(p.pid))
    with exclusive_folder(tmp_path) as lock:
        assert json.loads(lock.read_text())["pid"] == os.getpid()


def test_process_start_tells_two_processes_apart():
    a = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        start = process_start(a.pid)
        assert start is not None and start >= process_start(os.getpid())  # started after this test process
        assert process_start(a.pid) == start  # stable while it runs
    finally:
        a.kill()
        a.wait()
    assert process_start(a.pid) is None
