"""Tests of somtorch.disparity.filters.median_filter (the masked median the pipeline reads a map through)."""

from __future__ import annotations

import cv2
import pytest
import torch

from somtorch.disparity.filters import median_filter


def _noisy_plane(h: int = 120, w: int = 160, sigma: float = 0.5,
                 seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32),
                          indexing="ij")
    plane = 20.0 + 0.05 * x + 0.1 * y
    return plane, plane + sigma * torch.randn(h, w, generator=g)


@pytest.mark.parametrize("size", [3, 5])
def test_a_fully_valid_map_gets_opencvs_median_inside_the_border(size):
    d = torch.rand(90, 130, generator=torch.Generator().manual_seed(1)) * 60
    out = median_filter(d, torch.ones_like(d, dtype=torch.bool), size, rows=17)  # blocks of 17 rows
    ref = torch.from_numpy(cv2.medianBlur(d.numpy(), size))
    r = size // 2
    assert torch.equal(out[r:-r, r:-r], ref[r:-r, r:-r])
    assert out.dtype == d.dtype


def test_invalid_pixels_are_never_read_and_keep_their_value():
    _, d = _noisy_plane()
    valid = torch.ones_like(d, dtype=torch.bool)
    valid[30:60, 40:90] = False
    valid[::7, ::5] = False
    out = median_filter(d, valid, 5)
    changed = d.clone()
    changed[~valid] = 1e6  # whatever an invalid pixel holds
    assert torch.equal(median_filter(changed, valid, 5)[valid], out[valid])
    assert torch.equal(out[~valid], d[~valid])
    assert not bool(out.isnan().any())


def test_noise_goes_and_a_depth_edge_stays():
    plane, d = _noisy_plane(sigma=0.5)
    valid = torch.ones_like(d, dtype=torch.bool)
    before = float((d - plane).std())
    after = float((median_filter(d, valid, 5) - plane)[5:-5, 5:-5].std())
    assert after < 0.5 * before  # a 5x5 median keeps about a quarter of Gaussian noise's spread
    step = torch.full((40, 60), 10.0)
    step[:, 30:] = 40.0  # a straight depth edge (a corner is rounded off: the window's majority)
    assert torch.equal(median_filter(step, torch.ones_like(step, dtype=torch.bool), 5), step)


def test_size_one_is_a_copy_and_an_even_size_is_refused():
    _, d = _noisy_plane()
    valid = torch.ones_like(d, dtype=torch.bool)
    out = median_filter(d, valid, 1)
    assert torch.equal(out, d) and out is not d
    with pytest.raises(ValueError, match="odd"):
        median_filter(d, valid, 4)


@pytest.mark.parametrize("size", [3, 5])
def test_median_noise_is_the_error_the_median_leaves_of_gaussian_noise(size):
    """``median_noise``: the median of size² Gaussian samples errs by σ·√(π/2)/size."""
    from somtorch.disparity.filters import median_filter, median_noise

    noise = 1.5 * torch.randn(300, 300, generator=torch.Generator().manual_seed(size))
    out = median_filter(10.0 + noise, torch.ones(300, 300, dtype=torch.bool), size)
    err = float((out - 10.0)[size:-size, size:-size].std())
    assert median_noise(1.5, size) == pytest.approx(err, rel=0.06)
    assert median_noise(1.5, 1) == 1.5 and median_noise(1.5, 0) == 1.5
