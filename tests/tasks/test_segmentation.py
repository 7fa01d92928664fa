"""Tests of somtorch.tasks.segmentation: BMU label maps and their renderings."""

from __future__ import annotations

import pytest
import torch

from somtorch.disparity.features import make_features
from somtorch.tasks.segmentation import color_map, grey_map, segment


def _random_map(h: int = 23, w: int = 31, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    d = torch.rand(h, w, generator=g, dtype=torch.float64) * 40
    valid = torch.rand(h, w, generator=g) > 0.25
    return d, valid


def _brute_force_labels(weight: torch.Tensor, d: torch.Tensor, valid: torch.Tensor, feats) -> torch.Tensor:
    """(E, H, W): argmin over torch.cdist at every usable pixel, −1 elsewhere, by a plain loop."""
    e = weight.shape[0]
    h, w = d.shape
    out = torch.full((e, h, w), -1, dtype=torch.long)
    dist = torch.stack([torch.cdist(feats.x, weight[m]) for m in range(e)])  # (E, N, K)
    best = dist.argmin(-1)  # (E, N)
    for n, (y, x) in enumerate(feats.pixels.tolist()):
        out[:, y, x] = best[:, n]
    return out


@pytest.mark.parametrize("chunk_elements", [None, 7])
def test_segment_equals_brute_force_argmin_and_minus_one_elsewhere(chunk_elements):
    d, valid = _random_map()
    feats = make_features(d, valid, dtype=torch.float64)
    weight = torch.rand(3, 6, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)  # (E, K, D)
    kw = {} if chunk_elements is None else {"chunk_elements": chunk_elements}
    labels = segment(weight, feats.x, feats.pixels, feats.shape, **kw)
    assert labels.shape == (3, 23, 31) and labels.dtype == torch.long
    assert torch.equal(labels, _brute_force_labels(weight, d, valid, feats))
    assert bool((labels[:, ~valid] == -1).all())
    assert bool((labels[:, valid] >= 0).all()) and int(labels.max()) < 6


def test_segment_rejects_mismatched_inputs():
    d, valid = _random_map()
    feats = make_features(d, valid)
    weight = torch.rand(2, 5, 3)
    with pytest.raises(ValueError, match="x must have last dimension 3"):
        segment(weight, feats.x[:, :2], feats.pixels, feats.shape)
    with pytest.raises(ValueError, match="pixels has .* rows but x has"):
        segment(weight, feats.x, feats.pixels[:-1], feats.shape)
    with pytest.raises(ValueError, match="weight must have 3 dimensions"):
        segment(weight[0], feats.x, feats.pixels, feats.shape)


def test_grey_map_paints_each_segment_with_its_reference_disparity():
    labels = torch.tensor([[[0, 1, -1], [2, 2, 0]],
                           [[1, 1, 1], [-1, 0, 2]]])  # (E=2, H=2, W=3)
    ref = torch.tensor([[10.0, 20.0, 30.0], [5.0, 6.0, 7.0]])  # (E, K)
    g = grey_map(labels, ref)
    assert g.shape == labels.shape and g.is_floating_point()
    for e in range(2):
        for y in range(2):
            for x in range(3):
                k = int(labels[e, y, x])
                if k < 0:
                    assert torch.isnan(g[e, y, x])
                else:
                    assert float(g[e, y, x]) == float(ref[e, k])


def test_color_map_is_deterministic_per_seed_and_black_where_invalid():
    g = torch.Generator().manual_seed(5)
    labels = torch.randint(-1, 12, (2, 30, 40), generator=g)
    a = color_map(labels, 12, seed=3)
    b = color_map(labels, 12, seed=3)
    c = color_map(labels, 12, seed=4)
    assert a.shape == (2, 30, 40, 3) and a.dtype == torch.uint8
    assert torch.equal(a, b)
    assert not torch.equal(a, c)
    assert bool((a[labels < 0] == 0).all())
    assert bool((a[labels >= 0] >= 40).all())  # every segment colour is visibly non-black
    # one colour per label, the same in every member
    for k in range(12):
        cols = a[labels == k]
        assert bool((cols == cols[0]).all())
