"""Study jobs, sweeps and their aggregation: real Hydra processes, real launchers (basic, joblib,
Ray), a sweep killed half-way and resumed, and Optuna."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from experiments.aggregate import aggregate, find_metrics, fit_power
from experiments.study import SCHEMA, StudyConfig, complete_metrics, config_hash, execute

ROOT = Path(__file__).resolve().parents[2]
CONF = ROOT / "conf"
pytestmark = pytest.mark.slow

# a small sweep of 4 jobs on the embedded scene (no shared data needed); each job ~1 s
SWEEP = ["study=ci", "data=motorcycle", "ensemble=3", "execution=separate", "output.maps=false",
         "features.train_stride=10,20", "som.rows=3,4", "train.epochs=3"]


def _env() -> dict[str, str]:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("HYDRA_FULL_ERROR", None)
    return env


def _study(out: Path, *overrides: str, multirun: bool = True, timeout: int = 300) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "experiments.study", *(["-m"] if multirun else []), f"paths.output_dir={out}",
           *overrides]
    proc = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def _compose(overrides: list[str]) -> StudyConfig:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="study", overrides=overrides)
    return cfg


def _runs_without_time(m: dict) -> dict:
    return {k: v for k, v in m["runs"].items() if k != "runtime_s"}


def _job_runs(sweep_dir: Path) -> dict[str, dict]:
    return {str(p.relative_to(sweep_dir)): _runs_without_time(m) for p, m in find_metrics([sweep_dir])}


# ----------------------------------------------------------------------------------- one job


def test_one_job_on_a_shared_scene_writes_complete_metrics(tmp_path, shared_data):
    proc = _study(tmp_path, "data=kitti2015", "ensemble=3", f"paths.data_dir={shared_data}", multirun=False)
    (job,) = [p.parent for p in tmp_path.rglob("metrics.json")]
    m = json.loads((job / "metrics.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON {c}"))
    assert m["schema"] == SCHEMA and m["study"] == "adhoc" and m["method"] == "som"
    assert m["runs"]["seed"] == [0, 1, 2]
    s = m["summary"]
    assert s["runs"] == 3
    assert s["identified_95"] == sum(m["runs"]["identified_95"])
    assert s["useful_hits"] == sum(m["runs"]["useful_hit"])
    assert 0 < s["x_opt"] < 100 and 0.0 <= s["tradeoff"] <= 1.0
    assert set(m["per_object"]) and all(0 <= o["identified_95"] <= 3 for o in m["per_object"].values())
    assert list((job / "tb").glob("events.out.tfevents*")), "no TensorBoard events"
    assert (job / "areas.png").is_file()
    assert not list(job.glob(".partial-*")), "staging folder left behind"
    assert "kitti2015" in proc.stderr + proc.stdout


def test_ensemble_and_separate_executions_give_identical_runs(tmp_path, shared_data):
    base = ["data=kitti2015", "ensemble=3", f"paths.data_dir={shared_data}", "output.maps=false",
            "output.tensorboard=false", "som=grid4x7"]
    ms = {}
    for ex in ("ensemble", "separate"):
        dcfg = _compose([*base, f"execution={ex}"])
        ms[ex] = execute(OmegaConf.to_object(dcfg), tmp_path / ex, OmegaConf.to_container(dcfg, resolve=True))
    assert _runs_without_time(ms["ensemble"]) == _runs_without_time(ms["separate"])
    assert ms["ensemble"]["config_hash"] != ms["separate"]["config_hash"]  # execution is part of the config


def test_a_complete_job_is_skipped_and_a_changed_config_recomputed(tmp_path):
    over = ["data=motorcycle", "ensemble=2", "output.maps=false", "output.tensorboard=false", "train.epochs=2"]
    dcfg = _compose(over)
    conf = OmegaConf.to_container(dcfg, resolve=True)
    first = execute(OmegaConf.to_object(dcfg), tmp_path, conf)
    stamp = (tmp_path / "metrics.json").stat().st_mtime_ns
    again = execute(OmegaConf.to_object(dcfg), tmp_path, conf)
    assert again == json.loads((tmp_path / "metrics.json").read_text())
    assert (tmp_path / "metrics.json").stat().st_mtime_ns == stamp, "a complete job was recomputed"
    assert again["config_hash"] == first["config_hash"]
    # a different seed is a different config: recomputed in place
    dcfg2 = _compose([*over, "seed=5"])
    other = execute(OmegaConf.to_object(dcfg2), tmp_path, OmegaConf.to_container(dcfg2, resolve=True))
    assert other["config_hash"] != first["config_hash"] and other["runs"]["seed"] == [5, 6]
    assert complete_metrics(tmp_path, first["config_hash"]) is None
    assert complete_metrics(tmp_path, other["config_hash"]) is not None


def test_a_truncated_metrics_file_is_not_complete(tmp_path):
    (tmp_path / "metrics.json").write_text('{"schema": "somtorch.study/1", "config_ha')
    assert complete_metrics(tmp_path, "x") is None


def test_config_hash_ignores_where_files_go():
    a = {"seed": 0, "paths": {"output_dir": "a"}, "study": "x"}
    b = {"seed": 0, "paths": {"output_dir": "b"}, "study": "y"}
    assert config_hash(a) == config_hash(b) != config_hash({**a, "seed": 1})


@pytest.mark.parametrize("override, message", [
    ("execution=bogus", "execution"), ("repeats=0", "repeats"), ("resize=[10]", "resize"),
    ("method=bogus", "method"), ("baseline.kmeans_init=bogus", "kmeans_init"),
    ("task_baseline=bogus", "task_baseline.*plane_components"),
])
def test_bad_study_configs_fail_before_any_work(override, message):
    with pytest.raises(Exception, match=message):
        OmegaConf.to_object(_compose([override]))


# ---------------------------------------------------------------------- sweeps and launchers


@pytest.fixture(scope="module")
def basic_sweep(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("basic")
    proc = _study(out, *SWEEP, "hydra/launcher=basic")  # the reference: one job after another, in process
    (out / "stderr.txt").write_text(proc.stderr)
    return out / "studies" / "ci"


def test_a_sweep_says_its_job_count_and_time_first(basic_sweep):
    err = (basic_sweep.parents[1] / "stderr.txt").read_text().splitlines()
    first = err[0]
    assert first.startswith("study ci: 4 jobs, estimated ~") and "from the sizes of 4 job(s)" in first, err[:3]
    assert "largest peak memory ~" in first
    assert not any("Traceback" in line for line in err)


def test_basic_sweep_writes_one_folder_per_job_and_aggregates(basic_sweep, tmp_path):
    jobs = find_metrics([basic_sweep])
    assert len(jobs) == 4
    names = sorted(p.name for p, _ in jobs)
    assert names[0] == "data=motorcycle,ensemble=3,execution=separate,features.train_stride=10,output.maps=False," \
                       "som.rows=3,train.epochs=3"
    written = aggregate([basic_sweep], tmp_path)
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert len(rows) == 4 and {r["grid"] for r in rows} == {"3x8", "4x8"}
    assert "table1.md" not in written  # the embedded scene has no object mask: nothing to score
    timing = list(csv.DictReader((tmp_path / "timings.csv").open()))
    assert all(float(t["wall_s_median"]) > 0 for t in timing)


@pytest.mark.parametrize("launcher", ["somtorch", "joblib", "ray"])
def test_launchers_give_identical_results(launcher, basic_sweep, tmp_path):
    extra = {"somtorch": ["hydra.launcher.n_jobs=2"],  # the default launcher, two workers whatever the load
             "joblib": ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"],
             "ray": ["hydra/launcher=ray", "+hydra.launcher.ray.init.num_cpus=2",
                     "+hydra.launcher.ray.init.include_dashboard=false"]}[launcher]
    proc = _study(tmp_path, *SWEEP, *extra, timeout=600)
    ran = {"somtorch": "Launching 4 jobs locally, 2 side by side", "joblib": "Joblib", "ray": "Ray"}[launcher]
    assert ran in proc.stdout + proc.stderr  # the launcher really ran
    other = tmp_path / "studies" / "ci"
    assert _job_runs(other) == _job_runs(basic_sweep)
    aggregate([basic_sweep], tmp_path / "a")
    aggregate([other], tmp_path / "b")
    assert (tmp_path / "a" / "results.csv").read_text() == (tmp_path / "b" / "results.csv").read_text()
    if launcher in ("somtorch", "joblib"):  # two jobs side by side: each takes its share of the cores
        from somtorch.core.threads import auto_threads

        threads = {json.loads(m.read_text())["env"]["threads"] for m in _committed(other)}
        assert threads == {auto_threads(jobs=2)}, threads
        side = {json.loads(m.read_text())["env"]["jobs_side_by_side"] for m in _committed(other)}
        assert side == {2}, side


def _committed(sweep: Path) -> list[Path]:
    return [p for p in sweep.rglob("metrics.json") if not any(part.startswith(".partial-") for part in p.parts)]


def test_a_killed_sweep_resumes_and_loses_nothing(basic_sweep, tmp_path):
    cmd = [sys.executable, "-m", "experiments.study", "-m", f"paths.output_dir={tmp_path}", *SWEEP]
    sweep = tmp_path / "studies" / "ci"
    proc = subprocess.Popen(cmd, cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while not _committed(sweep):
            assert proc.poll() is None, "the sweep ended before it could be killed"
            assert time.monotonic() < deadline, "no job finished in time"
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    done = {p: p.read_bytes() for p in _committed(sweep)}  # a staging folder's file is not a result
    assert 1 <= len(done) < 4, f"{len(done)} jobs complete when killed"
    for p in done:  # every metrics.json present is complete JSON
        assert json.loads(p.read_text())["schema"] == SCHEMA
    rerun = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert (rerun.stdout + rerun.stderr).count("skipping") == len(done)
    for p, content in done.items():
        assert p.read_bytes() == content, f"{p} was recomputed"
    assert _job_runs(sweep) == _job_runs(basic_sweep)  # nothing lost, nothing changed
    assert not list(sweep.rglob(".partial-*"))


# --------------------------------------------------------------------------- Table 1 / Optuna


def test_table1_sweep_aggregates_into_the_paper_s_tables(tmp_path, shared_data):
    _study(tmp_path, "+experiment=table1", "data=kitti2015", "features.train_stride=10", "ensemble=2",
           "train.epochs=3", "output.maps=false", f"paths.data_dir={shared_data}", "hydra.launcher.n_jobs=2")
    sweep = tmp_path / "studies" / "table1"
    jobs = find_metrics([sweep])
    assert sorted(m["label"] for _, m in jobs) == ["paper", "robust"]
    aggregate([sweep], tmp_path / "agg")
    t1 = list(csv.DictReader((tmp_path / "agg" / "table1.csv").open()))
    by_label = {m["label"]: m for _, m in jobs}
    for row in t1:
        s = by_label[row["config"]]["summary"]
        assert (int(row["identified_100"]), int(row["identified_95"]), int(row["useful_hits"])) == (
            s["identified_100"], s["identified_95"], s["useful_hits"])
    md = (tmp_path / "agg" / "table2.md").read_text()
    assert "NOR stair | 12.56 | 79.13" in md and "kitti2015" in md
    # the two jobs ran side by side: the runtimes say so
    assert "ms per run: measured with up to 2 jobs side by side" in (tmp_path / "agg" / "table1.md").read_text()
    assert "kitti2015" in (tmp_path / "agg" / "per_object.md").read_text()
    import matplotlib.image as mpimg

    for name in ("table1.png", "table2.png"):  # the plots the README promises
        img = mpimg.imread(tmp_path / "agg" / name)
        assert img.shape[0] > 200 and img.shape[1] > 400 and img[..., :3].std() > 0.05  # not blank


def test_task_baselines_get_their_rows_in_tables_1_and_2(tmp_path, shared_data):
    from experiments.real_scenes import run_baseline
    from somtorch.config import ReductionConfig
    from somtorch.disparity import load_scene

    _study(tmp_path, "+experiment=table1_baselines", "data=kitti2015", f"paths.data_dir={shared_data}")
    sweep = tmp_path / "studies" / "table1"
    jobs = find_metrics([sweep])
    assert sorted(m["method"] for _, m in jobs) == ["plane_components", "uv_disparity"]
    scene = load_scene(shared_data / "kitti2015" / "devkit_demo")
    for _, m in jobs:  # one run, scored exactly as real_scenes scores the baseline
        assert m["summary"]["runs"] == 1 and m["mode"] == "all px"
        (direct,) = run_baseline(m["method"], scene, ReductionConfig())
        assert m["summary"]["useful_hits"] == int(direct.score.useful_hit)
        assert m["runs"]["reduction_union"] == [pytest.approx(direct.reduction.reduction_union)]
    aggregate([sweep], tmp_path / "agg")
    t1 = (tmp_path / "agg" / "table1.md").read_text()
    assert "| all px | kitti2015 | plane_components | – | 1 |" in t1 and "NOR stair | 91 | 91" in t1
    assert "| all px | kitti2015 | uv_disparity |" in (tmp_path / "agg" / "table2.md").read_text()


def test_a_trained_baselines_job_hash_names_its_model():
    from experiments.metrics_schema import config_hash
    from experiments.study import StudyConfig, job_hash
    from somtorch.baselines.learned.store import model_key
    from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig
    from somtorch.tasks.baselines import get_task_baseline

    from experiments.study import code_digest

    config = {"data": {"name": "kitti2015"}, "task_baseline": "learned"}
    key = model_key(LearnedModelConfig(), LearnedDataConfig(), LearnedFitConfig())
    assert get_task_baseline("learned").identity() == key
    learned = job_hash(StudyConfig(task_baseline="learned"), config)
    code = code_digest()
    assert learned == config_hash({**config, "code": code, "task_baseline_model": key}) != config_hash(config)
    # another model (another training config) is another job: a study runs it again, not skips it
    other = model_key(LearnedModelConfig(), LearnedDataConfig(frames=3), LearnedFitConfig())
    assert config_hash({**config, "code": code, "task_baseline_model": other}) != learned
    # a baseline that is its code: the config and the code
    plain = {**config, "task_baseline": "plane_components"}
    assert job_hash(StudyConfig(task_baseline="plane_components"), plain) == config_hash({**plain, "code": code})
    assert job_hash(StudyConfig(), config) == config_hash({**config, "code": code})


def test_a_jobs_hash_changes_with_the_library_code(tmp_path):
    """The same config under other code is another job (a study re-runs it rather than keep results
    of the code before): the digest reads every source file's path and bytes, nothing else."""
    import somtorch
    from experiments.study import code_digest, source_digest

    pkg = tmp_path / "pkg"
    (pkg / "core" / "csrc").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "core" / "csrc" / "op.cpp").write_text("int f() { return 1; }\n")
    (pkg / "notes.md").write_text("not code\n")
    first = source_digest(pkg)
    assert len(first) == 16 and source_digest(pkg) == first
    (pkg / "notes.md").write_text("still not code\n")
    assert source_digest(pkg) == first
    (pkg / "a.py").write_text("x = 2\n")
    second = source_digest(pkg)
    assert second != first
    (pkg / "core" / "csrc" / "op.cpp").write_text("int f() { return 2; }\n")
    third = source_digest(pkg)
    assert third not in (first, second)
    (pkg / "a.py").rename(pkg / "b.py")  # a file moved is other code too
    assert source_digest(pkg) != third
    assert code_digest() == source_digest(Path(somtorch.__file__).parent)


