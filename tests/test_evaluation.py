"""``somtorch.evaluation.selection_ceiling``: a perfect choice among the object step's areas, scored
in O(1) per box, must agree with the pipeline's own scoring of that box alone."""

from __future__ import annotations

import pytest
import torch

from somtorch.evaluation import selection_ceiling
from somtorch.pipeline import MemberResult, PipelineConfig, run_pipeline
from somtorch.tasks.objects import ObjectArea
from somtorch.tasks.reduction import reduce_map
from somtorch.tasks.scoring import optimal_reduction, score_reduction


@pytest.fixture(scope="module")
def boxes():
    """A box in front of a wall, a smaller one beside it, and a strip along the bottom at the main
    box's disparity (what chains a Middlebury table's objects into one area)."""
    from somtorch.disparity.scene import scene_from_arrays

    g = torch.Generator().manual_seed(3)
    d = 10.0 + 0.2 * torch.rand(90, 120, generator=g)
    objects = torch.zeros(90, 120, dtype=torch.long)
    d[30:70, 20:55] = 30.0
    objects[30:70, 20:55] = 1
    d[20:45, 80:100] = 24.0
    objects[20:45, 80:100] = 2
    d[82:, :] = 30.5
    return scene_from_arrays(d, torch.ones(90, 120, dtype=torch.bool), objects=objects, name="boxes")


def test_selection_ceiling_counts_the_runs_with_a_useful_single_box(boxes):
    cfg = PipelineConfig(ensemble=6)
    res = run_pipeline(boxes, cfg, metrics=True)
    obj, valid, r = boxes.main_object_mask, boxes.valid, cfg.reduction
    x_opt = optimal_reduction(obj, valid)
    tol = dict(tolerance_px=r.tolerance_px, tolerance_frac=r.tolerance_frac, tolerance_image=r.tolerance_image)

    def useful(box) -> bool:  # the slow way: a reduced map of that box alone, scored as a run
        return score_reduction(reduce_map([box], valid, **tol), obj, valid, x_opt=x_opt).useful_hit

    want = sum(any(useful(a.box) for a in list(m.kept) + list(m.areas)) for m in res.members)
    assert selection_ceiling(res.members, obj, valid, x_opt, **tol) == want
    assert want > 0  # the main box is among the candidates: the equality above is not 0 == 0
    # at least the runs that were useful with a single kept box, at most all
    singles = sum(len(m.kept) == 1 and m.score.useful_hit for m in res.members)
    assert singles <= want <= len(res.members)
    # a member whose only area is the whole map is never a useful box (x_opt is far above 0)
    h, w = valid.shape
    everything = ObjectArea([0], int(valid.sum()), (0, 0, w - 1, h - 1), 0.0, 0.0, 1.0)
    whole = MemberResult(0, [], [everything], res.members[0].reduction, None, res.members[0].stats)
    assert selection_ceiling([whole], obj, valid, x_opt, **tol) == 0
    # an empty object cannot be scored: no run counts
    assert selection_ceiling(res.members, torch.zeros_like(obj), valid, x_opt, **tol) == 0
