"""Tests of somtorch.tasks.scoring (the paper's Tables 1 and 2), synthetic and on the shared scenes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch.disparity import load_scene
from somtorch.tasks.reduction import reduce_map
from somtorch.tasks.scoring import object_box, optimal_reduction, score_reduction

H, W = 50, 60


def _object() -> tuple[torch.Tensor, torch.Tensor]:
    """A 5 × 20 object (rows 10–14, cols 20–39) on an all-valid 50 × 60 map: 100 valid object pixels."""
    obj = torch.zeros(H, W, dtype=torch.bool)
    obj[10:15, 20:40] = True
    return obj, torch.ones(H, W, dtype=torch.bool)


def _score(boxes, obj, valid, **kw):
    return score_reduction(reduce_map(boxes, valid, tolerance_frac=0.0, tolerance_image=0.0), obj, valid, **kw)


def test_identified_thresholds_at_100_and_95_percent():
    obj, valid = _object()
    full = _score([(20, 10, 39, 14)], obj, valid)
    assert full.identified_fraction == 1.0 and full.identified_100 and full.identified_95
    s95 = _score([(20, 10, 38, 14)], obj, valid)  # 19 of 20 columns
    assert s95.identified_fraction == 0.95 and s95.identified_95 and not s95.identified_100
    s90 = _score([(20, 10, 37, 14)], obj, valid)
    assert s90.identified_fraction == pytest.approx(0.90) and not s90.identified_95
    none = _score([], obj, valid)
    assert none.identified_fraction == 0.0 and not none.identified_95


def test_identified_fraction_counts_only_object_pixels_with_a_valid_disparity():
    obj, valid = _object()
    valid[10:15, 30:40] = False  # the right half of the object has no disparity
    s = _score([(20, 10, 29, 14)], obj, valid)  # covers exactly the valid half
    assert s.identified_fraction == 1.0 and s.identified_100
    s = _score([(20, 10, 24, 14)], obj, valid)
    assert s.identified_fraction == pytest.approx(25 / 50)


def test_x_opt_is_the_reduction_of_the_exact_object_bbox_including_invalid_object_pixels():
    obj, valid = _object()
    obj[30, 5] = True  # a stray object pixel without disparity still widens the box
    valid[30, 5] = False
    valid[0:5, :] = False
    assert object_box(obj) == (5, 10, 39, 30)
    x_opt = optimal_reduction(obj, valid)
    in_box = int(valid[10:31, 5:40].sum())
    assert x_opt == pytest.approx(100 * (1 - in_box / int(valid.sum())))
    assert x_opt == reduce_map([(5, 10, 39, 30)], valid, tolerance_frac=0.0, tolerance_image=0.0).reduction_union
    assert _score([(0, 0, 1, 1)], obj, valid).x_opt == x_opt


def test_useful_hit_needs_95_percent_and_three_quarters_of_x_opt():
    obj, valid = _object()
    x_opt = optimal_reduction(obj, valid)  # 100 · (1 − 100/3000)
    cases = {
        "exact": [(20, 10, 39, 14)],  # 100 %, reduction = x_opt
        "95": [(20, 10, 38, 14)],  # 95 %, reduction > x_opt
        "whole image": [(0, 0, W - 1, H - 1)],  # 100 %, reduction 0
        "missed": [(0, 0, 9, 9)],  # 0 %
    }
    hits = {}
    for name, boxes in cases.items():
        s = _score(boxes, obj, valid)
        assert s.x_opt == pytest.approx(x_opt)
        assert s.useful_hit == (s.identified_95 and s.reduction_union >= 0.75 * s.x_opt)
        hits[name] = s.useful_hit
    assert hits == {"exact": True, "95": True, "whole image": False, "missed": False}
    # a box just large enough to reach exactly 0.75 · x_opt is still useful; one more row is not
    total = int(valid.sum())
    need_kept = total * (1 - 0.75 * x_opt / 100)  # kept pixels at the limit
    rows = int(need_kept // W)  # full-width rows, starting at row 10
    at_limit = _score([(0, 10, W - 1, 10 + rows - 1)], obj, valid)
    beyond = _score([(0, 10, W - 1, 10 + rows)], obj, valid)
    assert at_limit.identified_100 and at_limit.useful_hit
    assert beyond.identified_100 and not beyond.useful_hit


def test_useful_factor_is_a_parameter():
    obj, valid = _object()
    s = _score([(0, 0, W - 1, 20)], obj, valid, useful_factor=0.0)
    assert s.useful_hit  # any complete hit counts when nothing is asked of the reduction
    s = _score([(20, 10, 39, 14)], obj, valid, useful_factor=1.01)
    assert not s.useful_hit


def test_a_known_x_opt_is_used_as_given():
    obj, valid = _object()
    red = reduce_map([(5, 10, 39, 30)], valid, tolerance_frac=0.0, tolerance_image=0.0)
    computed = score_reduction(red, obj, valid)
    assert score_reduction(red, obj, valid, x_opt=computed.x_opt) == computed
    assert score_reduction(red, obj, valid, x_opt=99.0).x_opt == 99.0


def test_score_as_dict_has_every_field():
    obj, valid = _object()
    d = _score([(20, 10, 39, 14)], obj, valid).as_dict()
    assert set(d) == {"identified_fraction", "identified_100", "identified_95", "reduction_union",
                      "reduction_crops", "x_opt", "useful_hit"}


def test_scoring_rejects_an_object_without_valid_pixels_and_shape_mismatches():
    obj, valid = _object()
    red = reduce_map([(0, 0, 5, 5)], valid, tolerance_image=0.0)
    with pytest.raises(ValueError, match="no pixel with a valid disparity"):
        score_reduction(red, obj, valid & ~obj)
    with pytest.raises(ValueError, match="same shape"):
        score_reduction(red, obj[:-1], valid)
    with pytest.raises(TypeError, match="object_mask has dtype"):
        score_reduction(red, obj.long(), valid)
    with pytest.raises(ValueError, match="empty"):
        object_box(torch.zeros(3, 3, dtype=torch.bool))


# x_opt reported for the shared scenes (object id 1; bbox over all its pixels, counts over valid ones)
X_OPT = {
    "middlebury2014/Motorcycle_Q": 31.5,
    "kitti2015/devkit_demo": 63.5,
    "sceneflow_flyingthings3d/A-0032-0006": 39.7,
    "eth3d/terrace": 94.3,
    "oakd_stereodemo/toy": 89.9,
    "oakd_stereodemo/selfie": 33.4,
    "oakd_stereodemo/bedroom_chair": 79.0,
    "oakd_stereodemo/cycles": 92.5,
}


@pytest.mark.parametrize("scene_dir, expected", X_OPT.items(), ids=list(X_OPT))
def test_x_opt_of_the_shared_scenes(shared_data, scene_dir, expected):
    scene = load_scene(shared_data / scene_dir)
    obj = scene.object_mask(1)
    x_opt = optimal_reduction(obj, scene.valid)
    assert round(x_opt, 1) == expected and x_opt == pytest.approx(expected, abs=0.05)
    # the same figure by hand in numpy
    o, v = obj.numpy(), scene.valid.numpy()
    ys, xs = np.nonzero(o)
    kept = v[ys.min():ys.max() + 1, xs.min():xs.max() + 1].sum()
    assert x_opt == pytest.approx(100 * (1 - kept / v.sum()), abs=1e-9)
