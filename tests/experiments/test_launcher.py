"""hydra/launcher=somtorch: how many jobs side by side, in which order, and what a sweep does when a
job fails, a worker dies or the user presses Ctrl-C (real sweeps, real worker processes)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hydra_plugins.somtorch_launcher.launcher import choose_workers, makespan

from .test_interrupt import _wait_for

ROOT = Path(__file__).resolve().parents[2]
GIB = 1 << 30
# two jobs of ~100 s of batch-map epochs each on the embedded scene: long enough to be stopped
LONG = ["ensemble=20", "train.epochs=100000", "output.tensorboard=false", "output.maps=false", "seed=0,1",
        "hydra.launcher.n_jobs=2"]
SMALL = ["ensemble=2", "output.maps=false", "output.tensorboard=false"]  # a job of a second or two


def test_makespan_hands_the_longest_job_out_first():
    assert makespan([5, 4, 3, 3, 3], 2) == 10  # 5 | 4 → 5 | 4+3 → 5+3 | 7 → 8 | 7+3
    assert makespan([10, 1, 1, 1], 2) == 10
    assert makespan([3, 3, 3, 3], 4) == 3 and makespan([3, 3, 3, 3], 1) == 12


@pytest.mark.parametrize("kw, want", [
    (dict(n_jobs=None, jobs=32, free=2, peak_bytes=GIB, memory_bytes=20 * GIB, alone=False), 2),   # the free cores
    (dict(n_jobs=None, jobs=32, free=1, peak_bytes=GIB, memory_bytes=20 * GIB, alone=False), 1),   # one core busy
    (dict(n_jobs=None, jobs=3, free=16, peak_bytes=GIB, memory_bytes=20 * GIB, alone=False), 3),   # no more than jobs
    (dict(n_jobs=None, jobs=32, free=16, peak_bytes=4 * GIB, memory_bytes=10 * GIB, alone=False), 2),  # memory
    (dict(n_jobs=None, jobs=32, free=16, peak_bytes=None, memory_bytes=None, alone=False), 16),    # no estimate
    (dict(n_jobs=None, jobs=32, free=16, peak_bytes=GIB, memory_bytes=20 * GIB, alone=True), 1),  # one GPU, or timed
    (dict(n_jobs=4, jobs=32, free=1, peak_bytes=GIB, memory_bytes=GIB, alone=False), 4),           # as asked
    (dict(n_jobs=-1, jobs=32, free=1, peak_bytes=None, memory_bytes=None, alone=False), 16),       # joblib's -1
    (dict(n_jobs=-2, jobs=32, free=1, peak_bytes=None, memory_bytes=None, alone=False), 15),
    (dict(n_jobs=None, jobs=1, free=16, peak_bytes=None, memory_bytes=None, alone=False), 1),
])
def test_choose_workers(kw, want):
    assert choose_workers(cores=16, **kw) == want


def _sweep(tmp_path: Path, *overrides: str, **kw) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "experiments.study", "-m", f"paths.output_dir={tmp_path}", "study=l", *overrides]
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kw)


def _finished(tmp_path: Path, *overrides: str) -> tuple[int, str]:
    """Run a sweep to its end: (exit status, stderr)."""
    p = _sweep(tmp_path, *overrides)
    _, err = p.communicate(timeout=300)
    return p.returncode, err


def _workers(pid: int) -> list[int]:
    """The spawned worker processes of ``pid`` (not multiprocessing's resource tracker)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmd = (d / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmd:
            out.append(int(d.name))
    return out


def _group_gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


def _jobs(tmp_path: Path) -> list[Path]:
    return sorted(p for p in (tmp_path / "studies" / "l").iterdir() if p.is_dir())


def _job(tmp_path: Path, last: str) -> Path:
    """The folder of the job whose override list ends with ``last`` (the folder may not exist yet)."""
    found = [p for p in _jobs(tmp_path) if p.name.endswith("," + last)] if (tmp_path / "studies" / "l").is_dir() else []
    return found[0] if found else tmp_path / "studies" / "l" / "missing"


@pytest.mark.slow
@pytest.mark.parametrize("sig, code, group", [(signal.SIGINT, 130, True), (signal.SIGINT, 130, False),
                                               (signal.SIGTERM, 143, False)])
def test_a_signal_stops_every_worker_and_marks_their_folders(tmp_path, sig, code, group):
    p = _sweep(tmp_path, *LONG)
    try:
        started = lambda: (tmp_path / "studies" / "l").is_dir() and len(  # noqa: E731
            [j for j in _jobs(tmp_path) if any(j.glob(".partial-*"))]) == 2
        assert _wait_for(started, 180), "the two jobs never started side by side"
        time.sleep(4)  # into the training epochs
        assert len(_workers(p.pid)) == 2
        if group:  # Ctrl-C in a terminal: the whole process group
            os.killpg(p.pid, sig)
        else:  # kill [-INT] <pid>: the launcher alone, which stops its workers
            p.send_signal(sig)
        _, err = p.communicate(timeout=90)
    finally:
        if not _group_gone(p.pid):
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == code, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    name = signal.Signals(sig).name
    assert err.strip().splitlines()[-1] == f"interrupted ({name}) with 0 of 2 jobs done", err
    for job in _jobs(tmp_path):
        assert (job / "FAILED").read_text().startswith("interrupted ("), job
        assert not (job / "metrics.json").exists() and not list(job.glob(".partial-*"))
    assert _wait_for(lambda: _group_gone(p.pid), 10), "a worker outlived the sweep"


def test_a_signal_while_a_worker_sends_its_result_ends_the_worker_quietly():
    # CI once printed a worker's traceback: SIGTERM landed inside the write of a "done" message the
    # launcher was not reading (it was stopping). A blocked send, interrupted, must return False.
    import multiprocessing
    import threading

    from hydra_plugins.somtorch_launcher._workers import _send
    from somtorch import interrupt

    parent, child = multiprocessing.Pipe()
    old = signal.getsignal(signal.SIGTERM)
    interrupt.reset()
    try:
        assert interrupt.install((signal.SIGTERM,))
        timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGTERM))
        timer.start()
        t0 = time.monotonic()
        assert _send(child, ("done", b"x" * (64 << 20))) is False  # far more than a pipe holds: blocks
        assert time.monotonic() - t0 < 30 and interrupt.requested() == signal.SIGTERM
        timer.join()
    finally:
        signal.signal(signal.SIGTERM, old)
        interrupt.reset()
        parent.close()
        child.close()
    a, b = multiprocessing.Pipe()
    assert _send(a, ("done", 1)) is True and b.recv() == ("done", 1)
    b.close()
    assert _send(a, ("done", 2)) is False  # the launcher's end closed: no exception either
    a.close()


