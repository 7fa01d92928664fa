"""Readers on the real files of ../shared/data and on hostile files written in tmp_path."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from somtorch.disparity.io import read_disparity, read_image, read_mask, read_pfm, write_pfm
from somtorch.validation import DataFileError

# ------------------------------------------------------------------------------------- real PFM files


def test_pfm_middlebury_values_are_pixels_and_rows_flipped(shared_data):
    folder = shared_data / "middlebury2014" / "Motorcycle_Q"
    d, scale = read_pfm(folder / "disp0GT.pfm")
    assert d.shape == (497, 741) and d.dtype == np.float32
    assert scale == pytest.approx(-1 / 255, rel=1e-3)  # magnitude ignored: values stay pixels
    finite = np.isfinite(d)
    assert 1 - finite.mean() == pytest.approx(0.021, abs=0.001)
    assert (d[finite].min(), d[finite].max()) == pytest.approx((9.18, 62.88), abs=0.01)
    # mask0nocc.png (top-to-bottom PNG): 0 = no GT. It matches the inf pattern only after the flip.
    no_gt = cv2.imread(str(folder / "mask0nocc.png"), cv2.IMREAD_UNCHANGED) == 0
    assert np.array_equal(no_gt, ~finite)
    assert not np.array_equal(no_gt, ~finite[::-1])


def test_pfm_freiburg_header_with_trailing_spaces(shared_data):
    path = shared_data / "sceneflow_flyingthings3d" / "A-0032-0006" / "disparity_left.pfm"
    assert path.read_bytes().startswith(b"Pf \n960 540 \n")
    d, scale = read_pfm(path)
    assert d.shape == (540, 960) and scale == -1.0
    assert np.isfinite(d).all()
    assert d.min() == pytest.approx(1.21, abs=0.01) and d.max() == pytest.approx(130.36, abs=0.01)


def test_read_disparity_eth3d(shared_data):
    d, valid = read_disparity(shared_data / "eth3d" / "terrace" / "disp0.pfm")
    assert d.shape == valid.shape == (434, 713) and d.dtype == torch.float32 and valid.dtype == torch.bool
    assert 1 - valid.float().mean().item() == pytest.approx(0.468, abs=0.002)
    assert (d[valid].min().item(), d[valid].max().item()) == pytest.approx((8.12, 17.42), abs=0.01)
    assert (d[~valid] == 0).all() and torch.isfinite(d).all()


# ------------------------------------------------------------------------------------- real PNG files


def test_read_disparity_kitti_png(shared_data):
    folder = shared_data / "kitti2015" / "devkit_demo"
    d, valid = read_disparity(folder / "disp_gt.png")
    assert d.shape == (375, 1242)
    assert 1 - valid.float().mean().item() == pytest.approx(0.761, abs=0.002)
    assert (d[valid].min().item(), d[valid].max().item()) == pytest.approx((4.738, 115.93), abs=0.01)
    raw = cv2.imread(str(folder / "disp_gt.png"), cv2.IMREAD_UNCHANGED)
    assert torch.equal(valid, torch.from_numpy(raw > 0))
    assert torch.allclose(d[valid], torch.from_numpy(raw[raw > 0] / 256.0).float())
    _, valid_est = read_disparity(folder / "disp_est.png")
    assert valid_est.float().mean().item() > 0.99  # the estimate is dense


@pytest.mark.parametrize("scene", ["toy", "selfie", "bedroom_chair", "cycles"])
def test_read_disparity_oakd_left_columns_invalid(shared_data, scene):
    d, valid = read_disparity(shared_data / "oakd_stereodemo" / scene / "disp_sgbm.png")
    assert d.shape == (480, 640)
    assert not valid[:, :128].any() and valid[:, 128:].any()
    assert 0.26 <= 1 - valid.float().mean().item() <= 0.58  # README: 26-58 % invalid
    assert d.max().item() < 128  # numDisparities = 128


def test_read_image_and_mask_real(shared_data):
    grey = read_image(shared_data / "oakd_stereodemo" / "toy" / "left.png")
    assert grey.shape == (3, 480, 640) and grey.dtype == torch.uint8
    assert torch.equal(grey[0], grey[1]) and torch.equal(grey[0], grey[2])
    rgba = read_image(shared_data / "sceneflow_flyingthings3d" / "A-0032-0006" / "left_cleanpass.png")
    assert rgba.shape == (3, 540, 960)
    mask = read_mask(shared_data / "kitti2015" / "devkit_demo" / "objects.png")
    assert mask.shape == (375, 1242) and mask.dtype == torch.int64
    assert sorted(torch.unique(mask).tolist()) == [0, 1, 2, 3, 4]


# ----------------------------------------------------------------------------------- synthetic files


@pytest.mark.parametrize("little_endian", [True, False])
def test_pfm_round_trip(tmp_path, little_endian):
    a = np.arange(12, dtype=np.float32).reshape(3, 4) - 2.5
    a[0, 1], a[2, 3] = np.inf, np.nan
    path = write_pfm(tmp_path / "a.pfm", a, little_endian=little_endian)
    raw = path.read_bytes()
    assert raw.startswith(b"Pf\n4 3\n" + (b"-1.0\n" if little_endian else b"1.0\n"))
    # first stored row is the bottom row
    first = np.frombuffer(raw[len(raw) - 48:][:16], dtype="<f4" if little_endian else ">f4")
    np.testing.assert_array_equal(first, a[2])
    b, scale = read_pfm(path)
    np.testing.assert_array_equal(b, a)
    assert scale == (-1.0 if little_endian else 1.0)
    assert [p.name for p in tmp_path.iterdir()] == ["a.pfm"]  # no temp file left behind


def test_pfm_colour_needs_channel(tmp_path):
    a = np.random.default_rng(0).random((2, 3, 3), dtype=np.float32)
    path = write_pfm(tmp_path / "flow.pfm", torch.from_numpy(a))
    with pytest.raises(DataFileError, match=r"flow\.pfm.*colour PFM"):
        read_pfm(path)
    np.testing.assert_array_equal(read_pfm(path, channel=1)[0], a[:, :, 1])


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (b"Pf\n4 3\n-1.0\n" + b"\0" * 20, "truncated"),
        (b"P6\n4 3\n-1.0\n" + b"\0" * 48, "magic"),
        (b"garbage without newlines", "header"),
        (b"Pf\nfour 3\n-1.0\n" + b"\0" * 48, "integers"),
        (b"Pf\n0 3\n-1.0\n", "positive"),
        (b"Pf\n4 -3\n-1.0\n", "positive"),
        (b"Pf\n4 3\n0\n" + b"\0" * 48, "non-zero"),
    ],
)
def test_hostile_pfm(tmp_path, content, problem):
    path = tmp_path / "bad.pfm"
    path.write_bytes(content)
    with pytest.raises(DataFileError, match=problem) as info:
        read_disparity(path)
    assert str(info.value).startswith(str(path))


def test_png_8bit_needs_scale(tmp_path):
    path = tmp_path / "vis.png"
    cv2.imwrite(str(path), np.full((4, 5), 7, np.uint8))
    with pytest.raises(DataFileError, match=r"vis\.png.*8-bit PNG.*scale="):
        read_disparity(path)
    d, valid = read_disparity(path, scale=1.0)
    assert valid.all() and (d == 7).all()


def test_png_16bit_encoding_and_colour_rejected(tmp_path):
    raw = np.array([[0, 256, 384], [65535, 1, 512]], np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), raw)
    d, valid = read_disparity(tmp_path / "d.png")
    assert valid.tolist() == [[False, True, True], [True, True, True]]
    assert d.flatten().tolist() == pytest.approx([0.0, 1.0, 1.5, 65535 / 256, 1 / 256, 2.0])
    cv2.imwrite(str(tmp_path / "c.png"), np.zeros((2, 3, 3), np.uint16))
    with pytest.raises(DataFileError, match=r"c\.png.*one channel"):
        read_disparity(tmp_path / "c.png")


def test_corrupt_png(tmp_path):
    path = tmp_path / "broken.png"
    path.write_bytes(b"\x89PNG not really")
    with pytest.raises(DataFileError, match=r"broken\.png.*cannot decode"):
        read_disparity(path)
    with pytest.raises(DataFileError, match=r"broken\.png"):
        read_image(path)


def test_npy_npz(tmp_path):
    a = np.array([[1.5, -2.0], [np.nan, -1.0]], np.float32)
    np.save(tmp_path / "d.npy", a)
    d, valid = read_disparity(tmp_path / "d.npy")
    assert valid.tolist() == [[True, False], [False, False]] and d.tolist() == [[1.5, 0.0], [0.0, 0.0]]
    d, valid = read_disparity(tmp_path / "d.npy", scale=2.0, invalid_value=1.5)
    assert not valid.any()
    np.savez(tmp_path / "named.npz", image=np.zeros((2, 2)), disp=a)
    assert read_disparity(tmp_path / "named.npz")[1].sum() == 1
    np.savez(tmp_path / "single.npz", whatever=a)
    assert read_disparity(tmp_path / "single.npz")[1].sum() == 1


@pytest.mark.parametrize(
    ("arrays", "problem"),
    [({}, "no arrays"), ({"a": np.ones((2, 2)), "b": np.ones((2, 2))}, r"keys \['a', 'b'\]"),
     ({"disparity": np.ones(3)}, "2-D"), ({"disparity": np.ones((2, 2), bool)}, "real numbers")],
)
def test_hostile_npz(tmp_path, arrays, problem):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(DataFileError, match=problem) as info:
        read_disparity(path)
    assert "bad.npz" in str(info.value)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match=r"\.exr.*\.pfm, \.png, \.npy, \.npz, \.tif, \.tiff"):
        read_disparity(tmp_path / "d.exr")
    with pytest.raises(FileNotFoundError, match=r"nothere\.pfm"):
        read_disparity(tmp_path / "nothere.pfm")
    with pytest.raises(ValueError, match="scale"):
        read_disparity(tmp_path / "d.npy", scale=0)


def test_read_image_channel_orders(tmp_path):
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[..., 0], bgr[..., 2] = 10, 200  # blue 10, red 200
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    img = read_image(tmp_path / "c.png")
    assert img.shape == (3, 2, 3) and img[0, 0, 0] == 200 and img[2, 0, 0] == 10
    bgra = np.concatenate([bgr, np.full((2, 3, 1), 77, np.uint8)], axis=2)
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    assert torch.equal(read_image(tmp_path / "a.png"), img)


def test_read_mask_rejects_colour(tmp_path):
    cv2.imwrite(str(tmp_path / "m.png"), np.dstack([np.zeros((2, 2), np.uint8), np.ones((2, 2), np.uint8),
                                                    np.zeros((2, 2), np.uint8)]))
    with pytest.raises(DataFileError, match=r"m\.png.*one channel"):
        read_mask(tmp_path / "m.png")


def test_float_tiff_disparity(tmp_path):
    import cv2

    from somtorch.disparity.io import read_disparity
    from somtorch.validation import DataFileError

    d = np.random.default_rng(0).uniform(0, 60, (20, 30)).astype(np.float32)
    d[0, 0], d[1, 1], d[2, 2] = np.nan, -1.0, np.inf
    assert cv2.imwrite(str(tmp_path / "d.tif"), d)
    disp, valid = read_disparity(tmp_path / "d.tif")
    assert not valid[0, 0] and not valid[1, 1] and not valid[2, 2] and int(valid.sum()) == d.size - 3
    assert np.array_equal(disp.numpy()[valid.numpy()], d[valid.numpy()])
    assert cv2.imwrite(str(tmp_path / "i.tiff"), (d.clip(0, 60) * 100).astype(np.uint16))
    with pytest.raises(DataFileError, match="scale="):
        read_disparity(tmp_path / "i.tiff")
    disp, valid = read_disparity(tmp_path / "i.tiff", scale=0.01)
    assert float(disp[5, 5]) == pytest.approx(float(d[5, 5]), abs=0.011)
