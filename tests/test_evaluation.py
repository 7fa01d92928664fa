"""``somtorch.evaluation.selection_ceiling``: a perfect choice among the object step's areas, scored
in O(1) per box, must agree with the pipeline's own scoring of that box alone; ``selection_gap``:
why the runs it counts missed."""

from __future__ import annotations

from dataclasses import replace

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


@pytest.fixture(scope="module")
def scored(boxes):
    """Six runs on ``boxes`` and what scoring them needs: ``(result, object, valid, x_opt, tolerances)``."""
    cfg = PipelineConfig(ensemble=6)
    res = run_pipeline(boxes, cfg, metrics=True)
    obj, valid, r = boxes.main_object_mask, boxes.valid, cfg.reduction
    tol = dict(tolerance_px=r.tolerance_px, tolerance_frac=r.tolerance_frac, tolerance_image=r.tolerance_image)
    return res, obj, valid, optimal_reduction(obj, valid), tol


def test_selection_ceiling_counts_the_runs_with_a_useful_single_box(scored):
    res, obj, valid, x_opt, tol = scored

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


def test_single_box_hit_is_true_when_one_of_a_baseline_s_boxes_alone_is_useful(scored, boxes):
    from somtorch.evaluation import single_box_hit
    from somtorch.tasks.baselines.plane_components import plane_components_boxes

    _, obj, valid, x_opt, tol = scored

    def useful(box) -> bool:  # the slow way, as above
        return score_reduction(reduce_map([box], valid, **tol), obj, valid, x_opt=x_opt).useful_hit

    h, w = valid.shape
    main, small, whole = (20, 30, 54, 69), (80, 20, 99, 44), (0, 0, w - 1, h - 1)
    assert useful(main) and not useful(small) and not useful(whole)
    assert single_box_hit([small, main], obj, valid, x_opt, **tol)  # the second of two counts
    assert not single_box_hit([small, whole], obj, valid, x_opt, **tol)
    assert not single_box_hit([], obj, valid, x_opt, **tol)
    # the union of two boxes may be useful where neither alone is: one box must do it on its own
    halves = [(20, 30, 54, 49), (20, 50, 54, 69)]
    assert not any(useful(b) for b in halves) and useful_union(halves, valid, obj, x_opt, tol)
    assert not single_box_hit(halves, obj, valid, x_opt, **tol)
    # the baseline's ranked components on this scene, every one tried, agree with the slow way
    found = [o.box for o in plane_components_boxes(boxes.disparity, boxes.valid)]
    assert found and single_box_hit(found, obj, valid, x_opt, **tol) == any(useful(b) for b in found)


def useful_union(boxes_, valid, obj, x_opt, tol) -> bool:
    return score_reduction(reduce_map(boxes_, valid, **tol), obj, valid, x_opt=x_opt).useful_hit


def test_grouping_ceiling_counts_the_runs_whose_segments_on_the_object_make_a_useful_box(scored, boxes):
    from somtorch.evaluation import grouping_ceiling

    res, obj, valid, x_opt, tol = scored
    h, w = valid.shape

    def useful(box) -> bool:  # the slow way, as above
        return score_reduction(reduce_map([box], valid, **tol), obj, valid, x_opt=x_opt).useful_hit

    def slow(lab) -> bool:  # the segments with more than half their pixels on the object, by hand
        keep = [k for k in range(int(lab.max()) + 1)
                if 2 * int(((lab == k) & obj).sum()) > int((lab == k).sum())]
        on = torch.isin(lab, torch.tensor(keep, dtype=lab.dtype)) if keep else torch.zeros_like(valid)
        ys, xs = on.nonzero(as_tuple=True)
        return bool(len(ys)) and useful((int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())))

    assert grouping_ceiling(res.labels, obj, valid, x_opt, **tol) == sum(slow(lab) for lab in res.labels)
    # with the members, a run counts where one of its areas or the oracle's grouping is useful
    areas = [any(useful(a.box) for a in list(m.kept) + list(m.areas)) for m in res.members]
    want = sum(a or slow(lab) for a, lab in zip(areas, res.labels))
    assert grouping_ceiling(res.labels, obj, valid, x_opt, members=res.members, **tol) == want
    assert want >= selection_ceiling(res.members, obj, valid, x_opt, **tol)
    with pytest.raises(ValueError, match="2 members for 6 label maps"):
        grouping_ceiling(res.labels, obj, valid, x_opt, members=res.members[:2], **tol)
    # hand-made label maps: the object split into two segments that lie on it is a perfect grouping
    split = torch.zeros(h, w, dtype=torch.long)
    split[30:50, 20:55], split[50:70, 20:55] = 1, 2
    # one segment straddling the object and as much wall beside it: no grouping of whole segments
    straddle = torch.zeros(h, w, dtype=torch.long)
    straddle[30:70, 20:90] = 1
    # the object's pixels without a segment (the ground cut, say) are not a grouping either
    unsegmented = torch.where(obj, -1, 0)
    maps = torch.stack([split, straddle, unsegmented])
    assert [grouping_ceiling(m[None], obj, valid, x_opt, **tol) for m in maps] == [1, 0, 0]
    assert grouping_ceiling(maps, obj, valid, x_opt, **tol) == 1
    assert grouping_ceiling(maps, torch.zeros_like(obj), valid, x_opt, **tol) == 0  # no object: nothing


