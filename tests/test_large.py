"""Maps larger than memory: blocks of rows give what one in-memory pass gives."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch.config import FeatureConfig
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
    ref = make_features(dt, dt > 0, normalize="image").subsample(FeatureConfig().train_stride)
    got = np.load(tmp_path / "w" / "train_features.npy")
    assert got.shape == tuple(ref.x.shape) and res.n_train == len(got)
    assert np.allclose(got, ref.x.numpy(), atol=1e-6)
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
