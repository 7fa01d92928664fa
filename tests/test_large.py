"""Maps larger than memory: blocks of rows give what one in-memory pass gives."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch.config import FeatureConfig, TrainConfig
from somtorch.disparity.features import make_features
from somtorch.large import _block_rows, train_segment_large


@pytest.fixture()
def disp(tmp_path):
    rng = np.random.default_rng(0)
    d = (5 + 20 * rng.random((300, 400))).astype(np.float32)
    d[50:150, 100:250] = 60.0
    d[rng.random(d.shape) < 0.2] = 0.0  # invalid pixels, KITTI style
    np.save(tmp_path / "d.npy", d)
    return np.load(tmp_path / "d.npy", mmap_mode="r")


def test_training_features_are_the_in_memory_ones(disp, tmp_path):
    res = train_segment_large(disp, tmp_path / "w", memory_budget=64 << 20)
    dt = torch.from_numpy(np.array(disp))
    fc = FeatureConfig()
    stride = fc.stride_at(fc.train_stride, *disp.shape)
    assert stride == 6  # 10 · √(120,000 / 307,200), rounded: counted on 640 × 480, scaled down
    ref = make_features(dt, dt > 0, normalize="image").subsample(stride)
    got = np.load(tmp_path / "w" / "train_features.npy")
    assert got.shape == tuple(ref.x.shape) and res.n_train == len(got)
    assert np.array_equal(got, ref.x.numpy())
    labels = np.asarray(res.labels)
    assert labels.dtype == np.int16 and labels.shape == disp.shape
    assert np.array_equal(labels >= 0, np.asarray(disp) > 0)
    full = make_features(dt, dt > 0, normalize="image")
    want = res.som.bmu(full.x)[0].numpy()
    assert np.array_equal(labels[np.asarray(disp) > 0], want)  # row-major, as make_features orders pixels


def test_block_size_follows_the_budget_not_the_result(disp, tmp_path):
    small = train_segment_large(disp, tmp_path / "a", memory_budget=64 << 20)
    # a wider map in the same budget gets fewer rows per block
    assert _block_rows(100_000, 64 << 20) < _block_rows(400, 64 << 20)
    big = train_segment_large(disp, tmp_path / "b", memory_budget=1 << 32)
    assert big.block_rows >= small.block_rows
    assert torch.equal(small.som.weight, big.som.weight)
    assert np.array_equal(np.asarray(small.labels), np.asarray(big.labels))


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="no valid pixel"):
        train_segment_large(np.zeros((10, 10), np.float32), tmp_path)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        train_segment_large(np.zeros(10, np.float32), tmp_path)
    with pytest.raises(ValueError, match="64 MiB"):
        train_segment_large(np.ones((10, 10), np.float32), tmp_path, memory_budget=1000)


@pytest.mark.parametrize("normalize", ["image", "minmax", "none"])
@pytest.mark.parametrize(("d_weight", "train_stride", "reference_pixels"),
                         [(2.0, 10, 307_200), (0.5, 3, 0), (1.0, 4, 30_000), (2.0, 1, 307_200)])
def test_features_equal_make_features_for_every_option(disp, tmp_path, normalize, d_weight, train_stride,
                                                       reference_pixels):
    """One FeatureConfig means one thing: the large path's training features are make_features's,
    bitwise, strided as the pipeline strides them (``stride_at``, so ``reference_pixels`` counts)."""
    fc = FeatureConfig(normalize=normalize, d_weight=d_weight, train_stride=train_stride,
                       reference_pixels=reference_pixels)
    d = np.array(disp)
    d[:7] = 0.0  # no valid pixel in the first rows and the last columns: minmax offsets are not 0
    d[:, -5:] = 0.0
    res = train_segment_large(d, tmp_path / "w", features=fc, memory_budget=64 << 20,
                              train=TrainConfig(epochs=1))
    dt = torch.from_numpy(d)
    full = make_features(dt, dt > 0, normalize=normalize, d_weight=d_weight)
    stride = fc.stride_at(train_stride, *d.shape)
    # 4 · √(120,000 / 30,000) = 8; 10 · √(120,000 / 307,200) = 6.25; 0: as given; 1 stays 1
    assert stride == {30_000: 8, 0: train_stride}.get(reference_pixels, 6 if train_stride == 10 else 1)
    ref = full.subsample(stride)
    got = torch.from_numpy(np.load(tmp_path / "w" / "train_features.npy"))
    assert torch.equal(got, ref.x)
    labels = np.asarray(res.labels)
    assert np.array_equal(labels[d > 0], res.som.bmu(full.x)[0].numpy())


@pytest.mark.parametrize(("field", "value"), [("color_weight", 0.5)])
def test_options_the_large_path_cannot_honour_are_refused(disp, tmp_path, field, value):
    with pytest.raises(ValueError, match=f"features.{field}"):
        train_segment_large(disp, tmp_path, features=FeatureConfig(**{field: value}))