@pytest.mark.slow
def test_a_bad_config_refuses_the_whole_sweep_before_any_job_runs(tmp_path):
    # train.epochs=0 fails the job's config rules: one line naming the job, status 2, nothing run
    code, err = _finished(tmp_path, *SMALL, "train.epochs=3,0", "hydra.launcher.n_jobs=2")
    assert code == 2, err
    assert "Traceback" not in err
    assert [line for line in err.splitlines() if line.startswith("error: ")] == [err.strip().splitlines()[-1]], err
    assert "train.epochs=0" in err and "train.epochs must be" in err and "no job of the sweep was run" in err, err
    assert not (tmp_path / "studies" / "l").exists() or not any(p.is_dir() for p in (tmp_path / "studies" / "l").iterdir())


@pytest.mark.slow
def test_a_job_failing_at_run_time_ends_the_sweep_with_its_status_after_the_good_one(tmp_path):
    # a scene that does not exist passes the config check and fails in its job: one line, status 2
    code, err = _finished(tmp_path, *SMALL, "data=file", "data.source=motorcycle,missing_scene.pfm",
                          "hydra.launcher.n_jobs=2")
    assert code == 2, err
    assert "Traceback" not in err
    assert sum(line.startswith("error: ") for line in err.splitlines()) == 1, err
    good, bad = sorted(_jobs(tmp_path), key=lambda j: not j.name.startswith("data.source=motorcycle"))
    assert json.loads((good / "metrics.json").read_text())["runs"]["seed"] == [0, 1]
    assert (bad / "FAILED").exists() and not (bad / "metrics.json").exists()


@pytest.mark.slow
def test_a_dead_worker_fails_its_job_and_a_new_worker_takes_the_next(tmp_path):
    # two long jobs start first (longest first); one worker is killed: its job fails, a new worker
    # runs the short job; then the sweep is stopped (the other long job would take minutes)
    p = _sweep(tmp_path, "ensemble=20", *SMALL[1:], "train.epochs=100000,99999,2", "hydra.launcher.n_jobs=2")
    sweep = tmp_path / "studies" / "l"
    try:
        started = lambda: sweep.is_dir() and len([j for j in _jobs(tmp_path) if any(j.glob(".partial-*"))]) == 2  # noqa: E731
        assert _wait_for(started, 180), "the two long jobs never started side by side"
        assert not _job(tmp_path, "train.epochs=2").exists()  # the short job waits for a free worker
        time.sleep(2)
        os.kill(_workers(p.pid)[0], signal.SIGKILL)
        assert _wait_for(lambda: (_job(tmp_path, "train.epochs=2") / "metrics.json").exists(), 180), \
            "no new worker ran the short job"
        assert len(_workers(p.pid)) == 2
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=90)
    finally:
        if not _group_gone(p.pid):
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 143, err
    assert "died (signal SIGKILL; out of memory?)" in err, err
    last = err.strip().splitlines()[-1]  # 1 of 3 when the short job's result was still on its way
    assert last in ("interrupted (SIGTERM) with 2 of 3 jobs done", "interrupted (SIGTERM) with 1 of 3 jobs done"), err
    assert "Traceback" not in err, err
    for n in (100000, 99999):
        assert not (_job(tmp_path, f"train.epochs={n}") / "metrics.json").exists()
    assert _wait_for(lambda: _group_gone(p.pid), 10), "a worker outlived the sweep"


@pytest.mark.slow
def test_a_timing_sweep_runs_its_jobs_one_at_a_time(tmp_path):
    # repeats > 1 (the runtime study): each job is timed alone, whatever cores are free
    code, err = _finished(tmp_path, *SMALL, "repeats=2", "train.epochs=2,3")
    assert code == 0, err
    assert err.splitlines()[0].endswith("; one after another"), err
    for job in _jobs(tmp_path):
        assert json.loads((job / "metrics.json").read_text())["env"]["jobs_side_by_side"] == 1
