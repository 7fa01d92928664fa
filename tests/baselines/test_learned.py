"""The learned baseline: it learns, it is deterministic, its checkpoints round-trip and refuse a
mismatch, and it never trains on real data."""

from __future__ import annotations

import json

import pytest
import torch

from somtorch.baselines.learned import (CheckpointMismatchError, RealDataError, TrainingCollapsedError, check_alive,
                                        check_synthetic, evaluate, fit, load, prepare_input, save)
from somtorch.baselines.learned.data import prepare_target, tensor_hash
from somtorch.config.learned import LearnedFitConfig, LearnedModelConfig
from somtorch.tasks.baselines import get_task_baseline, learned_boxes

TINY = LearnedModelConfig(widths=[8, 16, 32], groups=4, height=32, width=48)


def box_on_plane(gen: torch.Generator, h: int = 96, w: int = 144):
    """A ground plane (disparity rising down the image, the top rows empty: sky) and one box
    standing on it, nearer than the plane behind it; its mask and box."""
    rows = torch.arange(h, dtype=torch.float32)[:, None].expand(h, w)
    horizon = int(h * (0.2 + 0.2 * float(torch.rand(1, generator=gen))))
    slope = 0.3 + 0.4 * float(torch.rand(1, generator=gen))
    d = (rows - horizon).clamp_min(0) * slope + 1.0
    valid = rows >= horizon
    bw = int(w * (0.15 + 0.3 * float(torch.rand(1, generator=gen))))
    bh = int(h * (0.15 + 0.3 * float(torch.rand(1, generator=gen))))
    x0 = int(torch.randint(0, w - bw, (1,), generator=gen))
    y1 = int(torch.randint(max(horizon + bh, h // 2), h, (1,), generator=gen))
    y0 = y1 - bh
    mask = torch.zeros(h, w, dtype=torch.bool)
    mask[y0:y1 + 1, x0:x0 + bw] = True
    d = torch.where(mask, torch.full_like(d, float(d[y1, 0]) + 2.0), d)  # the box's front face
    valid = valid | mask
    d = d + 0.1 * torch.randn(h, w, generator=gen)
    holes = torch.rand(h, w, generator=gen) < 0.05  # stereo holes
    return d, valid & ~holes, mask, (x0, y0, x0 + bw - 1, y1)


def tiny_set(n: int, seed: int, cfg: LearnedModelConfig = TINY):
    gen = torch.Generator().manual_seed(seed)
    maps = [box_on_plane(gen) for _ in range(n)]
    x = torch.stack([prepare_input(d, v, cfg) for d, v, _, _ in maps])
    y = torch.stack([prepare_target(m, cfg) for _, _, m, _ in maps])
    return x, y, maps


def box_iou(a, b) -> float:
    iw, ih = min(a[2], b[2]) - max(a[0], b[0]) + 1, min(a[3], b[3]) - max(a[1], b[1]) + 1
    inter = max(iw, 0) * max(ih, 0)
    area = lambda r: (r[2] - r[0] + 1) * (r[3] - r[1] + 1)  # noqa: E731
    return inter / (area(a) + area(b) - inter)


@pytest.fixture(scope="module")
def trained():
    x, y, _ = tiny_set(96, seed=1)
    return fit(x, y, TINY, LearnedFitConfig(epochs=30, batch_size=16, lr=1e-2, seed=0))


def test_a_tiny_run_learns_a_box_on_a_plane(trained):
    x, y, maps = tiny_set(24, seed=2)  # held out: other draws
    scores = evaluate(trained, x, y)
    assert scores["mask_iou"] > 0.9, scores
    assert scores["box_iou"] > 0.9, scores
    # at the maps' own size, through the boxes every task baseline returns
    ious = []
    for d, v, _, truth in maps:
        found = learned_boxes(d, v, model=trained)
        ious.append(box_iou(found[0].box, truth) if found else 0.0)
    assert sum(ious) / len(ious) > 0.9, ious


def test_a_network_whose_positive_evidence_died_is_refused(trained):
    """Too large a step kills the ReLU units the head weighs positively: no pixel's logit then
    exceeds the head's bias, and the network marks every frame alike. check_alive refuses it (the
    message names the fields to change); a network that learned passes."""
    x, y, _ = tiny_set(32, seed=1)
    check_alive(trained, x)
    dead = fit(x, y, TINY, LearnedFitConfig(epochs=2, batch_size=8, lr=1.0, seed=0))
    with torch.no_grad():
        assert float(trained(x).max()) > float(trained.head.bias) + 1.0
        assert float(dead(x).max()) <= float(dead.head.bias)  # what is refused, measured directly
    with pytest.raises(TrainingCollapsedError, match=r"fit\.lr .*fit\.seed"):
        check_alive(dead, x)


def test_same_seed_same_weights_other_seed_other_weights():
    x, y, _ = tiny_set(16, seed=3)
    cfg = LearnedFitConfig(epochs=2, batch_size=8, seed=5)
    a, b = fit(x, y, TINY, cfg), fit(x, y, TINY, cfg)
    c = fit(x, y, TINY, LearnedFitConfig(epochs=2, batch_size=8, seed=6))
    sa, sb, sc = a.state_dict(), b.state_dict(), c.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)


def test_checkpoint_round_trips_bitwise(trained, tmp_path):
    meta = {"held_out_metrics": {"mask_iou": 0.5}}
    p1 = save(trained, tmp_path / "a.safetensors", data_hash="0123456789abcdef", meta=meta)
    back = load(p1, model_cfg=TINY, data_hash="0123456789abcdef")
    s0, s1 = trained.state_dict(), back.state_dict()
    assert s0.keys() == s1.keys() and all(torch.equal(s0[k], s1[k]) for k in s0)
    p2 = save(back, tmp_path / "b.safetensors", data_hash="0123456789abcdef", meta=meta)
    assert p1.read_bytes() == p2.read_bytes()
    sidecar = json.loads(p1.with_suffix(".json").read_text())
    assert sidecar["data_hash"] == "0123456789abcdef" and sidecar["model"]["widths"] == [8, 16, 32]
    x, _, _ = tiny_set(2, seed=4)
    assert torch.equal(trained(x), back(x))


def test_loading_with_another_config_or_data_hash_is_a_clear_error(trained, tmp_path):
    path = save(trained, tmp_path / "m.safetensors", data_hash="aaaa")
    other = LearnedModelConfig(widths=[8, 16, 32], groups=4, height=32, width=48, threshold=0.6)
    with pytest.raises(CheckpointMismatchError, match=r"model config differs.*threshold.*0\.5.*0\.6"):
        load(path, model_cfg=other)
    with pytest.raises(CheckpointMismatchError, match="trained on data 'aaaa', expected 'bbbb'"):
        load(path, data_hash="bbbb")
    with pytest.raises(FileNotFoundError, match="checkpoint not found"):
        load(tmp_path / "none.safetensors")


def test_the_data_hash_sees_every_byte():
    x, y, _ = tiny_set(2, seed=7)
    h = tensor_hash(x, y)
    x2 = x.clone()
    x2[0, 0, 0, 0] += 1e-6
    assert tensor_hash(x2, y) != h and tensor_hash(x.clone(), y.clone()) == h


def test_real_data_and_foreign_folders_are_refused(shared_data, tmp_path):
    from somtorch.synth import generate_frame, write_frame

    real = shared_data / "middlebury2014" / "Motorcycle_Q"
    with pytest.raises(RealDataError, match="lies under the real data"):
        check_synthetic(real, forbidden=(shared_data,))
    with pytest.raises(RealDataError, match="not a frame of this generator"):
        check_synthetic(real)  # no generator's objects.json, even when no root is named
    folder = write_frame(generate_frame("garden", 1000, "oakd", scale=0.1), tmp_path / "garden")
    assert check_synthetic(folder, forbidden=(shared_data,)) == folder.resolve()
    with pytest.raises(RealDataError, match="lies under the real data"):  # a generated frame put there
        check_synthetic(folder, forbidden=(tmp_path,))


def test_prepare_input_is_scale_free_and_checks_its_arguments():
    gen = torch.Generator().manual_seed(0)
    d, v, _, _ = box_on_plane(gen)
    a, b = prepare_input(d, v, TINY), prepare_input(d * 7.5, v, TINY)  # another focal length x baseline
    assert a.shape == (2, 32, 48) and torch.allclose(a, b, atol=1e-5)
    with pytest.raises(ValueError, match="differ in shape"):
        prepare_input(d, v[:-1], TINY)
    with pytest.raises(ValueError, match="needs the scene's left image"):
        prepare_input(d, v, LearnedModelConfig(widths=[8, 16, 32], groups=4, height=32, width=48, image=True))


def test_config_rules_name_the_field():
    with pytest.raises(ValueError, match="must divide by 2"):
        LearnedModelConfig(height=30)
    with pytest.raises(ValueError, match="groups=3 must divide every width"):
        LearnedModelConfig(groups=3)
    from somtorch.baselines.learned.data import synthetic_frames
    from somtorch.config.learned import LearnedDataConfig

    with pytest.raises(ValueError, match=r"data.cameras='zed' is not known; valid names: kitti, middlebury, oakd"):
        synthetic_frames(LearnedDataConfig(cameras=["zed"]))
    with pytest.raises(ValueError, match="data.cameras must be a non-empty list of distinct names"):
        LearnedDataConfig(cameras=["oakd", "oakd"])
    with pytest.raises(ValueError, match="data.first_seed"):
        LearnedDataConfig(first_seed=3)  # the corpus seeds (scored) are never trained on


def test_registered_with_a_fold_per_camera_and_a_clear_error_without_a_model(tmp_path, monkeypatch):
    monkeypatch.setenv("SOMTORCH_CACHE", str(tmp_path))
    entry = get_task_baseline("learned")
    fold = entry.without("kitti")
    assert fold.fn.without_camera == "kitti" and entry.without(None) is entry
    d, v, _, _ = box_on_plane(torch.Generator().manual_seed(0))
    with pytest.raises(FileNotFoundError, match=r"somtorch-train-baseline 'data.cameras=\[oakd,middlebury\]'"):
        fold(d, v)
