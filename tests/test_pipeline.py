"""Tests of somtorch.pipeline.run_pipeline on the embedded Motorcycle scene and a shared scene."""

from __future__ import annotations

import math

import pytest
import torch

from somtorch.disparity.scene import load_scene
from somtorch.pipeline import PipelineConfig, SOMConfig, TrainConfig, run_pipeline
from somtorch.tasks.reduction import reduce_map
from somtorch.tasks.scoring import Score

E, SEED, EPOCHS = 3, 5, 3
STAGES = {"features", "train", "segment", "objects", "reduction"}


def _cfg(ensemble: int = E, seed: int = SEED) -> PipelineConfig:
    return PipelineConfig(som=SOMConfig(rows=4, cols=7), train=TrainConfig(mode="batch", epochs=EPOCHS),
                          ensemble=ensemble, seed=seed)


@pytest.fixture(scope="module")
def motorcycle():
    return load_scene("motorcycle")


@pytest.fixture(scope="module")
def result(motorcycle):
    return run_pipeline(motorcycle, _cfg())


def _areas_key(member) -> list[tuple]:
    return [(tuple(a.neurons), a.pixels, a.box, a.mean_disparity, a.contrast) for a in member.areas]


def _kept_key(member) -> list[tuple]:
    return [(tuple(a.neurons), a.box, a.rank) for a in member.kept]


def test_shapes_timings_and_members(motorcycle, result):
    h, w = motorcycle.height, motorcycle.width
    k = 4 * 7
    assert result.labels.shape == (E, h, w) and result.labels.dtype == torch.long
    assert result.ref_disparity.shape == (E, k)
    assert result.som.weight.shape == (E, k, 3)
    assert STAGES <= set(result.timings)
    assert all(math.isfinite(t) and t >= 0 for t in result.timings.values())
    assert [m.seed for m in result.members] == [SEED + e for e in range(E)]
    assert all(m.score is None for m in result.members)  # the embedded scene has no object mask
    assert result.quantization_error.shape == result.topographic_error.shape == (E,)
    assert bool(torch.isfinite(result.quantization_error).all())


def test_labels_cover_exactly_the_segmented_pixels(motorcycle, result):
    feats = result.features
    segmented = torch.zeros(motorcycle.height, motorcycle.width, dtype=torch.bool)
    segmented[feats.pixels[:, 0], feats.pixels[:, 1]] = True
    assert bool((segmented <= motorcycle.valid).all())  # only pixels with a disparity are segmented
    for e in range(E):
        lab = result.labels[e]
        assert torch.equal(lab >= 0, segmented)
        assert int(lab.max()) < 28
    assert len(result.train_features) <= len(feats)
    assert result.train_features.stride == PipelineConfig().features.train_stride


def test_reduction_of_every_member_is_that_of_its_kept_boxes(motorcycle, result):
    rc = PipelineConfig().reduction
    for m in result.members:
        again = reduce_map([a.box for a in m.kept], motorcycle.valid, tolerance_px=rc.tolerance_px,
                           tolerance_frac=rc.tolerance_frac)
        assert again.boxes == m.reduction.boxes
        assert torch.equal(again.mask, m.reduction.mask)
        assert m.reduction.valid_total == motorcycle.n_valid
        assert {tuple(a.neurons) for a in m.kept} <= {tuple(a.neurons) for a in m.areas}


def test_same_seed_gives_identical_results(motorcycle, result):
    again = run_pipeline(motorcycle, _cfg())
    assert torch.equal(again.labels, result.labels)
    assert torch.equal(again.som.weight, result.som.weight)
    for a, b in zip(again.members, result.members, strict=True):
        assert _areas_key(a) == _areas_key(b)
        assert _kept_key(a) == _kept_key(b)
        assert a.reduction.boxes == b.reduction.boxes and a.reduction.kept_union == b.reduction.kept_union


@pytest.mark.parametrize("e", [1, E - 1])
def test_ensemble_member_equals_a_solo_run_with_seed_plus_e(motorcycle, result, e):
    solo = run_pipeline(motorcycle, _cfg(ensemble=1, seed=SEED + e))
    assert solo.members[0].seed == SEED + e
    assert torch.equal(solo.som.weight[0], result.som.weight[e])
    assert not torch.equal(solo.som.weight[0], result.som.weight[0])  # another seed, another map
    assert torch.equal(solo.labels[0], result.labels[e])
    assert _areas_key(solo.members[0]) == _areas_key(result.members[e])
    assert _kept_key(solo.members[0]) == _kept_key(result.members[e])
    assert solo.members[0].reduction.boxes == result.members[e].reduction.boxes


def test_training_log_callback_receives_every_epoch_and_metrics_can_be_skipped(motorcycle):
    logged: list[tuple[str, float, int]] = []
    r = run_pipeline(motorcycle, _cfg(ensemble=1), metrics=False,
                     log_training=lambda tag, v, step: logged.append((tag, v, step)))
    qe = [(v, s) for t, v, s in logged if t == "train/quantization_error"]
    assert len(qe) == EPOCHS
    assert all(math.isfinite(v) and v >= 0 for v, _ in qe)
    assert bool(torch.isnan(r.quantization_error).all()) and r.quantization_error.shape == (1,)


def test_bad_ensemble_is_rejected(motorcycle):
    with pytest.raises(ValueError, match="ensemble"):
        run_pipeline(motorcycle, _cfg(ensemble=0))


def test_a_scene_with_an_object_mask_scores_every_member(shared_data):
    scene = load_scene(shared_data / "eth3d" / "terrace")
    r = run_pipeline(scene, _cfg(ensemble=2))
    assert r.labels.shape == (2, scene.height, scene.width)
    assert len(r.members) == 2
    for m in r.members:
        assert isinstance(m.score, Score)
        assert 0.0 <= m.score.identified_fraction <= 1.0
        assert m.score.x_opt == pytest.approx(94.3, abs=0.05)
        assert m.score.reduction_union == pytest.approx(m.reduction.reduction_union)
        assert m.score.identified_95 == (m.score.identified_fraction >= 0.95)
