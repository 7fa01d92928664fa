"""The camera loaders on calibration files written in the test: values, units, and clear errors."""

from __future__ import annotations

import json

import pytest

from somtorch import DataFileError
from somtorch.disparity.camera import _middlebury_camera, _oakd_camera, read_middlebury_camera

CALIB = """cam0=[1000.5 0 300.25; 0 1000.5 200.75; 0 0 1]
cam1=[1000.5 0 330.25; 0 1000.5 200.75; 0 0 1]
doffs=30.0
baseline=193.0
width=640
height=480
ndisp=128
"""


def test_middlebury_calib_gives_focal_principal_point_baseline_in_mm_and_doffs(tmp_path):
    p = tmp_path / "calib.txt"
    p.write_text(CALIB)
    cam = read_middlebury_camera(p)
    assert (cam.focal_px, cam.cx, cam.cy, cam.baseline, cam.baseline_unit, cam.doffs) == \
        (1000.5, 300.25, 200.75, 193.0, "mm", 30.0)
    # without doffs: cam1.cx - cam0.cx
    p.write_text(CALIB.replace("doffs=30.0\n", ""))
    assert read_middlebury_camera(p).doffs == pytest.approx(30.0)
    # the folder loader checks the size the calibration was made for
    cam2, source = _middlebury_camera(tmp_path, (480, 640))
    assert cam2 is not None and source == str(p)
    with pytest.raises(DataFileError, match="480x640"):
        _middlebury_camera(tmp_path, (240, 320))


def test_middlebury_calib_without_a_camera_matrix_names_the_file_and_the_key(tmp_path):
    p = tmp_path / "calib.txt"
    p.write_text("baseline=193.0\nwidth=640\n")
    with pytest.raises(DataFileError, match=r"calib.txt.*cam0"):
        read_middlebury_camera(p)


def _oakd(tmp_path, **over):
    calib = {"width": 640, "height": 480, "fx": 451.03, "cx0": 320.5, "cx1": 322.0, "cy": 240.25,
             "baseline_meters": 0.075, **over}
    (tmp_path / "stereodemo_calibration.json").write_text(json.dumps(calib))


def test_oakd_json_gives_the_camera_in_metres(tmp_path):
    _oakd(tmp_path)
    cam, source = _oakd_camera(tmp_path, (480, 640))
    assert (cam.focal_px, cam.cx, cam.cy, cam.baseline, cam.baseline_unit) == (451.03, 320.5, 240.25, 0.075, "m")
    assert cam.doffs == pytest.approx(1.5) and source.endswith("stereodemo_calibration.json")
    assert _oakd_camera(tmp_path / "nothing", (480, 640)) == (None, None)


@pytest.mark.parametrize("over, words", [
    ({"fx": None}, ["stereodemo_calibration.json", "fx", "must be numbers"]),
    ({"fx": -3.0}, ["stereodemo_calibration.json", "invalid calibration"]),
    ({"width": 320}, ["stereodemo_calibration.json", "480x320"]),
])
def test_oakd_json_errors_name_the_file(tmp_path, over, words):
    _oakd(tmp_path, **over)
    with pytest.raises(DataFileError) as err:
        _oakd_camera(tmp_path, (480, 640))
    for w in words:
        assert w in str(err.value)


def test_oakd_json_missing_keys_are_listed(tmp_path):
    (tmp_path / "stereodemo_calibration.json").write_text(json.dumps({"width": 640}))
    with pytest.raises(DataFileError, match="lacks"):
        _oakd_camera(tmp_path, (480, 640))


def test_a_camera_matrix_that_is_not_a_matrix_and_non_numeric_fields_name_the_field(tmp_path):
    p = tmp_path / "calib.txt"
    p.write_text(CALIB.replace("cam0=[1000.5 0 300.25; 0 1000.5 200.75; 0 0 1]", "cam0=5"))
    with pytest.raises(DataFileError, match=r"calib.txt.*'cam0' must be a 3x3 matrix"):
        read_middlebury_camera(p)
    _oakd(tmp_path, cx0="left")
    with pytest.raises(DataFileError, match=r"stereodemo_calibration.json.*cx0.*must be numbers"):
        _oakd_camera(tmp_path, (480, 640))


# ----------------------------------------------------------------------- read_calibration
def test_read_calibration_knows_the_three_formats(tmp_path):
    import json

    from somtorch.disparity.camera import read_calibration

    (tmp_path / "my_oakd.json").write_text(json.dumps(
        {"width": 640, "height": 480, "fx": 451.0, "cx0": 299.0, "cx1": 299.0, "cy": 255.0, "baseline_meters": 0.075}))
    cam = read_calibration(tmp_path / "my_oakd.json", (480, 640))
    assert (cam.focal_px, cam.baseline, cam.baseline_unit) == (451.0, 0.075, "m")
    (tmp_path / "calib.txt").write_text("cam0=[1000 0 300; 0 1000 200; 0 0 1]\ncam1=[1000 0 330; 0 1000 200; 0 0 1]\n"
                                        "doffs=30\nbaseline=193.0\nwidth=640\nheight=480\n")
    cam = read_calibration(tmp_path / "calib.txt", (480, 640))
    assert (cam.focal_px, cam.doffs, cam.baseline_unit) == (1000.0, 30.0, "mm")
    # KITTI calib_cam_to_cam.txt: P_rect_03[0, 3] = -f * baseline
    (tmp_path / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\n"
        "P_rect_02: 7.215377e+02 0 6.095593e+02 4.485728e+01 0 7.215377e+02 1.728540e+02 2.163791e-01 0 0 1 2.745884e-03\n"
        "P_rect_03: 7.215377e+02 0 6.095593e+02 -3.395242e+02 0 7.215377e+02 1.728540e+02 2.199936e+00 0 0 1 2.729905e-03\n")
    cam = read_calibration(tmp_path / "calib_cam_to_cam.txt")
    assert cam.focal_px == pytest.approx(721.5377) and cam.cy == pytest.approx(172.854)
    assert cam.baseline == pytest.approx(0.5327, abs=1e-3) and cam.baseline_unit == "m"


@pytest.mark.parametrize("text, message", [
    ("hello", "not a calibration"),
    ('{"a": 1}', "stereodemo format"),
    ("P2: 1 2 3\n", "P_rect_02"),
])
def test_read_calibration_names_the_problem(tmp_path, text, message):
    from somtorch.disparity.camera import read_calibration
    from somtorch.validation import DataFileError

    (tmp_path / "c.txt").write_text(text)
    with pytest.raises(DataFileError, match=message) as e:
        read_calibration(tmp_path / "c.txt")
    assert "c.txt" in str(e.value)


def test_size_mismatch_is_refused(tmp_path):
    import json

    from somtorch.disparity.camera import read_calibration
    from somtorch.validation import DataFileError

    (tmp_path / "c.json").write_text(json.dumps(
        {"width": 640, "height": 480, "fx": 451.0, "cx0": 299.0, "cx1": 299.0, "cy": 255.0, "baseline_meters": 0.075}))
    with pytest.raises(DataFileError, match="480x640"):
        read_calibration(tmp_path / "c.json", (240, 320))