def test_selection_gap_says_what_became_of_the_useful_area_of_each_missed_run(scored):
    from somtorch.evaluation import GAP_REASONS, selection_gap
    from somtorch.tasks.detect import Candidate

    res, obj, valid, x_opt, tol = scored
    # the counts sum to the ceiling's runs that still missed
    gap = selection_gap(res.members, obj, valid, x_opt, **tol)
    assert list(gap) == list(GAP_REASONS)
    useful_in_ceiling = sum(m.score.useful_hit and selection_ceiling([m], obj, valid, x_opt, **tol) == 1
                            for m in res.members)
    assert sum(gap.values()) == selection_ceiling(res.members, obj, valid, x_opt, **tol) - useful_in_ceiling

    h, w = valid.shape
    main = ObjectArea([1], 1400, (20, 30, 54, 69), 30.0, 20.0, 0.13)  # the main box: useful alone
    strip = ObjectArea([2], 4800, (60, 0, w - 1, h - 1), 24.0, 14.0, 0.44)  # the right half: the other box, wall
    stats = res.members[0].stats

    def member(kept, candidates, areas=None):
        red = reduce_map([a.box for a in kept], valid, **tol)
        score = score_reduction(red, obj, valid, x_opt=x_opt)
        return MemberResult(0, areas if areas is not None else [main, strip], kept, red, score, stats,
                            candidates=candidates)

    both = member([main, strip], [Candidate(main, 2.0, 0, "kept"), Candidate(strip, 1.0, 1, "kept")])
    assert not both.score.useful_hit  # the second box costs the reduction
    over = "skipped: the kept boxes would hold 50 % of the valid pixels > keep_budget 35 %"
    budget = member([strip], [Candidate(strip, 2.0, 0, "kept"), Candidate(main, 1.0, 1, over, "skipped")])
    refused = member([strip], [Candidate(strip, 2.0, 0, "kept"),
                               Candidate(main, 1.0, 1, "refused: purity 0.10 < min_purity 0.15", "refused")])
    unranked = member([strip], [Candidate(strip, 2.0, 0, "kept")])
    hit = member([main], [Candidate(main, 2.0, 0, "kept")])
    assert hit.score.useful_hit
    got = selection_gap([both, budget, refused, unranked, hit], obj, valid, x_opt, **tol)
    assert got == {**dict.fromkeys(GAP_REASONS, 0), "kept, with further boxes": 1, "over the keep budget": 1,
                   "refused by a check": 1, "below the max_areas best": 1}
    hidden = member([strip], [Candidate(strip, 2.0, 0, "kept")], areas=[replace(main, contrast=-1.0), strip])
    assert selection_gap([hidden], obj, valid, x_opt, **tol)["behind its surroundings"] == 1
    # without a useful area (the main box never found) the run is no part of the gap
    assert sum(selection_gap([member([strip], [], areas=[strip])], obj, valid, x_opt, **tol).values()) == 0
