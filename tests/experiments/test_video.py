"""The video experiment: a pan over the embedded scene and a glob of frame files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _run(tmp_path, *overrides):
    proc = subprocess.run([sys.executable, "-m", "experiments.video", f"hydra.run.dir={tmp_path}", *overrides],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    return proc


def test_pan_over_the_embedded_scene(tmp_path):
    proc = _run(tmp_path, "sequence.frames=5", "sequence.width=320", "sequence.height=200")
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["schema"] == "somtorch.video/1" and m["summary"]["frames"] == 5
    assert [f["warm"] for f in m["frames"]] == [False, True, True, True, True]
    assert all(f["kept_boxes"] and 0 <= f["reduction_union"] <= 100 for f in m["frames"])
    assert m["summary"]["fps"] > 0 and m["summary"]["useful_hits"] is None  # the embedded map has no mask
    # what was kept, per frame: a video of 5 frames (320 x 200: smaller than the 640 px bound) and a sheet
    cap = cv2.VideoCapture(str(tmp_path / "kept.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    ok, frame = cap.read()
    assert ok and frame.shape == (200, 320, 3) and frame.std() > 10
    cap.release()
    sheet = cv2.imread(str(tmp_path / "contact_sheet.png"))
    assert sheet.shape == (2 * 200, 4 * 320, 3)  # 5 frames, 4 per row
    assert m["pictures"]["frames"] == 5 and m["pictures"]["contact_sheet_frames"] == [0, 1, 2, 3, 4]
    assert "outputs in" in proc.stdout and str(tmp_path) in proc.stdout
    assert not list(tmp_path.glob(".partial-*"))


def test_frames_from_files_and_a_bad_glob(tmp_path):
    d = tmp_path / "seq"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        disp = 5 + rng.random((60, 80), dtype=np.float32)
        disp[20:40, 20 + 5 * i:45 + 5 * i] = 30
        np.save(d / f"disp_{i:03d}.npy", disp)
    proc = _run(tmp_path / "out", f"sequence.glob={d}/disp_*.npy")
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["summary"]["frames"] == 3
    boxes = [f["kept_boxes"][0] for f in m["frames"]]
    assert [b[0] for b in boxes] == sorted(b[0] for b in boxes)  # the box follows the object right
    bad = _run(tmp_path / "bad", f"sequence.glob={d}/nothing_*.npy")
    assert bad.returncode == 2 and "matches no file" in bad.stderr
