"""segment_f1 against a pixel-by-pixel reference (invalid pixels, ties, empty maps)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch.evaluation import segment_f1


def _reference(labels: np.ndarray, obj: np.ndarray) -> tuple[float, float, float]:
    ok = labels >= 0
    chosen = set()
    for s in np.unique(labels[ok]):
        seg = ok & (labels == s)
        if 2 * (seg & obj).sum() > seg.sum():  # strictly more than half on the object
            chosen.add(int(s))
    sel = ok & np.isin(labels, list(chosen))
    tp = int((sel & obj).sum())
    p = tp / max(int(sel.sum()), 1)
    r = tp / max(int((ok & obj).sum()), 1)
    return p, r, (2 * p * r / (p + r) if p + r > 0 else 0.0)


@pytest.mark.parametrize("seed", range(8))
def test_segment_f1_matches_the_pixel_reference(seed):
    g = np.random.default_rng(seed)
    h, w, k = 23, 31, int(g.integers(1, 9))
    labels = g.integers(-1, k, (h, w))
    obj = g.random((h, w)) < g.random()
    if seed == 0:  # a segment of 4 pixels, exactly 2 on the object: a tie is not a majority
        labels[:] = -1
        labels[0, :4] = 0
        obj[:] = False
        obj[0, :2] = True
    assert segment_f1(torch.from_numpy(labels), torch.from_numpy(obj)) == _reference(labels, obj)


def test_segment_f1_of_a_map_without_valid_pixels_is_zero():
    labels = torch.full((4, 5), -1, dtype=torch.long)
    assert segment_f1(labels, torch.ones(4, 5, dtype=torch.bool)) == (0.0, 0.0, 0.0)
