"""The object step's native pass over a label map (:func:`somtorch.core.label_stats.native_label_stats`)
against its definition in ``torch.bincount`` and against the torch path it replaces: the same
numbers bit for bit, so ``SOMTORCH_NATIVE=0`` changes no kept box."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from somtorch.config import PipelineConfig
from somtorch.core import native
from somtorch.core.label_stats import native_label_stats
from somtorch.disparity.loading import load_scene
from somtorch.disparity.scene import scene_from_arrays
from somtorch.pipeline import detect, on_support, prepare, read_map, segment_runs
from somtorch.tasks.objects import _segment_counts, neuron_stats, pair_continuity

from .test_ground_pitch import cubes, render


def _maps(seed: int):
    """Random label maps in [−1, K) (some labels absent, thin and empty shapes included), two
    weight maps, and a group map."""
    g = torch.Generator().manual_seed(seed)
    for h, w in ((1, 1), (1, 17), (13, 1), (0, 5), (23, 31), (64, 48)):
        k = int(torch.randint(1, 12, (1,), generator=g))
        lab = torch.randint(-1, k + 3, (h, w), generator=g)
        lab[lab >= k] = -1  # some labels absent, many pixels unlabelled
        weights = [torch.rand(h, w, generator=g) * 90, torch.randn(h, w, generator=g, dtype=torch.float64)]
        groups = torch.randint(0, 4, (h, w), generator=g)
        yield lab, k, weights, groups


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_stats_equal_their_bincount_definitions(kernel, seed):
    for lab, k, weights, groups in _maps(seed):
        h, w = lab.shape
        cont = pair_continuity(weights[0])
        got = native_label_stats(lab, k, weights, pairs=True, continuity=cont, groups=groups, n_groups=4)
        assert got is not None
        key = torch.where(lab >= 0, lab, k).reshape(-1)
        assert torch.equal(got.count, torch.bincount(key, minlength=k + 1)[:k])
        for m, wt in enumerate(weights):  # float64 sums in pixel order: the same bits
            assert torch.equal(got.sums[m], torch.bincount(key, weights=wt.reshape(-1).double(),
                                                           minlength=k + 1)[:k])
        for i in range(k):
            ys, xs = (lab == i).nonzero(as_tuple=True)
            want = (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())) if ys.numel() \
                else (w, h, -1, -1)
            assert tuple(got.box[i].tolist()) == want
        table = torch.bincount(key * 4 + groups.reshape(-1), minlength=(k + 1) * 4).view(k + 1, 4)[:k]
        assert torch.equal(got.groups, table)
        # every 4-connected pair, pixel by pixel: horizontal ones row by row, then the vertical ones
        pairs, cpairs, p = torch.zeros(k, k, dtype=torch.long), torch.zeros(k, k, dtype=torch.long), 0
        for (dy, dx) in ((0, 1), (1, 0)):
            for y in range(h - dy):
                for x in range(w - dx):
                    a, b = int(lab[y, x]), int(lab[y + dy, x + dx])
                    if a >= 0 and b >= 0 and a != b:
                        pairs[a, b] += 1
                        cpairs[a, b] += int(cont[p])
                    p += 1
        assert p == cont.numel()
        assert torch.equal(got.pairs, pairs) and torch.equal(got.continuous, cpairs)


def test_the_fused_pass_gives_neuron_stats_the_torch_paths_numbers(kernel):
    for lab, k, weights, _ in _maps(5):
        if 0 in lab.shape:
            continue
        d = weights[0]
        for cont in (None, pair_continuity(d)):
            count, dsum, box, boundary, cboundary = _segment_counts(lab, d, k, cont)
            stats = neuron_stats(lab, d, k, continuity=cont, spread=((0.0, 1.0), (0.0, 1.0)))
            assert torch.equal(stats.count, count) and torch.equal(stats.box, box)
            assert torch.equal(stats.mean_d.nan_to_num(-7.0), (dsum / count).nan_to_num(-7.0))  # NaN: empty
            assert torch.equal(stats.boundary, boundary)
            assert (cont is None and stats.continuous is None) or torch.equal(stats.continuous, cboundary)


def test_the_kernel_declines_what_it_cannot_count_and_the_torch_path_takes_over(kernel, monkeypatch):
    lab = torch.tensor([[0, 1, -1], [2, 2, 0]])
    assert native_label_stats(lab, 3) is not None
    assert native_label_stats(lab, 2) is None  # label 2 outside [−1, 2)
    assert native_label_stats(lab - 1, 3) is None  # −2 is no label
    assert native_label_stats(lab, 3, groups=torch.full_like(lab, 3), n_groups=3) is None  # group 3 of 3
    assert native_label_stats(lab.int(), 3) is None  # int32 labels
    assert native_label_stats(lab, 3, continuity=torch.ones(7, dtype=torch.bool)) is None  # pairs not asked
    six = torch.ones(6, dtype=torch.bool)  # a 2 × 3 map has 7 pairs
    assert native_label_stats(lab, 3, pairs=True, continuity=six) is None
    monkeypatch.setenv(native.ENV_SWITCH, "0")
    assert native_label_stats(lab, 3) is None
    stats = neuron_stats(lab, torch.ones(2, 3), 3)  # the torch path
    assert stats.count.tolist() == [2.0, 1.0, 2.0] and stats.box[2].tolist() == [0, 1, 1, 1]


def _members(scene, monkeypatch, switch: str):
    cfg = replace(PipelineConfig(), ensemble=3, consensus=1)
    scene, window, sigma = read_map(scene, cfg)
    valid, ground, usable, feats, train = prepare(scene, cfg, sigma=sigma)
    seg = next(segment_runs(feats, train, on_support(scene, ground, cfg.features)[0], usable, cfg))
    seg = replace(seg, labels=seg.labels.long())
    monkeypatch.setenv(native.ENV_SWITCH, switch)
    return ground, detect(scene, seg, ground, cfg, warn=False)


def _summary(members):
    return [([(a.neurons, a.box, a.pixels, a.mean_disparity, a.contrast) for a in m.areas],
             [(a.neurons, a.box, a.purity, a.solidity, a.confidence) for a in m.kept],
             [(c.verdict, c.score) for c in m.candidates], m.no_object) for m in members]


@pytest.mark.parametrize("where", ["floor seen from above", "Motorcycle"])
def test_the_object_step_keeps_the_same_boxes_with_the_kernel_or_without(kernel, monkeypatch, where):
    if where == "Motorcycle":  # a forward view: the contrast rule
        scene = load_scene("motorcycle")
    else:  # cubes on a floor at 60°: a verified support, the continuity link, size × nearness
        d, valid, objects = render(60, cubes(60), noise_px=0.05)
        scene = scene_from_arrays(d, valid=valid, objects=objects, name="floor60")
    g_on, on = _members(scene, monkeypatch, "1")
    g_off, off = _members(scene, monkeypatch, "0")
    if where != "Motorcycle":
        assert g_on is not None and g_on.support  # the support path was exercised
    assert _summary(on) == _summary(off)
    assert all(torch.equal(a.stats.boundary, b.stats.boundary) for a, b in zip(on, off))
