"""Frames on disk: load_scene round trip, atomic writes, the manifest."""

from __future__ import annotations

import math

import pytest
import torch

from experiments.synth import frame_digest
from somtorch.disparity import load_scene
from somtorch.synth import ensure_frame, generate_frame, load_frame, write_frame
from somtorch.synth.store import dataset_dir, generator_version, read_manifest


def test_load_scene_reads_a_written_frame_in_both_versions(tmp_path):
    fr = generate_frame("tabletop", 2, "middlebury", scale=0.25)
    folder = write_frame(fr, tmp_path / "f")
    gt = load_scene(folder)
    valid = torch.isfinite(fr.disparity)
    assert torch.equal(gt.valid, valid) and torch.equal(gt.disparity[valid], fr.disparity[valid])
    assert torch.equal(gt.image, fr.left) and torch.equal(gt.objects, fr.objects)
    expected = [(o["id"], o["name"], o["main"]) for o in fr.object_info]
    assert [(o.id, o.name, o.main) for o in gt.object_info] == expected
    assert gt.main_object_mask is not None and gt.main_object_mask.sum() == fr.object_info[0]["pixels"]
    c = gt.camera
    assert (c.focal_px, c.cx, c.cy, c.doffs) == (fr.camera.focal_px, fr.camera.cx, fr.camera.cy, 0.0)
    assert math.isclose(c.baseline_m, 0.19)
    sg = load_scene(folder, disparity_file="disp_sgbm.pfm")
    ok = torch.isfinite(fr.sgbm)
    assert torch.equal(sg.valid, ok) and torch.equal(sg.disparity[ok], fr.sgbm[ok])
    assert torch.equal(sg.objects, fr.objects)
    # GT depth back from the loaded camera: the disparity is f·B/Z in this camera's units
    assert torch.isfinite(gt.camera.depth(gt.disparity[gt.valid])).all()


def test_written_bytes_are_identical_and_folders_complete(tmp_path):
    a = write_frame(generate_frame("hands", 1, "oakd", scale=0.25), tmp_path / "a")
    b = write_frame(generate_frame("hands", 1, "oakd", scale=0.25), tmp_path / "b")
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(["calib.txt", "disp0GT.pfm", "disp_sgbm.pfm", "im0.png", "im1.png", "objects.json",
                            "objects.png"])
    assert all((a / n).read_bytes() == (b / n).read_bytes() for n in names)
    assert frame_digest(a) == frame_digest(b)
    write_frame(generate_frame("hands", 2, "oakd", scale=0.25), a)  # replaces the old folder
    assert (a / "im0.png").read_bytes() != (b / "im0.png").read_bytes()
    assert frame_digest(a) != frame_digest(b)
    with pytest.raises(FileNotFoundError, match="no generated frame"):
        frame_digest(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]  # no temporary left behind


def test_ensure_frame_skips_current_frames_and_regenerates_stale_ones(tmp_path):
    folder = ensure_frame("fence", 0, "oakd", scale=0.25, root=tmp_path)
    stamp = (folder / "im0.png").stat().st_mtime_ns
    assert ensure_frame("fence", 0, "oakd", scale=0.25, root=tmp_path) == folder
    assert (folder / "im0.png").stat().st_mtime_ns == stamp
    dataset = dataset_dir("fence", "oakd", 0.25, tmp_path)
    manifest = read_manifest(dataset)
    assert manifest["frames"]["00000"]["generator"] == generator_version()
    manifest["frames"]["00000"]["generator"] = "stale"
    (dataset / "manifest.json").write_text(__import__("json").dumps(manifest))
    ensure_frame("fence", 0, "oakd", scale=0.25, root=tmp_path)
    assert read_manifest(dataset)["frames"]["00000"]["generator"] == generator_version()
    scene = load_frame("fence", 0, "oakd", "sgbm", scale=0.25, root=tmp_path)
    assert scene.name == "fence_oakd_00000_sgbm" and scene.source["disparity"].endswith("disp_sgbm.pfm")


def test_the_corpus_folder_is_the_one_the_dataset_registry_reads(tmp_path, monkeypatch):
    from experiments.datasets import corpus_dir
    from somtorch.synth import cache_root

    monkeypatch.delenv("SOMTORCH_CORPUS", raising=False)
    monkeypatch.setenv("SOMTORCH_CACHE", str(tmp_path / "c"))
    assert cache_root() == corpus_dir() == tmp_path / "c" / "corpus"
    monkeypatch.setenv("SOMTORCH_CORPUS", str(tmp_path / "k"))
    assert cache_root() == corpus_dir() == tmp_path / "k"
