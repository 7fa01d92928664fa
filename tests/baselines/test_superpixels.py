"""Superpixel baselines on the real embedded Motorcycle scene and on a synthetic depth step."""

from __future__ import annotations

import pytest
import torch

from somtorch.baselines import SUPERPIXELS, superpixel_labels
from somtorch.disparity import load_scene


@pytest.fixture(scope="module")
def scene():
    """scikit-image's Middlebury Motorcycle (500x741, ~7 % of the pixels without disparity)."""
    return load_scene("motorcycle")


@pytest.fixture(scope="module")
def labels(scene):
    """Both methods with their defaults, each run twice."""
    return {m: (superpixel_labels(scene.disparity, scene.valid, method=m),
                superpixel_labels(scene.disparity, scene.valid, method=m)) for m in SUPERPIXELS}


@pytest.mark.parametrize("method", SUPERPIXELS)
def test_real_scene_labels_are_valid_contiguous_and_deterministic(scene, labels, method):
    a, b = labels[method]
    assert a.shape == scene.disparity.shape and a.dtype == torch.long
    assert torch.equal(a, b)
    assert bool((a == -1).eq(~scene.valid).all())  # -1 exactly on the invalid pixels
    k = int(a.max()) + 1
    assert torch.equal(torch.unique(a[scene.valid]), torch.arange(k))  # 0 … K−1, all used
    assert k > 1


def test_slic_segment_count_is_near_n_segments(scene, labels):
    k = int(labels["slic"][0].max()) + 1
    assert 32 <= k <= 128  # n_segments=64 is a target, not a guarantee (52 with the defaults)
    k16 = int(superpixel_labels(scene.disparity, scene.valid, n_segments=16).max()) + 1
    assert 8 <= k16 <= 32 and k16 < k


def test_felzenszwalb_count_is_bounded_by_min_size(scene, labels):
    k = int(labels["felzenszwalb"][0].max()) + 1
    h, w = scene.disparity.shape
    assert 10 < k <= h * w // 50  # every segment has >= min_size pixels before masking
    coarser = superpixel_labels(scene.disparity, scene.valid, method="felzenszwalb", scale=1000.0,
                                min_size=500)
    assert int(coarser.max()) + 1 < k


@pytest.mark.parametrize("method", SUPERPIXELS)
def test_segments_do_not_cross_a_depth_step(method):
    d = torch.ones(40, 60)
    d[:, 30:] = 5.0  # two fronto-parallel planes
    d += 0.01 * torch.rand(40, 60, generator=torch.Generator().manual_seed(0))
    valid = torch.ones(40, 60, dtype=torch.bool)
    valid[:3, :5] = False
    lab = superpixel_labels(d, valid, method=method, n_segments=6, min_size=20)
    left, right = set(lab[:, :30][valid[:, :30]].tolist()), set(lab[:, 30:][valid[:, 30:]].tolist())
    assert left and right and not left & right
    assert bool((lab[:3, :5] == -1).all())


def test_values_at_invalid_pixels_are_ignored(scene):
    d = scene.disparity.clone()
    d[~scene.valid] = float("nan")
    for m in SUPERPIXELS:
        got = superpixel_labels(d, scene.valid, method=m, n_segments=16, scale=1000.0, min_size=500)
        want = superpixel_labels(scene.disparity, scene.valid, method=m, n_segments=16, scale=1000.0,
                                 min_size=500)
        assert torch.equal(got, want)


D, V = torch.rand(8, 9), torch.ones(8, 9, dtype=torch.bool)
BAD = [
    (dict(method="watershed"), ValueError,
     "method='watershed' is not known; valid names: felzenszwalb, slic"),
    (dict(disparity=D.numpy()), TypeError, "disparity must be a torch.Tensor"),
    (dict(disparity=D[None]), ValueError, "disparity must have 2 dimensions"),
    (dict(disparity=D.long()), TypeError, "disparity must be a floating-point"),
    (dict(valid=V.float()), TypeError, "valid has dtype torch.float32 but torch.bool"),
    (dict(valid=V[:, :5]), ValueError, "valid must have the shape of disparity"),
    (dict(valid=torch.zeros_like(V)), ValueError, "valid has no True pixel"),
    (dict(disparity=torch.full((8, 9), float("nan"))), ValueError, "disparity holds 72 NaN/inf"),
    (dict(n_segments=0), ValueError, "n_segments must be a positive integer"),
    (dict(compactness=0.0), ValueError, "compactness must be finite and > 0"),
    (dict(scale=-1.0), ValueError, "scale must be finite and > 0"),
    (dict(sigma=-0.5), ValueError, "sigma must be finite and >= 0"),
    (dict(min_size=-1), ValueError, "min_size must be >= 0"),
    (dict(min_size=2.5), TypeError, "min_size must be an int"),
]


@pytest.mark.parametrize("kwargs,err,msg", BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_input_names_the_argument(kwargs, err, msg):
    args = dict(disparity=D, valid=V)
    args.update(kwargs)
    with pytest.raises(err, match=msg):
        superpixel_labels(args.pop("disparity"), args.pop("valid"), **args)
