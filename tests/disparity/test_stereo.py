"""StereoSGBM on real pairs: the shipped OAK-D maps are reproduced, the Motorcycle GT is approached."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from skimage import data

from somtorch.disparity.io import read_disparity, read_image
from somtorch.disparity import Camera, load_scene
from somtorch.disparity.stereo import SGBMParams, compute_disparity, scene_from_stereo


@pytest.fixture(scope="module")
def motorcycle_pair() -> tuple[np.ndarray, np.ndarray]:
    left, right, _ = data.stereo_motorcycle()
    return left, right


@pytest.mark.parametrize("scene", ["toy", "selfie", "bedroom_chair", "cycles"])
def test_reproduces_shipped_oakd_disparity(shared_data, scene):
    folder = shared_data / "oakd_stereodemo" / scene
    params = SGBMParams.from_dict(json.loads((folder / "sgbm_params.json").read_text()))
    assert params == SGBMParams()  # the defaults are the OAK-D settings
    left, right = read_image(folder / "left.png")[0], read_image(folder / "right.png")[0]  # (H, W) grey
    d, valid = compute_disparity(left, right, params)
    ref, ref_valid = read_disparity(folder / "disp_sgbm.png")
    # measured with OpenCV 5.0: identical masks and values (the maps were made with OpenCV 4)
    assert (valid == ref_valid).float().mean().item() >= 0.999
    both = valid & ref_valid
    assert ((d - ref).abs()[both] <= 1.0).float().mean().item() >= 0.999
    assert not valid[:, :128].any()


def test_motorcycle_against_ground_truth(motorcycle_pair):
    left, right = motorcycle_pair
    gt = load_scene("motorcycle")
    d, valid = compute_disparity(left, right)  # colour, numpy (H, W, 3)
    both = valid & gt.valid
    within3 = ((d - gt.disparity).abs()[both] <= 3).float().mean().item()
    coverage = both.sum().item() / gt.n_valid
    # measured: 95.8 % within 3 px on 75.1 % of the GT pixels
    assert within3 > 0.94
    assert coverage > 0.70


def test_tensor_and_numpy_inputs_agree(motorcycle_pair):
    left, right = (x[::4, ::4].copy() for x in motorcycle_pair)  # (125, 186, 3), fast
    params = SGBMParams(numDisparities=16, blockSize=3)
    d_np, v_np = compute_disparity(left, right, params)
    chw = [torch.from_numpy(x).permute(2, 0, 1) for x in (left, right)]  # (3, H, W)
    d_t, v_t = compute_disparity(*chw, params)
    assert torch.equal(d_np, d_t) and torch.equal(v_np, v_t)
    assert d_np.dtype == torch.float32 and (d_np[~v_np] == 0).all() and (d_np[v_np] > 0).all()
    # disparities are multiples of 1/16 (OpenCV's fixed point)
    assert torch.equal(d_np * 16, (d_np * 16).round())


def test_scene_from_stereo(motorcycle_pair):
    left, right = (x[::4, ::4].copy() for x in motorcycle_pair)
    cam = Camera(focal_px=248.7, cx=77.8, cy=63.7, baseline=193.001, baseline_unit="mm", doffs=7.8)
    scene = scene_from_stereo(left, right, SGBMParams(numDisparities=16, blockSize=3), camera=cam, name="m4")
    assert scene.name == "m4" and scene.camera is cam and scene.source["layout"] == "stereo"
    assert torch.equal(scene.image, torch.from_numpy(left).permute(2, 0, 1))
    grey = scene_from_stereo(left[..., 0], right[..., 0], SGBMParams(numDisparities=16, blockSize=3))
    assert grey.image.shape == (3, *left.shape[:2]) and torch.equal(grey.image[0], grey.image[2])


def test_input_validation(motorcycle_pair):
    left, right = motorcycle_pair
    with pytest.raises(ValueError, match=r"left \(500, 741, 3\), right \(500, 740, 3\)"):
        compute_disparity(left, right[:, :-1])
    with pytest.raises(TypeError, match="uint8"):
        compute_disparity(left.astype(np.float32), right.astype(np.float32))
    with pytest.raises(ValueError, match="grey or 3-channel"):
        compute_disparity(left[..., :2].copy(), right[..., :2].copy())
    with pytest.raises(TypeError, match="SGBMParams"):
        compute_disparity(left, right, {"numDisparities": 64})


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"numDisparities": 100}, ValueError, "multiple of 16"),
        ({"numDisparities": 0}, ValueError, "multiple of 16"),
        ({"blockSize": 4}, ValueError, "odd"),
        ({"P1": 800, "P2": 200}, ValueError, "P2 must be larger"),
        ({"mode": "fast"}, ValueError, "hh, hh4, sgbm, sgbm_3way"),
        ({"blockSize": 5.0}, TypeError, "blockSize must be an int"),
        ({"speckleRange": True}, TypeError, "speckleRange must be an int"),
        ({"uniquenessRatio": -1}, ValueError, "uniquenessRatio must be >= 0"),
    ],
)
def test_params_validation(kwargs, error, match):
    with pytest.raises(error, match=match):
        SGBMParams(**kwargs)


def test_params_from_dict():
    assert SGBMParams.from_dict({"mode": 0}).mode == "sgbm"
    assert SGBMParams.from_dict({"mode": "hh4", "P1": None, "P2": None}).P1 is None
    with pytest.raises(ValueError, match=r"unknown SGBM parameter\(s\) \['numDisp'\]"):
        SGBMParams.from_dict({"numDisp": 64})
    with pytest.raises(ValueError, match="mode code 9"):
        SGBMParams.from_dict({"mode": 9})


def test_parameters_that_opencv_cannot_take_fail_with_a_clear_message():
    import numpy as np

    from somtorch.disparity.stereo import SGBMParams, compute_disparity

    narrow = np.zeros((40, 100), dtype=np.uint8)
    with pytest.raises(ValueError, match="100 px wide.*numDisparities"):
        compute_disparity(narrow, narrow, SGBMParams(numDisparities=128))
    with pytest.raises(ValueError, match="blockSize=51 is larger"):
        compute_disparity(narrow, narrow, SGBMParams(numDisparities=16, blockSize=51))
    with pytest.raises(ValueError, match="32-bit"):
        SGBMParams(uniquenessRatio=2**40)
