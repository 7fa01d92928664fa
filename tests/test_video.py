"""The sequence runner: warm-started frames, re-used ground, the same results as run_pipeline cold."""

from __future__ import annotations

import pytest
import torch

from somtorch.config import PipelineConfig, with_overrides
from somtorch.disparity.scene import scene_from_arrays
from somtorch.pipeline import run_pipeline
from somtorch.video import SequenceRunner, iter_sequence, pan_sequence


def _world(h=90, w=200):
    """A floor rising towards the camera, a wall behind, one box standing on the floor."""
    rows = torch.arange(h, dtype=torch.float32)[:, None].expand(h, w)
    d = torch.where(rows > 30, 5.0 + (rows - 30) * 0.5, torch.full_like(rows, 5.0)).clone()
    d += 0.05 * torch.rand(h, w, generator=torch.Generator().manual_seed(0))
    obj = torch.zeros(h, w, dtype=torch.int64)
    obj[35:70, 80:120] = 1
    d[obj == 1] = 40.0
    return scene_from_arrays(d, objects=obj, name="world")


def test_pan_moves_the_window_and_its_objects():
    frames = list(pan_sequence(_world(), 120, 90, 5, step_px=10))
    assert len(frames) == 5 and all(f.disparity.shape == (90, 120) for f in frames)
    xs = [int(f.objects.nonzero()[:, 1].min()) for f in frames]
    assert xs == [80, 70, 60, 50, 40]  # the window slides right: the object moves left
    with pytest.raises(ValueError, match="does not fit"):
        next(pan_sequence(_world(), 300, 90, 1))


def test_warm_frames_keep_the_object_and_reuse_the_ground():
    cfg = with_overrides(PipelineConfig(), {"ensemble": 1})
    res = list(iter_sequence(pan_sequence(_world(), 120, 90, 8, step_px=3), cfg))
    assert [r.warm for r in res] == [False] + [True] * 7
    assert all(r.members[0].score.useful_hit for r in res)
    assert res[0].ground is not None and sum(r.ground_reused for r in res) >= 5
    assert set(res[1].timings) == {"ground", "features", "train", "segment", "objects"}


@pytest.mark.parametrize("noise, consensus", [(0.0, 1), (0.6, 1), (0.0, 3)])
def test_a_cold_frame_is_what_run_pipeline_gives(noise, consensus):
    """Also on a dense sensor's noisy frame, which both read through the median (features.median),
    and with several maps per run (the consensus' map is kept, and warm-started next)."""
    cfg = with_overrides(PipelineConfig(), {"ensemble": 2, "consensus": consensus})
    frame = next(pan_sequence(_world(), 120, 90, 1))
    if noise:
        g = torch.Generator().manual_seed(1)
        frame = scene_from_arrays(frame.disparity + noise * torch.randn(frame.disparity.shape, generator=g),
                                  objects=frame.objects, name="noisy")
    cold = SequenceRunner(cfg, warm=False).step(frame)
    ref = run_pipeline(frame, cfg, metrics=False)
    assert ref.median == (3 if noise else 0)
    for got, want in zip(cold.members, ref.members):
        assert [a.box for a in got.kept] == [a.box for a in want.kept]
        assert got.reduction.reduction_union == want.reduction.reduction_union
        assert (got.seed, got.consensus_map, got.agreement) == (want.seed, want.consensus_map, want.agreement)
    runner = SequenceRunner(cfg)
    runner.step(frame)
    assert torch.equal(runner.som.weight, ref.som.weight) and runner.som.seeds == [m.seed for m in ref.members]


def test_runner_checks_its_settings():
    with pytest.raises(ValueError, match="method='som'"):
        SequenceRunner(with_overrides(PipelineConfig(), {"method": "kmeans"}))
    with pytest.raises(ValueError):
        SequenceRunner(warm_epochs=0)
    with pytest.raises(ValueError):
        SequenceRunner(ground_keep=1.5)


def test_a_warm_frame_labels_only_what_the_object_step_reads_with_the_same_result():
    from somtorch.pipeline import detect, prepare
    from somtorch.segmenters import _from_prototypes
    from somtorch.tasks.segmentation import segment

    cfg = with_overrides(PipelineConfig(), {"ensemble": 1})
    assert cfg.objects.map_stride == 2
    frames = list(pan_sequence(_world(), 120, 90, 3, step_px=3))
    runner = SequenceRunner(cfg)
    runner.step(frames[0])
    runner.step(frames[1])
    w_before = runner.som.weight.detach().clone()
    got = runner.step(frames[2])
    assert got.warm
    # the same frame with every pixel labelled: the runner's weights after its warm training
    valid, ground, usable, feats, train = prepare(frames[2], cfg, ground_fn=lambda v: got.ground)
    w = runner.som.weight.detach()
    assert not torch.equal(w, w_before)  # the frame trained
    seg = _from_prototypes(w, feats, runner.som.grid_d2, runner.som, runner.som.seeds)
    seg.labels = segment(w, feats.x, feats.pixels, feats.shape)
    want = detect(frames[2], seg, ground, cfg)
    for g, r in zip(got.members, want):
        assert [a.box for a in g.kept] == [a.box for a in r.kept]
        assert g.reduction.reduction_union == r.reduction.reduction_union


def test_features_on_a_grid_keep_the_training_pixels_and_the_image_axes():
    from somtorch.pipeline import prepare

    cfg = with_overrides(PipelineConfig(), {"ensemble": 1})
    frame = next(pan_sequence(_world(), 120, 90, 1))
    _, _, usable, full, train_full = prepare(frame, cfg)
    _, _, usable2, grid, train_grid = prepare(frame, cfg, grid=2)
    assert torch.equal(usable, usable2)  # the map's usable pixels, whatever the grid
    want = usable.clone()
    want[1::2, :] = False
    want[:, 1::2] = False
    assert torch.equal(grid.mask, want) and len(grid) == int(want.sum())
    assert torch.equal(train_full.pixels, train_grid.pixels)  # stride 10 lies on the 2-grid
    on = want[full.pixels[:, 0], full.pixels[:, 1]]
    assert torch.equal(full.x[on][:, :2], grid.x[:, :2])  # y, x scale with the image, not the pixels
