"""The ranking's ceiling (session 32): ``kept_areas(try_first=…)`` tries one candidate first, and
``first_place`` asks whether any candidate tried first makes the run useful."""

from __future__ import annotations

import pytest
import torch

from somtorch.tasks.context import MapContext
from somtorch.tasks.detect import first_place, kept_areas
from somtorch.tasks.objects import AreaConfig, select_areas

from .toys import flat_segments

H, W = 60, 120
DEPTH = {0: 10.0, 1: 30.0, 2: 40.0}


def _two_blocks():
    """A far background (0, d 10), a small block (1, d 30) and a large nearer one (2, d 40) whose box
    alone holds 38 % of the view: ranked first, it leaves no room in the keep budget for the other."""
    labels = torch.zeros(H, W, dtype=torch.long)
    labels[20:40, 10:25] = 1
    labels[5:55, 60:115] = 2
    cfg = AreaConfig()
    disp, stats, areas = flat_segments(labels, DEPTH, cfg)
    ctx = MapContext.build(disp, torch.ones(H, W, dtype=torch.bool), labels >= 0, None, cfg)
    return labels, stats, areas, ctx, cfg


def test_a_candidate_tried_first_leads_and_the_natural_first_changes_nothing():
    labels, stats, areas, ctx, cfg = _two_blocks()
    assert [a.neurons for a in select_areas(areas, stats, cfg)][:2] == [[2], [1]]
    natural = kept_areas(areas, stats, labels, cfg, ctx)
    assert [a.neurons for a in natural] == [[2]]  # the small block no longer fits the budget
    same = kept_areas(areas, stats, labels, cfg, ctx, try_first=[2])
    assert [(a.neurons, a.box, a.rank) for a in same] == [(a.neurons, a.box, a.rank) for a in natural]
    trace = []
    led = kept_areas(areas, stats, labels, cfg, ctx, try_first=[1], trace=trace)
    assert [a.neurons for a in led] == [[1]] and led[0].box == (10, 20, 24, 39) and led[0].rank == 0
    assert [c.area.neurons for c in trace][:2] == [[1], [2]]
    assert trace[1].verdict.startswith("skipped: the kept boxes would hold")
    with pytest.raises(ValueError, match="no candidate area has these neurons"):
        kept_areas(areas, stats, labels, cfg, ctx, try_first=[7])


def test_first_place_tries_the_candidates_in_rank_order_until_one_is_useful():
    labels, stats, areas, ctx, cfg = _two_blocks()
    ranks = [a.rank for a in areas]
    seen: list[list[list[int]]] = []

    def small_block(kept) -> bool:
        seen.append([a.neurons for a in kept])
        return seen[-1] == [[1]]

    assert first_place(areas, stats, labels, cfg, ctx, small_block)
    assert seen == [[[2]], [[1]]]  # the step's own choice first, then the next candidate leads
    assert [a.rank for a in areas] == ranks  # the areas given are not touched
    seen.clear()
    assert not first_place(areas, stats, labels, cfg, ctx, lambda kept: seen.append(kept) is not None)
    assert len(seen) == 2  # every candidate tried (the background lies behind: no candidate)
    # the paper's rule keeps its one nearest area: nothing to reorder
    assert first_place(areas, stats, labels, AreaConfig(rule="paper"), ctx,
                       lambda kept: [a.neurons for a in kept] == [[2]])


def _members(scene, cfg):
    """The object step's inputs of every member of one run of ``cfg`` on ``scene``, as
    :func:`somtorch.pipeline.detect` builds them: (areas, stats, labels, ctx, object config)."""
    from somtorch.pipeline import find_objects, object_setup, on_support, prepare, read_map, segment_runs

    scene, _, sigma = read_map(scene, cfg)
    _, ground, usable, feats, train = prepare(scene, cfg, sigma=sigma)
    seg = next(segment_runs(feats, train, on_support(scene, ground, cfg.features)[0], usable, cfg))
    setup = object_setup(scene, seg.labels, ground, cfg)
    st, ctx = setup.stride, setup.ctx
    labels = seg.labels[:, ::st, ::st].contiguous()
    for e in range(labels.shape[0]):
        found = find_objects(labels[e], seg.ref_disparity[e], seg.grid_d2, ctx, setup.ocfg)
        yield found.areas, found.stats, labels[e], ctx, setup.ocfg


@pytest.mark.parametrize("which, merge", [("motorcycle", 0.75), ("motorcycle", 0.0), ("floor", 0.75)])
def test_the_memo_of_the_tries_changes_nothing(tmp_path, which, merge):
    # first_place shares one memo between its tries (session 42: the ceiling about a fifth faster): every
    # candidate tried first keeps the same areas, field for field, with and without it — on the
    # contrast rule's map (Motorcycle, with and without merge) and on a support-verified floor
    from dataclasses import replace

    from somtorch.config import PipelineConfig
    from somtorch.disparity import load_scene
    from somtorch.synth import generate_frame, write_frame
    from somtorch.tasks.detect import salient_order, standing_areas

    if which == "motorcycle":
        scene = load_scene("motorcycle")
    else:
        scene = load_scene(write_frame(generate_frame("floor", 1, "middlebury", scale=0.5), tmp_path / "f"))
    cfg = PipelineConfig(ensemble=3, consensus=1)
    cfg = replace(cfg, objects=replace(cfg.objects, merge=merge))  # 0: merge_adjacent returns the area itself
    tries = 0
    on_support = []
    for areas, stats, labels, ctx, ocfg in _members(scene, cfg):
        standing = [replace(a) for a in standing_areas(areas, labels, stats, ctx)]
        on_support.append(ctx.islands is not None)
        memo: dict = {}
        for a in salient_order(standing, ocfg, on_support=ctx.islands is not None):
            plain = kept_areas([replace(b) for b in standing], stats, labels, ocfg, ctx, try_first=a.neurons)
            shared = kept_areas(standing, stats, labels, ocfg, ctx, try_first=a.neurons, memo=memo)
            assert shared == plain, a.neurons
            tries += 1
        assert any(k[0] == "parts" for k in memo)
    assert tries >= 6
    assert all(on_support) == (which == "floor")