def test_optuna_sweeper_searches_and_reports_the_best_trade_off(tmp_path, shared_data):
    _study(tmp_path, "+experiment=optuna", "data=kitti2015", "ensemble=2", "train.epochs=3",
           "hydra.sweeper.n_trials=3", f"paths.data_dir={shared_data}")
    result = OmegaConf.load(tmp_path / "studies" / "optuna" / "optimization_results.yaml")
    assert 0.0 <= float(result.best_value) <= 1.0
    assert {"train.lr", "train.sigma", "som.rows", "reduction.tolerance_image"} <= set(result.best_params)
    values = [m["summary"]["tradeoff"] for _, m in find_metrics([tmp_path / "studies" / "optuna"])]
    assert len(values) == 3 and max(values) == pytest.approx(float(result.best_value))


# ------------------------------------------------------------------------------ aggregation


def test_fit_power_recovers_a_known_exponent():
    px = [1e4, 3e4, 1e5, 3e5, 1e6]
    b, c = fit_power(px, [2e-6 * n ** 0.8 for n in px])
    assert b == pytest.approx(0.8, abs=1e-9) and c == pytest.approx(2e-6, rel=1e-6)


def test_aggregate_without_metrics_is_a_clear_error(tmp_path):
    from experiments.aggregate import main

    assert main([str(tmp_path)]) == 2
    with pytest.raises(FileNotFoundError, match="no such folder"):
        aggregate([tmp_path / "missing"], tmp_path)


