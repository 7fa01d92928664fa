"""load_scene on every shared scene, the embedded skimage scene, and hostile folders."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from somtorch.disparity.io import write_pfm
from somtorch.disparity import (
    Camera,
    ObjectInfo,
    Scene,
    load_scene,
    parse_middlebury_calib,
    scene_from_arrays,
)
from somtorch.validation import DataFileError

# folder, (H, W), invalid fraction, (min, max) valid disparity, layout -- facts from the data READMEs
SCENES = {
    "middlebury2014/Motorcycle_Q": ((497, 741), 0.021, (9.2, 62.9), "middlebury"),
    "eth3d/terrace": ((434, 713), 0.47, (8.1, 17.4), "middlebury"),
    "kitti2015/devkit_demo": ((375, 1242), 0.76, (4.7, 115.9), "kitti"),
    "sceneflow_flyingthings3d/A-0032-0006": ((540, 960), 0.0, (1.2, 130.4), "sceneflow"),
    "oakd_stereodemo/toy": ((480, 640), None, None, "oakd"),
    "oakd_stereodemo/selfie": ((480, 640), None, None, "oakd"),
    "oakd_stereodemo/bedroom_chair": ((480, 640), None, None, "oakd"),
    "oakd_stereodemo/cycles": ((480, 640), None, None, "oakd"),
}


@pytest.fixture(scope="module")
def motorcycle() -> Scene:
    return load_scene("motorcycle")


@functools.cache
def _shared_scene(path) -> Scene:
    """Each shared scene read once per session (tests only read scenes, never change them)."""
    return load_scene(path)


@pytest.mark.parametrize("rel", list(SCENES))
def test_shared_scene_matches_readme_and_objects_json(shared_data, rel):
    size, invalid, value_range, layout = SCENES[rel]
    scene = _shared_scene(shared_data / rel)
    assert (scene.height, scene.width) == size and scene.source["layout"] == layout
    assert scene.image is not None and scene.image.shape == (3, *size)
    if invalid is not None:
        assert 1 - scene.n_valid / scene.valid.numel() == pytest.approx(invalid, abs=0.005)
        d = scene.disparity[scene.valid]
        assert d.min().item() == pytest.approx(value_range[0], abs=0.06)
        assert d.max().item() == pytest.approx(value_range[1], abs=0.06)
    else:  # OAK-D SGBM: nothing in the left 128 columns
        assert not scene.valid[:, :128].any()
    doc = json.loads((shared_data / rel / "objects.json").read_text())
    assert scene.object_info == [ObjectInfo(o["id"], o["name"], o["main"]) for o in doc["objects"]]
    for o in doc["objects"]:
        mask = scene.object_mask(o["id"])
        assert int(mask.sum()) == o["pixel_count"]
        assert int((mask & scene.valid).sum()) == o["valid_disparity_pixels"]
        ys, xs = mask.nonzero(as_tuple=True)
        assert [xs.min().item(), ys.min().item(), xs.max().item(), ys.max().item()] == o["bbox_xyxy"]
        median = scene.disparity[mask & scene.valid].median().item()
        assert median == pytest.approx(o["median_disparity"], abs=0.01)
    assert torch.equal(scene.main_object_mask, scene.object_mask(1))


def test_cameras_of_shared_scenes(shared_data):
    q = _shared_scene(shared_data / "middlebury2014" / "Motorcycle_Q").camera
    assert (q.focal_px, q.cx, q.cy, q.doffs, q.baseline) == (999.421, 294.182, 252.932, 32.778, 193.001)
    assert q.baseline_unit == "mm"
    assert q.baseline_m == pytest.approx(0.193001)
    eth = _shared_scene(shared_data / "eth3d" / "terrace").camera
    assert (eth.focal_px, eth.doffs, eth.baseline) == (711.499, 0.0, 59.9432)
    kitti = _shared_scene(shared_data / "kitti2015" / "devkit_demo").camera
    assert kitti.approximate
    assert (kitti.focal_px, kitti.baseline, kitti.cx, kitti.cy) == (721.5, 0.54, 621.0, 187.5)
    sf = _shared_scene(shared_data / "sceneflow_flyingthings3d" / "A-0032-0006").camera
    assert sf.baseline_unit == "unit" and sf.baseline_m is None
    assert (sf.focal_px, sf.cx, sf.cy) == (1050, 479.5, 269.5)
    oak = _shared_scene(shared_data / "oakd_stereodemo" / "toy").camera
    assert oak.focal_px == pytest.approx(451.034, abs=1e-3) and oak.baseline == 0.075 and oak.doffs == 0.0
    # README: Z[m] = 0.075 * 451.034 / d
    assert oak.depth(torch.tensor([45.1034])).item() == pytest.approx(0.75, abs=1e-4)


def test_motorcycle_q_depth_of_main_object(shared_data):
    scene = _shared_scene(shared_data / "middlebury2014" / "Motorcycle_Q")
    depth = scene.camera.depth(scene.disparity)[scene.main_object_mask & scene.valid]
    # median d = 52.048 px -> Z = 193.001 * 999.421 / (52.048 + 32.778) mm
    assert depth.median().item() == pytest.approx(193.001 * 999.421 / 84.826, rel=1e-3)


def test_disparity_file_choice_and_single_file(shared_data):
    est = load_scene(shared_data / "kitti2015" / "devkit_demo", disparity_file="disp_est.png")
    assert est.source["disparity"].endswith("disp_est.png") and est.n_valid / est.valid.numel() > 0.99
    assert len(est.object_info) == 4 and est.camera.approximate
    single = load_scene(shared_data / "eth3d" / "terrace" / "disp0.pfm")
    assert single.name == "disp0" and single.source["layout"] == "file"
    assert single.image is None and single.objects is None
    # the calib.txt beside the file gives the camera (a point cloud needs one)
    assert single.camera is not None and single.camera.focal_px == pytest.approx(711.499)
    assert single.n_valid == _shared_scene(shared_data / "eth3d" / "terrace").n_valid


# ------------------------------------------------------------------------ embedded skimage motorcycle


def test_embedded_motorcycle(motorcycle):
    assert (motorcycle.height, motorcycle.width) == (500, 741) and motorcycle.image.shape == (3, 500, 741)
    assert 1 - motorcycle.n_valid / motorcycle.valid.numel() == pytest.approx(0.0735, abs=0.001)
    assert torch.isfinite(motorcycle.disparity).all() and motorcycle.main_object_mask is None
    cam = motorcycle.camera
    # full-res Motorcycle-perfect calib x 741/2964 = the values skimage documents for its copy
    assert cam.focal_px == pytest.approx(994.978, abs=1e-3) and cam.cx == pytest.approx(311.193, abs=1e-3)
    assert cam.cy == pytest.approx(254.877, abs=1e-3) and cam.doffs == pytest.approx(31.086, abs=1e-3)
    assert cam.baseline == 193.001 and cam.baseline_unit == "mm"


def test_embedded_motorcycle_depth_agrees_with_motorcycle_q(motorcycle, shared_data):
    q = _shared_scene(shared_data / "middlebury2014" / "Motorcycle_Q")
    both = q.main_object_mask & q.valid & motorcycle.valid[:497]
    ratio = motorcycle.camera.depth(motorcycle.disparity[:497])[both] / q.camera.depth(q.disparity)[both]
    # two rectifications of the same scene (measured median 1.048): a wrong scale factor gives ~1.9
    assert 1.0 < ratio.median().item() < 1.08


# ----------------------------------------------------------------------------------- hostile folders


def _write_scene(folder, disp, image_size=None):
    folder.mkdir()
    write_pfm(folder / "disp0GT.pfm", disp)
    if image_size is not None:
        cv2.imwrite(str(folder / "im0.png"), np.zeros((*image_size, 3), np.uint8))
    return folder


def test_image_of_wrong_size(tmp_path):
    folder = _write_scene(tmp_path / "s", np.ones((4, 6), np.float32), image_size=(4, 5))
    with pytest.raises(DataFileError, match=r"im0\.png: image size 4x5 .* disparity 4x6 from disp0GT\.pfm"):
        load_scene(folder)


def test_objects_of_wrong_size_or_unknown_id(tmp_path):
    folder = _write_scene(tmp_path / "s", np.ones((4, 6), np.float32), image_size=(4, 6))
    cv2.imwrite(str(folder / "objects.png"), np.zeros((3, 6), np.uint8))
    with pytest.raises(DataFileError, match=r"objects\.png: instance map size 3x6"):
        load_scene(folder)
    mask = np.zeros((4, 6), np.uint8)
    mask[1, 1], mask[2, 2] = 1, 2
    cv2.imwrite(str(folder / "objects.png"), mask)
    (folder / "objects.json").write_text(json.dumps({"objects": [{"id": 1, "name": "a", "main": True}]}))
    with pytest.raises(DataFileError, match=r"objects\.png: holds object id\(s\) \[2\]"):
        load_scene(folder)
    (folder / "objects.json").write_text("{not json")
    with pytest.raises(DataFileError, match=r"objects\.json: invalid JSON"):
        load_scene(folder)
    (folder / "objects.json").unlink()  # no json: names inferred, id 1 main
    scene = load_scene(folder)
    assert scene.object_info == [ObjectInfo(1, "object_1", True), ObjectInfo(2, "object_2", False)]


def test_all_invalid_disparity(tmp_path):
    folder = _write_scene(tmp_path / "s", np.full((3, 3), np.inf, np.float32))
    with pytest.raises(DataFileError, match=r"disp0GT\.pfm: no valid disparity"):
        load_scene(folder)
    with pytest.raises(DataFileError, match=r"disp0GT\.pfm: no valid disparity"):
        load_scene(folder / "disp0GT.pfm")


def test_unrecognised_folder_and_missing_paths(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFileError, match=r"empty: no recogni.*disp0GT\.pfm.*disp_sgbm\.png"):
        load_scene(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_scene(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match=r"disp_est\.png"):
        load_scene(tmp_path / "empty", disparity_file="disp_est.png")
    with pytest.raises(ValueError, match="embedded"):
        load_scene("motorcycle", disparity_file="x.pfm")


def test_calibration_checked_against_disparity(tmp_path):
    folder = _write_scene(tmp_path / "s", np.ones((4, 6), np.float32))
    (folder / "calib.txt").write_text("cam0=[999.421 0 294.182; 0 999.421 252.932; 0 0 1]\ndoffs=32.778\n"
                                      "baseline=193.001\nwidth=741\nheight=497\n")
    with pytest.raises(DataFileError, match=r"calib\.txt: calibration is for 497x741"):
        load_scene(folder)
    (folder / "calib.txt").write_text("cam0=[1 0 2; 0 1 3; 0 0 1]\nbaseline=50\nwidth=6\nheight=4\n")
    assert load_scene(folder).camera == Camera(1.0, 2.0, 3.0, 50.0, "mm", doffs=0.0)
    (folder / "calib.txt").write_text("cam0=[1 0 2; 0 1 3]\n")
    with pytest.raises(DataFileError, match=r"calib\.txt: line 1: matrix cam0 must be 3x3"):
        parse_middlebury_calib(folder / "calib.txt")


def test_parse_middlebury_calib(shared_data):
    calib = parse_middlebury_calib(shared_data / "middlebury2014" / "Motorcycle_Q" / "calib.txt")
    assert calib["cam0"].shape == (3, 3) and calib["cam1"][0, 2] == 326.96
    assert calib["ndisp"] == 70 and isinstance(calib["ndisp"], int) and calib["doffs"] == 32.778


# ----------------------------------------------------------------------------- arrays and the camera


def test_scene_from_arrays():
    d = np.array([[1.0, np.nan], [-1.0, 2.0]], np.float32)
    image = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)  # numpy: channels last
    scene = scene_from_arrays(d, image=image, objects=np.array([[0, 1], [2, 2]]), name="tiny")
    assert scene.valid.tolist() == [[True, False], [False, True]]
    assert scene.disparity.tolist() == [[1.0, 0.0], [0.0, 2.0]]
    assert torch.equal(scene.image, torch.from_numpy(image).permute(2, 0, 1))
    assert scene.main_object_mask.tolist() == [[False, True], [False, False]]
    assert repr(scene) == "Scene('tiny', 2x2, valid 50.0%, image, 2 object(s), no camera)"
    grey = scene_from_arrays(torch.ones(2, 2), image=torch.zeros(2, 2, dtype=torch.uint8))
    assert grey.image.shape == (3, 2, 2)
    with pytest.raises(ValueError, match="no valid disparity"):
        scene_from_arrays(np.full((2, 2), np.inf))
    with pytest.raises(ValueError, match=r"image must have shape \(3, 2, 2\)"):
        scene_from_arrays(torch.ones(2, 2), image=torch.zeros(3, 2, 3, dtype=torch.uint8))
    with pytest.raises(TypeError, match="valid must be a bool"):
        scene_from_arrays(torch.ones(2, 2), valid=torch.ones(2, 2))


def test_camera_validation_and_depth():
    cam = Camera(focal_px=100.0, cx=5.0, cy=6.0, baseline=0.5, doffs=2.0)
    assert cam.depth(torch.tensor([8.0, -2.0, -3.0], dtype=torch.float64)).tolist() == [5.0, np.inf, np.inf]
    assert cam.intrinsics().tolist() == [[100.0, 0.0, 5.0], [0.0, 100.0, 6.0], [0.0, 0.0, 1.0]]
    assert cam.scaled(0.5) == Camera(50.0, 2.5, 3.0, 0.5, doffs=1.0)
    with pytest.raises(ValueError, match="focal_px"):
        Camera(focal_px=-1.0, cx=0, cy=0, baseline=1)
    with pytest.raises(ValueError, match=r"baseline_unit='km'.*m, mm, unit"):
        Camera(focal_px=1.0, cx=0, cy=0, baseline=1, baseline_unit="km")
    with pytest.raises(TypeError, match="floating-point"):
        cam.depth(torch.tensor([1, 2]))


def _kitti_official(root):
    import cv2

    for sub in ("image_2", "disp_occ_0", "calib_cam_to_cam"):
        (root / sub).mkdir(parents=True)
    rng = np.random.default_rng(0)
    d = (rng.uniform(1, 60, (30, 80)) * 256).astype(np.uint16)
    d[rng.random(d.shape) < 0.5] = 0
    cv2.imwrite(str(root / "disp_occ_0" / "000046_10.png"), d)
    cv2.imwrite(str(root / "image_2" / "000046_10.png"), rng.integers(0, 255, (30, 80, 3), dtype=np.uint8))
    (root / "calib_cam_to_cam" / "000046.txt").write_text(
        "P_rect_02: 7.215377e+02 0 6.095593e+02 4.485728e+01 0 7.215377e+02 1.728540e+02 2.163791e-01 0 0 1 0\n"
        "P_rect_03: 7.215377e+02 0 6.095593e+02 -3.395242e+02 0 7.215377e+02 1.728540e+02 2.199936e+00 0 0 1 0\n")
    return d


def test_official_kitti_layout(tmp_path):
    from somtorch.disparity.loading import load_kitti_frame

    d = _kitti_official(tmp_path / "training")
    scene = load_kitti_frame(tmp_path / "training", 46)
    assert scene.name == "kitti_000046" and scene.image is not None and scene.camera is not None
    assert scene.camera.baseline == pytest.approx(0.5327, abs=1e-3)
    assert np.array_equal(scene.valid.numpy(), d > 0)
    assert np.allclose(scene.disparity.numpy()[d > 0], d[d > 0] / 256.0)
    with pytest.raises(FileNotFoundError, match="disp_occ_0"):
        load_kitti_frame(tmp_path / "training", 47)
    with pytest.raises(ValueError, match="disp_noc_0"):
        load_kitti_frame(tmp_path / "training", 46, disparity="disp_x")


def test_official_kitti_layout_from_the_command_line(tmp_path):
    import json
    import subprocess
    import sys

    _kitti_official(tmp_path / "training")
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, "-m", "experiments.run", "data=kitti2015_official",
                           f"data.source={tmp_path / 'training'}", "data.frame=46", f"paths.output_dir={tmp_path / 'out'}",
                           "output.pointcloud=false", "output.maps=false", "output.tensorboard=false"],
                          cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    runs = list((tmp_path / "out" / "run" / "kitti_46").glob("*/metrics.json"))
    assert len(runs) == 1 and json.loads(runs[0].read_text())["scene"]["name"] == "kitti_46"


def test_an_old_middlebury_folder_with_an_8bit_disparity_and_its_scale(tmp_path):
    """Middlebury 2003 style: im2.png + disp2.png (8-bit, 4 x the disparity, 0 = unknown)."""
    rng = np.random.default_rng(0)
    d8 = rng.integers(1, 255, (20, 30), dtype=np.uint8)
    d8[0, :5] = 0
    cv2.imwrite(str(tmp_path / "disp2.png"), d8)
    with pytest.raises(Exception, match="scale"):  # 8-bit PNG has no standard encoding
        load_scene(tmp_path / "disp2.png")
    scene = load_scene(tmp_path / "disp2.png", disparity_scale=0.25)
    assert np.allclose(scene.disparity.numpy()[scene.valid.numpy()], d8[d8 > 0] / 4.0)
    assert int((~scene.valid).sum()) == 5
    folder = load_scene(tmp_path, disparity_file="disp2.png", disparity_scale=0.25)
    assert torch.equal(folder.disparity, scene.disparity)
