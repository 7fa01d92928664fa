"""Several maps per run (PipelineConfig.consensus): the medoid of the maps' reduced maps is kept."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from somtorch.consensus import SEED_STRIDE, agreement, medoid, shifted
from somtorch.disparity import load_scene
from somtorch.outputs import summarize
from somtorch.pipeline import PipelineConfig, SOMConfig, TrainConfig, run_pipeline

E, K, SEED = 4, 3, 7


def _cfg(**kw) -> PipelineConfig:
    kw = {"ensemble": E, "seed": SEED, "consensus": 1, **kw}
    return PipelineConfig(som=SOMConfig(rows=4, cols=7), train=TrainConfig(epochs=3), **kw)


@pytest.fixture(scope="module")
def scene(shared_data):
    """A real frame with a labelled object whose maps disagree from seed to seed (ETH3D terrace)."""
    return load_scene(shared_data / "eth3d" / "terrace")


@pytest.fixture(scope="module")
def runs(scene):
    """The consensus run, and each of its maps run alone (one map per run, the map's own seeds)."""
    cfg = _cfg(consensus=K)
    return run_pipeline(scene, cfg), [run_pipeline(scene, shifted(_cfg(), k)) for k in range(K)]


def _box_masks(boxes: list[tuple[int, int, int, int]], h: int = 6, w: int = 8) -> torch.Tensor:
    m = torch.zeros(len(boxes), h, w, dtype=torch.bool)
    for i, (x0, y0, x1, y1) in enumerate(boxes):
        m[i, y0:y1 + 1, x0:x1 + 1] = True
    return m


def test_the_medoid_follows_the_majority_and_ties_go_to_the_first():
    masks = _box_masks([(0, 0, 3, 3), (4, 2, 7, 5), (4, 2, 7, 4)])  # two maps agree, one kept elsewhere
    iou = agreement(masks)
    assert torch.equal(iou, iou.T) and torch.allclose(iou.diagonal(), torch.ones(3, dtype=iou.dtype))
    assert iou[0, 1] == 0 and iou[1, 2] == pytest.approx(12 / 16)
    k, agree = medoid(masks)
    assert k == 1 and agree == pytest.approx((0 + 12 / 16) / 2)  # 1 and 2 tie on 0.75: the first
    assert medoid(_box_masks([(0, 0, 3, 3), (4, 2, 7, 5)])) == (0, 0.0)  # two that disagree: the first
    assert medoid(masks[:1]) == (0, 1.0)
    assert medoid(torch.zeros(3, 4, 4, dtype=torch.bool)) == (0, 1.0)  # nothing kept, alike


@pytest.mark.parametrize("packed", ["bitwise_count", "byte table"])
def test_the_packed_pixel_counts_give_the_float_products_ious(packed, monkeypatch):
    # the IoUs by a population count of the packed masks equal those of the float64 product of
    # 0/1 masks to the bit, on sizes that do and do not fill a 64-pixel word; with numpy < 2 (no
    # bitwise_count) a byte table counts the bits
    import numpy as np

    from somtorch.consensus import pair_counts

    if packed == "byte table":
        monkeypatch.delattr(np, "bitwise_count", raising=False)
    g = torch.Generator().manual_seed(1)
    for shape in [(5, 72, 126), (3, 7, 9), (1, 1), (4, 0), (2, 64), (3, 65)]:
        masks = torch.rand(*shape, generator=g) > 0.4
        if shape[0] > 1:
            masks[1] = False  # an empty mask: agrees fully with another empty one only
        flat = masks.reshape(shape[0], -1)
        want = torch.stack([(flat[i] & flat).sum(1) for i in range(shape[0])])
        assert torch.equal(pair_counts(masks), want)
        m = flat.double()
        inter, area = m @ m.T, m.sum(1)
        union = area[:, None] + area[None, :] - inter
        want_iou = torch.where(union > 0, inter / union.clamp(min=1), torch.ones_like(inter))
        assert torch.equal(agreement(masks), want_iou)
    assert torch.equal(agreement(masks.double()), agreement(masks))  # a non-boolean mask: the float product


def test_map_seeds_are_distinct_32_bit_seeds_and_map_0_is_the_run_s_own():
    cfg = _cfg()
    assert shifted(cfg, 0) is cfg
    assert shifted(cfg, 1).seed == SEED + SEED_STRIDE
    assert [shifted(replace(cfg, seed=2 ** 32 - 1), k).seed for k in range(3)] == [
        2 ** 32 - 1, SEED_STRIDE - 1, (2 * SEED_STRIDE - 1) % 2 ** 32]  # 32-bit: torch's CPU generator
    # the module's claim: the first eight maps of runs seeded below 2**20 never share a seed
    import numpy as np

    runs, maps = np.arange(2 ** 20, dtype=np.uint64), np.arange(8, dtype=np.uint64)
    every = (runs[:, None] + maps * SEED_STRIDE) % 2 ** 32
    assert (np.diff(np.sort(every.ravel())) > 0).all()


def test_each_run_keeps_the_medoid_of_its_maps(scene, runs):
    result, alone = runs
    assert len(result.members) == E and result.labels.shape == (E, scene.height, scene.width)
    picked = set()
    for e, m in enumerate(result.members):
        masks = torch.stack([a.members[e].reduction.mask for a in alone])
        k, agree = medoid(masks)
        picked.add(k)
        want = alone[k].members[e]
        assert (m.consensus_map, m.seed) == (k, SEED + e) and m.agreement == pytest.approx(agree)
        assert m.maps_useful == sum(a.members[e].score.useful_hit for a in alone)  # the maps' own hits
        assert result.som.seeds[e] == shifted(_cfg(), k).seed + e  # the kept map's own seed
        assert torch.equal(m.reduction.mask, want.reduction.mask)
        assert [a.box for a in m.kept] == [a.box for a in want.kept]
        assert m.score.useful_hit == want.score.useful_hit
        assert torch.equal(result.labels[e], alone[k].labels[e])
        assert torch.equal(result.som.weight[e], alone[k].som.weight[e])
        assert result.quantization_error[e] == pytest.approx(float(alone[k].quantization_error[e]))
    assert picked != {0}, "no run kept another map than its first: the test no longer shows a choice"


def test_the_kept_map_alone_reproduces_its_run(scene, runs):
    result, _ = runs
    e, m = next((e, m) for e, m in enumerate(result.members) if m.consensus_map > 0)
    solo = run_pipeline(scene, _cfg(ensemble=1, seed=result.som.seeds[e], consensus=1)).members[0]
    assert torch.equal(solo.reduction.mask, m.reduction.mask)
    # ... and run e of the ensemble is the run seeded seed + e alone, consensus and all
    alone = run_pipeline(scene, _cfg(ensemble=1, seed=SEED + e, consensus=K)).members[0]
    assert torch.equal(alone.reduction.mask, m.reduction.mask) and alone.consensus_map == m.consensus_map


def test_one_map_per_run_is_the_plain_pipeline(scene, runs):
    _, alone = runs
    plain = alone[0]
    assert [m.seed for m in plain.members] == [SEED + e for e in range(E)]
    assert all(m.consensus_map == 0 and m.agreement is None and m.maps_useful is None for m in plain.members)


def test_metrics_json_says_which_map_each_run_kept(scene, runs):
    result, alone = runs
    members = summarize(scene, result)["members"]
    assert [m["consensus_map"] for m in members] == [m.consensus_map for m in result.members]
    assert all(0.0 <= m["agreement"] <= 1.0 for m in members)
    assert [m["maps_useful"] for m in members] == [m.maps_useful for m in result.members]
    assert all(m["agreement"] is None for m in summarize(scene, alone[0])["members"])


def test_a_deterministic_method_trains_one_map():
    scene = load_scene("motorcycle")
    cfg = PipelineConfig(method="slic", som=SOMConfig(rows=3, cols=4), ensemble=2, consensus=1)
    one, three = run_pipeline(scene, cfg), run_pipeline(scene, replace(cfg, consensus=3))
    assert torch.equal(one.labels, three.labels)
    assert [(m.consensus_map, m.agreement) for m in three.members] == [(0, None)]


def test_a_bad_consensus_is_refused():
    with pytest.raises(ValueError, match="consensus"):
        run_pipeline(load_scene("motorcycle"), _cfg(consensus=0))


def test_the_summary_picture_names_the_kept_map(scene, runs):
    import matplotlib.pyplot as plt

    from somtorch.viz import draw_summary

    result, alone = runs
    e = next(e for e, m in enumerate(result.members) if m.consensus_map > 0)
    m = result.members[e]
    fig = draw_summary(scene, result, e)
    assert f"map {m.consensus_map} kept (agreement {m.agreement:.2f})" in fig._suptitle.get_text()
    plt.close(fig)
    fig = draw_summary(scene, alone[0], 0)
    assert "kept (agreement" not in fig._suptitle.get_text()
    plt.close(fig)


@pytest.mark.parametrize("maps", [1, K])
def test_maps_held_as_int16_give_the_same_runs_as_int64_maps(scene, maps):
    """What validate's cache holds (:func:`~somtorch.consensus.compact`): the object step widens only
    the grid it reads, and the kept labels come back as int64 either way."""
    from somtorch.consensus import compact
    from somtorch.pipeline import detect_runs, on_support, prepare, read_map, segment_runs

    cfg = _cfg(consensus=maps)
    read, _, sigma = read_map(scene, cfg)
    _, ground, usable, feats, train = prepare(read, cfg, sigma=sigma)
    wide = list(segment_runs(feats, train, on_support(read, ground, cfg.features)[0], usable, cfg))
    small = [compact(s) for s in wide]
    assert {s.labels.dtype for s in small} == {torch.int16} and {s.labels.dtype for s in wide} == {torch.long}
    seg_w, runs_w = detect_runs(read, wide, ground, cfg)
    seg_s, runs_s = detect_runs(read, small, ground, cfg)
    assert seg_s.labels.dtype == torch.long and torch.equal(seg_s.labels, seg_w.labels)
    for a, b in zip(runs_s, runs_w, strict=True):
        assert [x.box for x in a.kept] == [x.box for x in b.kept] and a.consensus_map == b.consensus_map
        assert torch.equal(a.reduction.mask, b.reduction.mask) and a.score == b.score


def test_a_run_whose_maps_disagree_is_flagged(scene, runs, caplog):
    """A member whose kept map shares less than half its pixels with its other maps (``agreement`` under
    ``LOW_AGREEMENT``) gets a warning line naming it; inside ``fallback_summary`` it is counted for the
    one line at the end. Members of the real consensus run, their agreement set on either side."""
    import logging

    from somtorch.fallbacks import LOW_AGREEMENT, fallback_summary, warn_fallbacks

    result, _ = runs
    members = [replace(m, agreement=LOW_AGREEMENT - 0.2 if e in (1, 3) else LOW_AGREEMENT)
               for e, m in enumerate(result.members)]
    with caplog.at_level(logging.WARNING, logger="somtorch.pipeline"):
        warn_fallbacks(scene.name, members)
        lines = [r.getMessage() for r in caplog.records if "disagree" in r.getMessage()]
        assert lines == [f"scene {scene.name}: member(s) [1, 3]: the run's maps disagree on what to keep "
                         f"(agreement under {LOW_AGREEMENT:g}): its answer depends on the seed"]
        caplog.clear()
        warn_fallbacks(scene.name, [replace(m, agreement=None) for m in members])  # one map a run: no reading
        assert not any("disagree" in r.getMessage() for r in caplog.records)
        caplog.clear()
        with fallback_summary(scene.name) as counts:
            warn_fallbacks(scene.name, members)
            warn_fallbacks(scene.name, members[:2])
    assert counts[2:] == [E + 2, 3]
    assert len(caplog.records) == 1 and "3 with maps that disagree" in caplog.records[0].getMessage()
