"""Thread-count choice: environment, affinity, cgroup quota, launcher jobs."""

from __future__ import annotations

import os

import pytest
import torch

from somtorch.core import threads


@pytest.fixture
def restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_env_threads_precedence(monkeypatch, caplog):
    monkeypatch.delenv(threads.ENV_THREADS, raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert threads.env_threads() is None
    monkeypatch.setenv("OMP_NUM_THREADS", "3,1")  # one count per nesting level: the first counts
    assert threads.env_threads() == 3
    monkeypatch.setenv(threads.ENV_THREADS, "5")
    assert threads.env_threads() == 5
    monkeypatch.setenv(threads.ENV_THREADS, "zero")  # not a count: ignored (one warning), the next source counts
    with caplog.at_level("WARNING", logger="somtorch.core.threads"):
        assert threads.env_threads() == 3
        assert threads.env_threads() == 3
    assert [r.getMessage() for r in caplog.records] == [
        "SOMTORCH_THREADS='zero' is not a positive number of threads; ignored"]
    monkeypatch.setenv("OMP_NUM_THREADS", "0")
    assert threads.env_threads() is None


def test_cgroup_v2_quota(tmp_path):
    (tmp_path / "cpu.max").write_text("150000 100000\n")
    assert threads.cgroup_cpu_limit(tmp_path) == pytest.approx(1.5)
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert threads.cgroup_cpu_limit(tmp_path) is None


def test_cgroup_v1_quota(tmp_path):
    cpu = tmp_path / "cpu"
    cpu.mkdir()
    (cpu / "cpu.cfs_quota_us").write_text("50000\n")
    (cpu / "cpu.cfs_period_us").write_text("100000\n")
    assert threads.cgroup_cpu_limit(tmp_path) == pytest.approx(0.5)
    (cpu / "cpu.cfs_quota_us").write_text("-1\n")
    assert threads.cgroup_cpu_limit(tmp_path) is None


def test_available_cores_respects_affinity_and_quota(tmp_path):
    affinity = len(os.sched_getaffinity(0))
    assert threads.available_cores(tmp_path) == affinity  # no quota file: the affinity mask
    (tmp_path / "cpu.max").write_text("50000 100000\n")
    assert threads.available_cores(tmp_path) == 1  # half a core still runs one thread
    (tmp_path / "cpu.max").write_text(f"{100000 * (affinity + 4)} 100000\n")
    assert threads.available_cores(tmp_path) == affinity  # a quota above the mask does not add cores


def test_auto_threads_splits_between_jobs(monkeypatch):
    monkeypatch.delenv(threads.ENV_THREADS, raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    cores = threads.available_cores()
    assert threads.auto_threads(1) == cores
    assert threads.auto_threads(cores) == 1
    assert threads.auto_threads(10 * cores) == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    assert threads.auto_threads(4) == 7  # an explicit count wins over the split


def test_configure_sets_torch_threads(monkeypatch, restore_threads):
    monkeypatch.setenv(threads.ENV_THREADS, "1")
    assert threads.configure() == 1
    assert torch.get_num_threads() == 1
    assert threads.configure(threads=2) == 2
    assert torch.get_num_threads() == 2


def test_launcher_jobs_outside_hydra_and_under_torchrun(monkeypatch):
    from experiments.cli import launcher_jobs

    monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    assert launcher_jobs() == 1
    monkeypatch.setenv("LOCAL_WORLD_SIZE", "4")
    assert launcher_jobs() == 4


@pytest.mark.parametrize("mode", ["batch", "online", "minibatch"])
def test_training_gives_the_same_bits_for_any_thread_count(mode, restore_threads, monkeypatch):
    # the kernels may run fewer threads on a busy machine: that must change the speed only
    monkeypatch.delenv(threads.ENV_THREADS, raising=False)
    from somtorch import SOM

    x = torch.rand(3000, 3, generator=torch.Generator().manual_seed(0))
    out = []
    for n in (1, 2):
        torch.set_num_threads(n)
        som = SOM(6, 6, 3, ensemble=3, seed=1).fit(x, mode=mode, epochs=2, progress=False)
        out.append(som.weight.detach().clone())
    assert torch.equal(out[0], out[1])


def test_free_core_monitor_sees_a_busy_process():
    import subprocess
    import sys
    import time

    if not os.path.exists("/proc/stat"):
        pytest.skip("no /proc/stat on this platform")
    cores = threads.available_cores()
    if cores < 2:
        pytest.skip("one core: nothing to divide")
    mon = threads.FreeCoreMonitor(window_s=0.3)
    assert mon.free(cores) is None  # the first sample only starts the window
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(cores - 1)]
    try:
        time.sleep(0.6)
        mon.free(cores)  # a window that began before the hogs ran may mix idle and busy time
        time.sleep(0.6)
        busy = mon.free(cores)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    assert busy == 1, busy  # cores - 1 hogs leave one core


def _fresh_in_child(q):
    q.put((threads._monitor._last is None, threads._cores is None))


def test_a_forked_child_starts_its_own_free_core_window():
    import multiprocessing as mp

    if "fork" not in mp.get_all_start_methods():
        pytest.skip("no fork on this platform")
    threads.kernel_threads()  # the parent has sampled (or at least computed its cores)
    threads._monitor.free(threads.available_cores())
    assert threads._monitor._last is not None
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=_fresh_in_child, args=(q,))
    p.start()
    got = q.get(timeout=30)
    p.join(timeout=30)
    assert got == (True, True)
