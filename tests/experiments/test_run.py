"""``python -m experiments.run`` end to end, as a real subprocess writing real files."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from somtorch import SOM
from somtorch.consensus import SEED_STRIDE
from somtorch.disparity.io import write_pfm
from somtorch.disparity import load_scene
from somtorch.geometry import read_ply

ROOT = Path(__file__).resolve().parents[2]
MAPS = ("disparity", "segments_grey", "segments_color", "reference_vectors", "areas", "reduced_disparity")
OURS = (".json", ".png", ".ply", ".npz", ".safetensors")  # file types a run writes besides Hydra's

pytestmark = pytest.mark.slow


def _run(run_dir: Path, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run([sys.executable, "-m", "experiments.run", f"hydra.run.dir={run_dir}",
                           "output.render_backend=matplotlib", *overrides],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _ok(proc: subprocess.CompletedProcess) -> None:
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"


def _strict_json(path: Path) -> dict:
    def reject(c):
        raise ValueError(f"{path}: non-standard JSON constant {c}")
    return json.loads(path.read_text(), parse_constant=reject)


def _our_files(run_dir: Path) -> list[str]:
    return sorted(str(p.relative_to(run_dir)) for p in run_dir.rglob("*")
                  if p.is_file() and (p.suffix in OURS or p.name.startswith("events.out.tfevents"))
                  and ".hydra" not in p.parts)


def _no_temp_files(run_dir: Path) -> None:
    assert not [p for p in run_dir.rglob(".*.tmp*")], "temporary files left behind"


# ------------------------------------------------------------------------------------ full run


@pytest.fixture(scope="module")
def embedded_run(tmp_path_factory) -> Path:
    run_dir = tmp_path_factory.mktemp("run") / "motorcycle"
    # objects=paper ("nearest") always keeps an area, so the reduced cloud is written too
    _ok(_run(run_dir, "objects=paper", "ensemble=2", "train.epochs=4"))
    return run_dir


def test_metrics_json_is_complete(embedded_run):
    m = _strict_json(embedded_run / "metrics.json")
    scene = load_scene("motorcycle")
    assert m["scene"]["name"] == "motorcycle" and m["scene"]["valid_pixels"] == scene.n_valid
    assert {"load", "features", "train", "segment", "objects", "reduction", "errors"} <= set(m["timings_s"])
    assert all(v >= 0 for v in m["timings_s"].values())
    # compute (the pipeline's stages) apart from writing the outputs; the parts add up to the total
    assert {"maps", "point_clouds", "checkpoint", "tensorboard"} <= set(m["output_timings_s"])
    w = m["wall_s"]
    assert w["compute"] == pytest.approx(sum(m["timings_s"].values()))
    assert w["output"] == pytest.approx(sum(m["output_timings_s"].values()))
    assert w["compute"] + w["output"] + w["other"] == pytest.approx(w["total"])
    assert w["other"] < 0.2 * w["total"] + 0.5  # nothing big left unaccounted
    # the stride is counted on 640x480: configured 10, 11 on the 741x500 Motorcycle, and the reason
    assert m["pixels"]["train_stride"] == 10 and m["pixels"]["train_stride_effective"] == 11
    assert "features.reference_pixels=307200" in m["pixels"]["train_stride_reason"]
    assert len(m["members"]) == 2 and [mem["seed"] for mem in m["members"]] == [0, 1]
    assert all(len(mem["kept_areas"]) == 1 for mem in m["members"])
    assert m["config"]["ensemble"] == 2 and m["config"]["objects"]["rule"] == "paper"
    pc = m["pointcloud"]
    assert pc["written"] is True and pc["points_full"] == scene.n_valid
    with np.load(embedded_run / "reduced.npz") as z:
        assert pc["points_reduced"] == int(z["valid"].sum()) > 0
    _no_temp_files(embedded_run)


def test_pictures_and_point_clouds_are_readable(embedded_run):
    scene = load_scene("motorcycle")
    for name in MAPS:
        img = cv2.imread(str(embedded_run / f"{name}.png"))
        assert img is not None and img.shape == (scene.height, scene.width, 3), name
    assert cv2.imread(str(embedded_run / "cloud_reduced.png")) is not None
    m = _strict_json(embedded_run / "metrics.json")
    assert len(read_ply(embedded_run / "cloud_full.ply")) == m["pointcloud"]["points_full"]
    assert len(read_ply(embedded_run / "cloud_reduced.ply")) == m["pointcloud"]["points_reduced"]


def test_checkpoint_loads_as_the_trained_som(embedded_run):
    som = SOM.load(embedded_run / "som.safetensors")
    grid = _strict_json(embedded_run / "metrics.json")["config"]["som"]
    assert (som.rows, som.cols, som.dim, som.ensemble) == (grid["rows"], grid["cols"], 3, 2)
    members = _strict_json(embedded_run / "metrics.json")["members"]
    assert [m["seed"] for m in members] == [0, 1]  # the runs' seeds; the checkpoint holds the kept maps
    assert som.seeds == [m["map_seed"] for m in members]
    assert som.seeds == [(s + m["consensus_map"] * SEED_STRIDE) % 2 ** 32 for s, m in zip((0, 1), members)]
    assert som.weight.shape == (2, grid["rows"] * grid["cols"], 3)
    assert bool(som.weight.isfinite().all())


def test_tensorboard_events_hold_the_training_curve(embedded_run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(embedded_run / "tb"))
    acc.Reload()
    scalars = acc.Tags()["scalars"]
    assert {"train/quantization_error", "train/topographic_error"} <= set(scalars)
    qe = acc.Scalars("train/quantization_error")
    assert len(qe) == 4  # one per epoch
    assert all(np.isfinite(e.value) and e.value >= 0 for e in qe)
    assert {"maps/disparity", "maps/areas"} <= set(acc.Tags()["images"])


def test_a_shared_scene_with_a_mask_gets_a_summary(tmp_path, shared_data):
    run_dir = tmp_path / "terrace"
    _ok(_run(run_dir, "data=eth3d_terrace", f"paths.data_dir={shared_data}", "ensemble=3",
             "output.pointcloud=false", "output.tensorboard=false"))
    m = _strict_json(run_dir / "metrics.json")
    s = m["summary"]
    assert s["runs"] == 3
    scores = [mem["score"] for mem in m["members"]]
    assert s["identified_100"] == sum(sc["identified_100"] for sc in scores)
    assert s["identified_95"] == sum(sc["identified_95"] for sc in scores)
    assert 0 <= s["identified_100"] <= s["identified_95"] <= 3
    assert s["x_opt"] == pytest.approx(94.3, abs=0.05)
    assert "pointcloud" not in m and not (run_dir / "tb").exists() and not list(run_dir.glob("*.ply"))


# ------------------------------------------------------------------- bad input leaves nothing of ours


def _truncated_pfm(path: Path) -> Path:
    write_pfm(path, np.ones((40, 60), np.float32))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def _all_invalid_npy(path: Path) -> Path:
    np.save(path, np.full((30, 40), np.nan, np.float32))
    return path


@pytest.mark.parametrize("make, message", [
    (lambda d: d / "missing.pfm", "missing.pfm"),
    (lambda d: _truncated_pfm(d / "short.pfm"), "short.pfm"),
    (lambda d: _all_invalid_npy(d / "empty.npy"), "empty.npy"),
], ids=["missing", "truncated_pfm", "all_invalid_npy"])
def test_bad_input_fails_and_leaves_no_output(tmp_path, make, message):
    source = make(tmp_path)
    run_dir = tmp_path / "run"
    proc = _run(run_dir, "data=file", f"data.source={source}")
    assert proc.returncode != 0
    log = (run_dir / "run.log").read_text() if (run_dir / "run.log").exists() else ""
    assert message in proc.stderr + log, proc.stderr[-2000:]
    assert _our_files(run_dir) == []
    assert not (run_dir / "tb").exists()
    assert {p.name for p in run_dir.iterdir()} <= {".hydra", "run.log", "FAILED"}
    assert "failed" in (run_dir / "FAILED").read_text()  # marked, so no one takes it for a run


def test_bad_som_value_fails_and_leaves_no_output(tmp_path):
    run_dir = tmp_path / "run"
    proc = _run(run_dir, "som.rows=0")
    assert proc.returncode != 0 and "rows" in proc.stderr
    assert _our_files(run_dir) == []


def test_console_script_composes_from_any_directory(tmp_path):
    exe = Path(sys.executable).parent / "somtorch-run"
    if not exe.exists():
        pytest.skip(f"console script not installed next to {sys.executable} (pip install -e . creates it)")
    proc = subprocess.run([str(exe), "--cfg", "job", "som.rows=3"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "rows: 3" in proc.stdout and "source: motorcycle" in proc.stdout


def test_stereo_pair_with_camera_gives_point_clouds(shared_data, tmp_path):
    toy = shared_data / "oakd_stereodemo" / "toy"
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", f"hydra.run.dir={tmp_path}", "data=stereo_pair",
         f"data.left={toy / 'left.png'}", f"data.right={toy / 'right.png'}", "data.focal_px=451.03",
         "data.baseline=0.075", "output.tensorboard=false", "train.epochs=3", "output.render_backend=auto"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    pc = m["pointcloud"]
    assert pc["written"] and pc["unit"] == "m"
    assert pc["points_full"] == m["scene"]["valid_pixels"]  # SGBM's valid pixels, one point each
    assert 0 < pc["points_reduced"] <= pc["points_full"]
    assert len(read_ply(tmp_path / "cloud_reduced.ply")) == pc["points_reduced"]
    assert m["scene"]["name"] == "toy"  # the folder holding left.png, not "stereo_pair"
    assert "vulkan" not in proc.stderr.lower()  # headless Open3D falls back to matplotlib without a line


def test_a_disparity_file_with_calib_txt_beside_it_gives_point_clouds(shared_data, tmp_path):
    """data=file: the camera comes from the calib.txt beside the PFM; --quiet still says where."""
    src = tmp_path / "terrace"
    src.mkdir()
    for name in ("disp0.pfm", "calib.txt"):
        (src / name).write_bytes((shared_data / "eth3d" / "terrace" / name).read_bytes())
    run_dir = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "--quiet", f"hydra.run.dir={run_dir}", "data=file",
                           f"data.source={src / 'disp0.pfm'}", "output.render=false", "output.maps=false",
                           "output.tensorboard=false", "train.epochs=3"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines() == [f"outputs in {run_dir}"]
    m = json.loads((run_dir / "metrics.json").read_text())
    assert m["pointcloud"]["written"] and m["pointcloud"]["points_full"] == m["scene"]["valid_pixels"]
    assert m["scene"]["source"]["camera"] == str(src / "calib.txt")
    assert (run_dir / "cloud_full.ply").exists()


def test_stereo_pair_with_half_a_camera_fails_before_output(shared_data, tmp_path):
    toy = shared_data / "oakd_stereodemo" / "toy"
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", f"hydra.run.dir={tmp_path}", "data=stereo_pair",
         f"data.left={toy / 'left.png'}", f"data.right={toy / 'right.png'}", "data.focal_px=451.03"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0 and "data.baseline" in proc.stderr
    assert not (tmp_path / "metrics.json").exists()


def test_two_runs_started_together_keep_both_results(tmp_path):
    """Issue 14 item 10: two runs into the same output root in the same second each keep their own
    folder, run.log and metrics.json."""
    import os

    cmd = [sys.executable, "-m", "experiments.run", f"paths.output_dir={tmp_path}", "output.pointcloud=false",
           "output.tensorboard=false", "output.maps=false", "output.checkpoint=false", "train.epochs=2"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen(cmd + [f"seed={s}"], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for s in (1, 2)]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-2000:]
    runs = sorted((tmp_path / "run" / "motorcycle").iterdir())
    assert len(runs) == 2
    seeds = sorted(json.loads((r / "metrics.json").read_text())["members"][0]["seed"] for r in runs)
    assert seeds == [1, 2]
    assert not [p for r in runs for p in r.iterdir() if p.name.startswith((".partial-", ".lock"))]


def test_a_folder_held_by_a_run_refuses_a_second_writer(tmp_path):
    from somtorch.locks import exclusive_folder

    with exclusive_folder(tmp_path) as lock:
        assert lock.exists()
        with pytest.raises(RuntimeError, match=f"being written by the run of PID {os.getpid()} "):
            with exclusive_folder(tmp_path):
                pass
    assert not lock.exists()


def test_a_run_killed_with_sigterm_leaves_no_staging_folder(tmp_path):
    """Issue 14 item 11: SIGTERM removes the staging folder (and the lock) of the main job."""
    import os
    import signal
    import time

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-m", "experiments.run", f"hydra.run.dir={tmp_path}", "ensemble=30"],
                         cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.time()
    while not list(tmp_path.glob(".partial-*")) and time.time() - t0 < 120 and p.poll() is None:
        time.sleep(0.05)
    assert p.poll() is None, "the run ended before it could be killed"
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 128 + signal.SIGTERM, err[-3000:]  # (a failure shows where the signal landed)
    assert not list(tmp_path.glob(".partial-*")) and not (tmp_path / ".lock").exists()
    assert not (tmp_path / "metrics.json").exists()


@pytest.mark.parametrize("override, words", [
    ("som.rows=0", ["som.rows", "[1, inf)"]),
    ("objects.rule=bogus", ["objects.rule", "salient"]),
    ("output.member=5", ["output.member"]),
])
def test_bad_input_ends_in_one_line_on_stderr_and_exit_status_2(tmp_path, override, words):
    proc = _run(tmp_path, override)
    assert proc.returncode == 2, proc.stderr[-500:]
    err = proc.stderr.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and err.startswith("error: ")
    for w in words:
        assert w in err


@pytest.mark.parametrize("value, hint", [(0.0, "all-zero map"), (7.0, "constant map")])
def test_a_constant_map_is_refused_before_work(tmp_path, value, hint):
    np.save(tmp_path / "flat.npy", np.full((40, 50), value, np.float32))
    proc = _run(tmp_path / "run", "data=file", f"data.source={tmp_path / 'flat.npy'}")
    assert proc.returncode == 2 and hint in proc.stderr and "flat" in proc.stderr
    assert (tmp_path / "run" / "FAILED").exists() and not (tmp_path / "run" / "metrics.json").exists()


def test_a_file_input_names_its_folder_and_scene(tmp_path):
    rng = np.random.default_rng(0)
    d = (5 + rng.random((60, 80))).astype(np.float32)
    d[20:40, 20:50] = 30.0
    np.save(tmp_path / "my_scan_07.npy", d)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "data=file", f"data.source={tmp_path / 'my_scan_07.npy'}",
                           f"paths.output_dir={tmp_path / 'out'}", "output.pointcloud=false"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    _ok(proc)
    runs = list((tmp_path / "out" / "run" / "my_scan_07").glob("*/metrics.json"))
    assert len(runs) == 1
    m = json.loads(runs[0].read_text())
    assert m["scene"]["name"] == "my_scan_07"
    assert m["scene"]["invalid_pixels"] == 0 and "removed_pixels" not in m["scene"]
    assert all(isinstance(x["kept_everything"], bool) for x in m["members"])
    for x in m["members"]:  # what became of each candidate: a kept one where the member kept an area
        assert all(c["verdict"] and len(c["box_xyxy"]) == 4 for c in x["candidates"])
        assert x["no_object"] or any(c["verdict"].startswith("kept") for c in x["candidates"])
        assert all(n > 0 for n in x["areas_not_ranked"].values())
    assert m["object_step"]["mode"] in ("support", "contrast") and m["object_step"]["reason"]
    assert ("ground_plane" in m) == ("no ground plane" not in m["object_step"]["reason"])


def test_quiet_prints_only_where_the_results_are_and_keeps_the_log(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "--quiet", f"hydra.run.dir={tmp_path / 'run'}",
                           "output.pointcloud=false", "output.maps=false"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout == f"outputs in {tmp_path / 'run'}\n" and proc.stderr == ""
    assert "outputs in" in (tmp_path / "run" / "run.log").read_text()


def test_a_labelled_frame_whose_object_has_no_valid_pixel_is_reduced_unscored(tmp_path):
    """A generated frame whose main object has no valid disparity (a matcher leaves a textureless
    object without any): the run reduces it, says in one warning why it is not scored, and writes
    metrics.json without a score; the library refuses it before any work."""
    from dataclasses import replace as dc_replace

    from somtorch.disparity import load_scene
    from somtorch.pipeline import PipelineConfig, run_pipeline
    from somtorch.synth.frame import generate_frame
    from somtorch.synth.store import write_frame

    frame = generate_frame("floor", 0, "oakd", sgbm=False)
    gap = frame.disparity.clone()
    gap[frame.objects == 1] = float("inf")
    folder = write_frame(dc_replace(frame, disparity=gap), tmp_path / "gap")
    p = _run(tmp_path / "run", "data=file", f"data.source={folder}", "ensemble=2")
    _ok(p)
    assert "scene 'gap': the main object has no pixel with a valid disparity, so no run of it can be scored; " \
        "the runs are not scored" in p.stderr + p.stdout
    metrics = _strict_json(tmp_path / "run" / "metrics.json")
    assert all(m["score"] is None for m in metrics["members"]) and "summary" not in metrics
    assert metrics["members"][0]["reduction_union"] > 0  # reduced all the same
    with pytest.raises(ValueError, match="scene 'gap': the main object has no pixel with a valid disparity"):
        run_pipeline(load_scene(folder), PipelineConfig(ensemble=1))