@pytest.mark.parametrize("argv0, usage", [("/u/.venv/bin/somtorch-aggregate", "usage: somtorch-aggregate "),
                                           ("/repo/experiments/aggregate.py", "usage: python -m experiments.aggregate ")])
def test_aggregate_usage_names_the_command_typed(argv0, usage, monkeypatch, capsys):
    from experiments.aggregate import main

    monkeypatch.setattr(sys, "argv", [argv0])
    with pytest.raises(SystemExit):
        main([])
    assert capsys.readouterr().err.startswith(usage)


def test_a_terminated_job_leaves_no_staging_folder_and_reruns(tmp_path):
    cmd = [sys.executable, "-m", "experiments.study", f"paths.output_dir={tmp_path}", "study=term", "data=motorcycle",
           "ensemble=40", "execution=separate", "output.maps=false", "output.tensorboard=false"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not list(tmp_path.rglob(".partial-*")):  # the job is working
        assert proc.poll() is None and time.monotonic() < deadline, "the job never started"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 128 + signal.SIGTERM
    assert not list(tmp_path.rglob(".partial-*")), "staging folder left behind"
    assert not list(tmp_path.rglob("metrics.json"))


def test_table_plots_stay_readable_for_the_whole_table1_sweep(tmp_path):
    """8 scenes x {OR, NOR} x {paper, robust} (the paper-preset sweep): one panel per scene, at most
    ~1800 px wide (a single strip of 36 bar groups was 4752 x 462 px)."""
    from PIL import Image

    from experiments.aggregate import PAPER_TABLE1, PAPER_TABLE2
    from experiments.study_sections import tables_plot

    rows = [{"scene": f"scene_{i}", "mode": mode, "config": cfg, "runs": 100, "identified_100": 40,
             "identified_95": 90, "useful_hits": 70, "x_min": 10.0, "x_mean": 20.0, "x_max": 30.0, "x_opt": 35.0}
            for i in range(8) for mode in ("OR", "NOR") for cfg in ("paper", "robust")]
    assert tables_plot(rows, tmp_path, PAPER_TABLE1, PAPER_TABLE2) == ["table1.png", "table2.png"]
    for name in ("table1.png", "table2.png"):
        with Image.open(tmp_path / name) as im:
            w, h = im.size
        assert w <= 1800 and 600 <= h <= 1400, (name, w, h)
