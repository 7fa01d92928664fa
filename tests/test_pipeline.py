"""Tests of somtorch.pipeline.run_pipeline on the embedded Motorcycle scene and a shared scene."""

from __future__ import annotations

import math

import pytest
import torch

from somtorch.disparity import load_scene
from somtorch.pipeline import PipelineConfig, SOMConfig, TrainConfig, run_pipeline, train_stride
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
    # the training stride is counted on a 640 x 480 image: the 741 x 497 Motorcycle trains on every 11th pixel
    assert result.train_features.stride == train_stride(motorcycle, PipelineConfig()) == 11


def test_reduction_of_every_member_is_that_of_its_kept_boxes(motorcycle, result):
    rc = PipelineConfig().reduction
    for m in result.members:
        again = reduce_map([a.box for a in m.kept], motorcycle.valid, tolerance_px=rc.tolerance_px,
                           tolerance_frac=rc.tolerance_frac, tolerance_image=rc.tolerance_image)
        assert again.boxes == m.reduction.boxes
        assert torch.equal(again.mask, m.reduction.mask)
        assert m.reduction.valid_total == motorcycle.n_valid
        for k in m.kept:  # a selected area, possibly grown by adjacent segments (objects.merge)
            assert any(set(a.neurons) <= set(k.neurons) for a in m.areas)
            assert len(k.neurons) == len(set(k.neurons))


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


# ---------------------------------------------------------------------------- baseline methods


def _method_cfg(method: str, ensemble: int = 2, **kw) -> PipelineConfig:
    train = TrainConfig(mode="online" if method == "minisom" else "batch", epochs=2)
    return PipelineConfig(method=method, som=SOMConfig(rows=3, cols=4), train=train, ensemble=ensemble, seed=SEED,
                          **kw)


@pytest.mark.parametrize("method", ["kmeans", "minisom", "slic", "felzenszwalb"])
def test_every_baseline_runs_the_same_pipeline(motorcycle, method):
    from somtorch.pipeline import DETERMINISTIC_METHODS

    res = run_pipeline(motorcycle, _method_cfg(method))
    runs = 1 if method in DETERMINISTIC_METHODS else 2
    assert res.method == method and len(res.members) == runs and res.labels.shape[0] == runs
    k = res.num_segments
    seg = res.labels >= 0
    assert int(res.labels.max()) < k and torch.equal(seg[0], seg[-1])
    assert bool((seg[0] <= motorcycle.valid).all())
    assert (res.som is not None) == (method == "minisom")
    lab = res.labels[0][seg[0]]
    ref = res.ref_disparity[0]
    used = torch.unique(lab)
    means = torch.stack([motorcycle.disparity[res.labels[0] == i].mean() for i in used[:5]])
    if method in DETERMINISTIC_METHODS:  # a superpixel's reference disparity is its mean disparity
        assert torch.allclose(ref[used[:5]], means, atol=1e-3)
    for m in res.members:
        assert m.reduction.mask.shape == motorcycle.valid.shape


def test_kmeans_members_equal_solo_runs_and_use_k_equal_rows_times_cols(motorcycle):
    both = run_pipeline(motorcycle, _method_cfg("kmeans", 2))
    solo = run_pipeline(motorcycle, PipelineConfig(**{**_method_cfg("kmeans", 1).__dict__, "seed": SEED + 1}))
    assert both.num_segments == 12
    assert torch.equal(both.labels[1], solo.labels[0])
    assert torch.isfinite(both.quantization_error).all() and torch.isnan(both.topographic_error).all()


def test_minisom_method_segments_with_minisom_s_own_weights(motorcycle):
    from somtorch.baselines import train_minisom

    res = run_pipeline(motorcycle, _method_cfg("minisom", 1))
    w = train_minisom(res.train_features.x, 3, 4, seeds=[SEED], epochs=2, lr=0.5, order="random")
    assert torch.equal(res.som.weight.detach(), w)


def test_minisom_method_needs_the_online_rule(motorcycle):
    cfg = _method_cfg("minisom")
    cfg.train = TrainConfig(mode="batch")
    with pytest.raises(ValueError, match="train.mode"):
        run_pipeline(motorcycle, cfg)


def test_unknown_method_is_rejected():
    with pytest.raises(ValueError, match="method"):
        PipelineConfig(method="dbscan")


def test_a_map_without_a_convincing_object_keeps_everything_flags_it_and_warns(caplog):
    import logging

    from somtorch.disparity.scene import scene_from_arrays

    # a smooth slanted plane with no object: every candidate fails or nothing stands out
    ys, xs = torch.meshgrid(torch.arange(60.0), torch.arange(80.0), indexing="ij")
    d = 10.0 + 0.05 * xs + 0.02 * ys + 0.01 * torch.sin(xs)
    scene = scene_from_arrays(d, torch.ones(60, 80, dtype=torch.bool), name="plane")
    cfg = PipelineConfig(ensemble=3)
    cfg.objects.min_purity = 1.0  # nothing can pass
    cfg.ground.rule = "none"  # (the support test would take the whole plane as the floor)
    with caplog.at_level(logging.WARNING, logger="somtorch.pipeline"):
        res = run_pipeline(scene, cfg, metrics=False)
    assert all(m.no_object for m in res.members)
    assert all(m.reduction.reduction_union == 0.0 for m in res.members)  # the whole map is kept
    assert "no convincing object area" in caplog.text and "3 of 3" in caplog.text


def test_a_map_that_is_all_ground_is_segmented_whole_with_a_warning(caplog):
    """An empty floor seen from above: the support test takes the whole map as its plane, and
    cutting it would leave nothing to train on. The plane is not removed and the map is segmented
    whole (before: a ValueError saying the map had no valid pixel). A box on the same floor still
    has its floor cut."""
    import logging

    from somtorch.disparity.scene import scene_from_arrays

    ys, xs = torch.meshgrid(torch.arange(120.0), torch.arange(160.0), indexing="ij")
    floor = 10.0 + 0.02 * xs + 0.01 * ys
    valid = torch.ones(120, 160, dtype=torch.bool)
    with caplog.at_level(logging.WARNING, logger="somtorch.pipeline"):
        res = run_pipeline(scene_from_arrays(floor, valid, name="empty_floor"), PipelineConfig(ensemble=2),
                           metrics=False)
    assert res.ground is None and "leaves none to train on" in caplog.text
    assert bool((res.labels >= 0).all()) and all(m.kept for m in res.members)
    boxed = floor.clone()
    boxed[50:70, 50:80] += 8.0
    res = run_pipeline(scene_from_arrays(boxed, valid, name="box_on_floor"), PipelineConfig(ensemble=2),
                       metrics=False)
    assert res.ground is not None and res.ground.support
    # a 160 × 120 map is read at every pixel (strides counted on 640 × 480 scale down): the box exactly
    assert all(m.kept[0].box == (50, 50, 79, 69) for m in res.members)


def _floor_with_boxes(noise: float) -> tuple:
    from somtorch.disparity.scene import scene_from_arrays

    ys, xs = torch.meshgrid(torch.arange(120.0), torch.arange(160.0), indexing="ij")
    d = 30.0 + 0.02 * xs + 0.01 * ys
    objects = torch.zeros(120, 160, dtype=torch.long)
    d[40:80, 30:70] += 2.5  # 5 sigma of the noisy map's noise
    objects[40:80, 30:70] = 1
    d[20:40, 110:140] += 2.0
    objects[20:40, 110:140] = 2
    d = d + noise * torch.randn(120, 160, generator=torch.Generator().manual_seed(0))
    return scene_from_arrays(d, torch.ones(120, 160, dtype=torch.bool), name=f"floor_noise_{noise}",
                             objects=objects)


def test_a_noisy_map_is_read_through_the_median_and_a_clean_one_as_given():
    """features.median: only a map whose per-pixel noise sets the ground band is filtered (a dense
    sensor's 0.5 px here; σ ≤ 0.14 px on every stereo and GT map of the corpus); the caller's scene
    is left as it was."""
    from dataclasses import replace

    from somtorch.pipeline import denoised
    from somtorch.tasks.ground import noise_sigma

    cfg = PipelineConfig(ensemble=4)
    noisy, clean = _floor_with_boxes(0.5), _floor_with_boxes(0.0)
    assert noise_sigma(noisy.disparity, noisy.valid) > 0.4
    assert noise_sigma(clean.disparity, clean.valid) < 0.01
    before = noisy.disparity.clone()
    res = run_pipeline(noisy, cfg, metrics=False)
    assert res.median == 3 and torch.equal(noisy.disparity, before)
    read, window = denoised(noisy, cfg)
    assert window == 3 and float((read.disparity - noisy.disparity).abs().max()) > 0.5
    # the larger box rises 2.5 px: read through the median it is kept in every run, as given in at most
    # one of four (the noise splits it into speckled segments)
    assert all(m.score.useful_hit for m in res.members)
    raw = run_pipeline(noisy, replace(cfg, features=replace(cfg.features, median=0)), metrics=False)
    assert raw.median == 0 and sum(m.score.useful_hit for m in raw.members) <= 1
    calm = run_pipeline(clean, cfg, metrics=False)
    off = run_pipeline(clean, replace(cfg, features=replace(cfg.features, median=0)), metrics=False)
    assert calm.median == 0 and torch.equal(calm.labels, off.labels)
    assert denoised(clean, cfg) == (clean, 0)
    with pytest.raises(ValueError, match="odd window"):
        replace(cfg.features, median=4)


def test_a_map_resampled_from_a_coarser_grid_reads_its_own_noise():
    """A depth map registered to an image twice its size repeats each value over 2 × 2 pixels:
    half of its neighbour differences are 0, and read one pixel apart the noise vanishes (the map
    was read as given, its noise left to split the floor). Read two pixels apart as well, it is the
    noise of the map it came from, and the map is read through the median."""
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import read_map
    from somtorch.tasks.ground import noise_sigma

    ys, xs = torch.meshgrid(torch.arange(120.0), torch.arange(160.0), indexing="ij")
    noise = 0.5 * torch.randn(120, 160, generator=torch.Generator().manual_seed(5))
    coarse = 20.0 + 0.01 * xs + 0.05 * ys + noise
    fine = coarse.repeat_interleave(2, 0).repeat_interleave(2, 1)
    ones = torch.ones(240, 320, dtype=torch.bool)
    both = ones[:, :-1] & ones[:, 1:]
    lag1 = (fine[:, 1:] - fine[:, :-1])[both]
    assert float((lag1 - lag1.median()).abs().median()) == 0.0  # what one pixel apart reads
    assert noise_sigma(fine, ones) == pytest.approx(noise_sigma(coarse, ones[:120, :160]), rel=1e-6)
    assert noise_sigma(coarse, ones[:120, :160]) == pytest.approx(0.5, rel=0.05)
    _, window, _ = read_map(scene_from_arrays(fine, ones, name="registered"), PipelineConfig())
    assert window >= 3


def test_the_noise_reading_steps_over_rows_to_at_most_half_a_million_pixels():
    """noise_sigma reads every k-th row of a large map, k rounded up so that it reads at most about
    half a million pixels: a 720 × 1000 map (720,000 px) is read on its even rows (k = 2), 1 px of
    noise on them is read in full, and on the odd rows not at all."""
    from somtorch.tasks.ground import noise_sigma

    ys, xs = torch.meshgrid(torch.arange(720.0), torch.arange(1000.0), indexing="ij")
    clean = 30.0 + 0.01 * xs + 0.02 * ys
    noise = torch.randn(360, 1000, generator=torch.Generator().manual_seed(3))
    ones = torch.ones(720, 1000, dtype=torch.bool)
    even, odd = clean.clone(), clean.clone()
    even[0::2] += noise
    odd[1::2] += noise
    assert noise_sigma(even, ones) == pytest.approx(1.0, rel=0.05)
    assert noise_sigma(even, ones) == noise_sigma(even[::2], ones[::2])  # 360,000 px: every row of them
    assert noise_sigma(odd, ones) < 1e-4


def test_the_noise_reading_s_medians_are_torch_s():
    """noise_sigma takes its medians by numpy's partial sort: the same value as ``torch.median`` (the
    lower middle of an even count), NaN where a NaN is among them, ±inf in place; the reading equals
    its torch formulation bit for bit on maps with integers, NaN and inf."""
    import math

    import numpy as np

    from somtorch.tasks.ground import _median, noise_sigma

    def torch_sigma(d, v):
        sigma = 0.0
        for lag in (1, 2):
            both = v[:, :-lag] & v[:, lag:]
            diff = (d[:, lag:] - d[:, :-lag])[both].double()
            if diff.numel() >= 10:
                mad = (diff - diff.median()).abs().median()
                sigma = max(sigma, float(1.4826 * mad / math.sqrt(2.0)))
        return sigma

    inf, nan = float("inf"), float("nan")
    g = torch.Generator().manual_seed(5)
    # zeros below, at and above the middle (the partial sort skips them), none, all
    mixed = [(torch.randint(-3, 4, (n,), generator=g) * torch.rand(n, generator=g).round()).tolist()
             for n in (1, 2, 9, 10, 101, 1000)]
    for x in ([3.0, 1.0, 2.0, 4.0], [5.0], [2.0, 2.0, 1.0], [1.0, nan, 0.0], [inf, 1.0, -2.0],
              [-inf, inf, 0.0, 1.0], [0.0, 0.0, 0.0, -1.0, 5.0], [-3.0, -2.0, -1.0, 0.0],
              [0.0, 0.0, 1.0, 2.0, 3.0], [0.0] * 6, [-1.0, -1.0, 0.0, 2.0], *mixed):
        a, b = _median(np.array(x, dtype=np.float64)), float(torch.tensor(x, dtype=torch.float64).median())
        assert a == b or (math.isnan(a) and math.isnan(b)), x
    for i in range(60):
        h, w = int(torch.randint(2, 50, (1,), generator=g)), int(torch.randint(3, 70, (1,), generator=g))
        d = (torch.randn(h, w, generator=g) * 3).float()
        d = d.round() if i % 3 == 0 else d
        d[torch.rand(h, w, generator=g) < (0.05 if i % 4 == 0 else 0.0)] = float("inf" if i % 8 else "nan")
        v = torch.rand(h, w, generator=g) < 0.8
        a, b = noise_sigma(d, v), torch_sigma(d, v)
        assert a == b or (math.isnan(a) and math.isnan(b)), i


def test_the_noise_is_measured_once_whether_the_map_is_filtered_or_not(monkeypatch):
    """The median's trigger and the ground band read the same σ, measured once: on a map read as
    given the band takes it as measured; on a noisy one, filtered, what the median leaves of it
    (the filtered map's neighbour differences underrate it: ``median_noise``)."""
    import somtorch.pipeline as pipeline_module
    import somtorch.tasks.ground as ground_module

    calls = []
    real = ground_module.noise_sigma

    def counted(d, v):
        calls.append(1)
        return real(d, v)

    monkeypatch.setattr(ground_module, "noise_sigma", counted)
    monkeypatch.setattr(pipeline_module, "noise_sigma", counted)
    clean = _floor_with_boxes(0.0)
    res = run_pipeline(clean, PipelineConfig(ensemble=1), metrics=False)
    assert res.median == 0 and res.ground is not None and len(calls) == 1
    calls.clear()
    assert run_pipeline(_floor_with_boxes(0.5), PipelineConfig(ensemble=1), metrics=False).median == 3
    assert len(calls) == 1
    # the plane is the one a fit that measures σ itself finds
    own = ground_module.fit_ground_plane(clean.disparity, clean.valid, PipelineConfig().ground)
    assert (own.a, own.b, own.c, own.tol) == (res.ground.a, res.ground.b, res.ground.c, res.ground.tol)


def test_a_filtered_map_s_ground_band_is_what_the_median_leaves_of_its_noise():
    """A dense sensor's floor with 0.8 px of noise, read through the 3 × 3 median (a 120-px side:
    the solidity square allows no wider one): each filtered pixel still errs by ~0.33 px, which
    the filtered map's pixel differences read as ~0.25 (windows one or two pixels apart share most
    of their pixels). The band takes the median's standard error of the measured noise, so the floor
    stays one plane (with the neighbour reading alone a tenth of it was left as speckle; the plane's
    own spread now recovers that too)."""
    from somtorch.disparity.filters import median_noise
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import read_map
    from somtorch.tasks.ground import fit_ground_plane, noise_sigma

    ys, xs = torch.meshgrid(torch.arange(120.0), torch.arange(300.0), indexing="ij")
    truth = 20.0 + 0.01 * xs + 0.05 * ys
    noisy = truth + 0.8 * torch.randn(120, 300, generator=torch.Generator().manual_seed(3))
    scene = scene_from_arrays(noisy, torch.ones(120, 300, dtype=torch.bool), name="noisy_floor")
    cfg = PipelineConfig()
    read, window, sigma = read_map(scene, cfg)
    assert window == 3 and sigma == pytest.approx(median_noise(noise_sigma(noisy, scene.valid), 3))
    err = float((read.disparity - truth)[2:-2, 2:-2].std())  # the filtered map's per-pixel error
    assert sigma == pytest.approx(err, rel=0.1) and noise_sigma(read.disparity, read.valid) < 0.8 * err
    plane = fit_ground_plane(read.disparity, read.valid, cfg.ground, sigma=sigma)
    assert plane.tol == pytest.approx(cfg.ground.noise_band * sigma) and plane.inlier_frac > 0.93
    # σ read off the filtered map sets no band above tol_px; the plane's own spread about it (the
    # median's error is correlated: support_surface.own_band) still widens it to hold the floor
    underrated = fit_ground_plane(read.disparity, read.valid, cfg.ground)
    assert cfg.ground.noise_band * noise_sigma(read.disparity, read.valid) < cfg.ground.tol_px
    assert underrated.tol > 1.2 * cfg.ground.tol_px and underrated.inlier_frac > 0.93


@pytest.mark.parametrize("sigma, size, window, capped", [
    (0.5, (300, 400), 3, False), (0.8, (300, 400), 5, False), (1.1, (300, 400), 7, False),
    (1.5, (300, 400), 7, True), (1.1, (120, 160), 3, True)])
def test_a_noisier_map_is_read_through_a_wider_median(sigma, size, window, capped):
    """The smallest odd window from ``features.median`` (3) whose left-over noise no longer sets
    the ground band (2 · σ·√(π/2)/k ≤ 0.5 px), at most the object step's solidity square (7 px on
    a 300-px side, 3 px on a 120-px one: the last two cases stop there)."""
    from somtorch.disparity.filters import median_noise
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import read_map

    h, w = size
    ys, xs = torch.meshgrid(torch.arange(float(h)), torch.arange(float(w)), indexing="ij")
    d = 30.0 + 0.02 * xs + 0.01 * ys + sigma * torch.randn(h, w, generator=torch.Generator().manual_seed(1))
    scene = scene_from_arrays(d, torch.ones(h, w, dtype=torch.bool), name=f"noisy_{sigma}")
    cfg = PipelineConfig()
    read, k, left = read_map(scene, cfg)
    assert k == window and left == pytest.approx(median_noise(sigma, k), rel=0.05)
    assert (cfg.ground.noise_band * left <= cfg.ground.tol_px) != capped
    if k > 3:  # the pipeline reads it through the same window
        assert run_pipeline(scene, PipelineConfig(ensemble=1), metrics=False).median == k


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA device on this machine"))])
def test_device_flows_through_the_pipeline(device):
    from somtorch.config import PipelineConfig, with_overrides
    from somtorch.disparity import load_scene
    from somtorch.pipeline import run_pipeline

    scene = load_scene("motorcycle")
    ref = run_pipeline(scene, with_overrides(PipelineConfig(), {"ensemble": 2}), metrics=False)
    got = run_pipeline(scene, with_overrides(PipelineConfig(), {"ensemble": 2, "device": device}), metrics=True)
    assert got.labels.device.type == "cpu" and got.som.weight.device.type == "cpu"
    assert all(m.kept for m in got.members)
    if device == "cpu":  # the default path, bitwise
        assert torch.equal(got.labels, ref.labels)
        assert [[a.box for a in m.kept] for m in got.members] == [[a.box for a in m.kept] for m in ref.members]


def test_an_unavailable_device_is_refused_before_training():
    from somtorch.config import PipelineConfig, with_overrides
    from somtorch.disparity import load_scene
    from somtorch.pipeline import run_pipeline

    scene = load_scene("motorcycle")
    with pytest.raises(ValueError, match="not a torch device"):
        run_pipeline(scene, with_overrides(PipelineConfig(), {"device": "gpu0"}))
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="cuda.is_available"):
            run_pipeline(scene, with_overrides(PipelineConfig(), {"device": "cuda"}))


def test_object_step_on_a_strided_map_keeps_full_size_boxes(motorcycle):
    from dataclasses import replace

    from somtorch.tasks.objects import AreaConfig

    full = run_pipeline(motorcycle, replace(_cfg(ensemble=2), objects=AreaConfig(map_stride=1)), metrics=False)
    half = run_pipeline(motorcycle, replace(_cfg(ensemble=2), objects=AreaConfig(map_stride=2)), metrics=False)
    h, w = motorcycle.disparity.shape
    for a, b in zip(full.members, half.members):
        x0, y0, x1, y1 = b.kept[0].box
        assert 0 <= x0 <= x1 < w and 0 <= y0 <= y1 < h
        assert x0 % 2 == 0 and y0 % 2 == 0  # corners on the sampled grid, in full-size pixels
        # the same object, within a few pixels of the box found on every pixel
        assert max(abs(u - v) for u, v in zip(a.kept[0].box, b.kept[0].box)) <= 0.02 * max(h, w)
        # the reduction is computed on the full map, for the full-size boxes
        want = reduce_map([k.box for k in b.kept], motorcycle.valid, tolerance_image=_cfg().reduction.tolerance_image)
        assert b.reduction.reduction_union == pytest.approx(want.reduction_union)
        assert b.kept[0].pixels % 4 == 0  # sampled pixels counted at full size


def test_an_object_setup_serves_only_the_pixels_it_was_built_for(motorcycle):
    # the maps of a run share one object setup (the context of the segmented pixels, the full-size
    # integral, x_opt); a map segmenting other pixels gets its own, never a stale one
    from dataclasses import replace

    from somtorch.pipeline import detect, object_setup, on_support, prepare, read_map, segment_runs

    cfg = replace(_cfg(ensemble=2), consensus=1)
    scene, _, sigma = read_map(motorcycle, cfg)
    _, ground, usable, feats, train = prepare(scene, cfg, sigma=sigma)
    seg = next(segment_runs(feats, train, on_support(scene, ground, cfg.features)[0], usable, cfg))
    seg = replace(seg, labels=seg.labels.long())
    setup = object_setup(scene, seg.labels, ground, cfg)
    assert setup.serves(seg.labels) and setup.stride == 2
    fewer = seg.labels.clone()
    fewer[:, :, : fewer.shape[-1] // 3] = -1  # the left third no longer segmented
    assert not setup.serves(fewer)
    other = replace(seg, labels=fewer)
    given, built = (detect(scene, other, ground, cfg, warn=False, setup=s) for s in (setup, None))
    assert [_kept_key(m) for m in given] == [_kept_key(m) for m in built]
    assert [_areas_key(m) for m in given] == [_areas_key(m) for m in built]
    assert [_kept_key(m) for m in given] != [_kept_key(m) for m in detect(scene, seg, ground, cfg, warn=False,
                                                                            setup=setup)]
    # the setup reads a map on the object step's grid only (every 2nd pixel): a map that differs off
    # it is served, and the step keeps what a setup built for it keeps
    off = seg.labels.clone()
    off[:, 1::2, 1::2] = -1  # no sampled pixel changes
    assert setup.serves(off) and not torch.equal(off >= 0, seg.labels >= 0)
    other = replace(seg, labels=off)
    given, built = (detect(scene, other, ground, cfg, warn=False, setup=s) for s in (setup, None))
    assert [_kept_key(m) for m in given] == [_kept_key(m) for m in built]
    assert [_areas_key(m) for m in given] == [_areas_key(m) for m in built]
    ys, xs = (seg.labels[0, ::2, ::2] >= 0).nonzero(as_tuple=True)
    one = seg.labels.clone()
    one[:, 2 * int(ys[0]), 2 * int(xs[0])] = -1  # one sampled pixel no longer labelled
    assert not setup.serves(one)


def test_a_bent_support_is_re_expressed_on_the_strided_map():
    """The object step reads every 2nd pixel: the plane's slopes scale by 2, its bend by 4, so that
    the strided map's surface is the full map's at the sampled pixels."""
    from dataclasses import replace

    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import _strided
    from somtorch.tasks.ground import GroundPlane
    from somtorch.tasks.objects import AreaConfig

    h, w = 60, 80
    g = GroundPlane(0.01, 0.05, 30.0, 0.5, torch.ones(h, w, dtype=torch.bool), 1.0, True, 1.0, (2e-4, -1e-4, 3e-4))
    scene = scene_from_arrays(g.disparity(h, w).clone(), name="bent")
    labels = torch.zeros(1, h, w, dtype=torch.long)
    _, _, _, g2, _ = _strided(scene, labels, g, AreaConfig(map_stride=2))
    assert torch.allclose(g2.disparity(h // 2, w // 2), g.disparity(h, w)[::2, ::2], atol=1e-4)
    assert g2.mask.shape == (h // 2, w // 2)
    flat = replace(g, bend=(0.0, 0.0, 0.0))
    assert not torch.allclose(flat.disparity(h, w), g.disparity(h, w), atol=0.1)  # the bend is read


def test_the_paper_preset_reads_every_pixel():
    from experiments.distributed import compose_config

    assert compose_config(["+preset=paper", "train.parallel=none"])[0].objects.map_stride == 1
    assert compose_config(["train.parallel=none"])[0].objects.map_stride == 2


def test_a_map_that_varies_only_off_the_check_sample_is_usable():
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import check_usable

    d = torch.full((40, 40), 5.0)
    valid = torch.ones(40, 40, dtype=torch.bool)
    check = PipelineConfig()
    with pytest.raises(ValueError, match="constant map"):
        check_usable(scene_from_arrays(d, valid, name="flat"), check)
    d[1, 3] = 9.0  # not on the 4-pixel grid of the quick sample: the full check must see it
    check_usable(scene_from_arrays(d, valid, name="one"), check)


def test_a_map_too_small_for_its_map_stride_is_read_whole_with_a_warning(motorcycle, caplog):
    from dataclasses import replace

    from somtorch.tasks.objects import AreaConfig

    base = _cfg(ensemble=1)
    base = replace(base, features=replace(base.features, reference_pixels=0))  # strides in pixels as given
    coarse = run_pipeline(motorcycle, replace(base, objects=AreaConfig(map_stride=100_000)), metrics=False)
    assert f"objects.map_stride=100000 (every 100000th pixel at {motorcycle.width}x{motorcycle.height}) leaves " \
        "fewer than 28 valid pixels" in caplog.text  # 4 x 7 neurons
    whole = run_pipeline(motorcycle, replace(base, objects=AreaConfig(map_stride=1)), metrics=False)
    coarsest = [t for t in range(2, 200) if int(motorcycle.valid[::t, ::t].sum()) >= 28][-1]
    same = run_pipeline(motorcycle, replace(base, objects=AreaConfig(map_stride=coarsest)), metrics=False)
    assert coarse.members[0].kept[0].box == same.members[0].kept[0].box  # the coarsest stride that fits
    assert coarsest > 1 and whole.members[0].kept  # the map itself is usable


def test_strides_scale_with_the_resolution_so_a_resampled_map_trains_on_as_many_pixels(motorcycle):
    from dataclasses import replace

    from somtorch.disparity.resize import resize_scene
    from somtorch.pipeline import map_stride

    cfg = PipelineConfig()
    big = resize_scene(motorcycle, motorcycle.width * 2, motorcycle.height * 2)
    assert train_stride(big, cfg) == 2 * train_stride(motorcycle, cfg) or \
        abs(train_stride(big, cfg) - 2 * train_stride(motorcycle, cfg)) <= 1
    assert map_stride(big, cfg) == cfg.features.stride_at(cfg.objects.map_stride, *big.valid.shape) == 4
    # training sets of the same size (within the rounding of the stride)
    n_small = int(motorcycle.valid[::train_stride(motorcycle, cfg), ::train_stride(motorcycle, cfg)].sum())
    n_big = int(big.valid[::train_stride(big, cfg), ::train_stride(big, cfg)].sum())
    assert 0.8 < n_big / n_small < 1.25
    # a smaller image scales them down alike (session 27): as many training pixels, the object step
    # reads as many; reference_pixels 0 counts strides in pixels
    small = resize_scene(motorcycle, motorcycle.width // 2, motorcycle.height // 2)
    assert abs(2 * train_stride(small, cfg) - train_stride(motorcycle, cfg)) <= 1
    n_half = int(small.valid[::train_stride(small, cfg), ::train_stride(small, cfg)].sum())
    assert 0.8 < n_half / n_small < 1.25
    assert map_stride(small, cfg) == 1 < map_stride(motorcycle, cfg) == cfg.objects.map_stride
    raw = replace(cfg, features=replace(cfg.features, reference_pixels=0))
    assert train_stride(big, raw) == cfg.features.train_stride and map_stride(big, raw) == cfg.objects.map_stride
    assert cfg.features.stride_at(1, 5 * 480, 5 * 640) == 1  # NOR (every pixel) stays every pixel


def test_many_calls_warn_once_about_kept_everything(caplog):
    """The paper preset keeps the whole map in many runs: inside fallback_summary (a study job's
    separate runs) one line for all of them instead of one per run."""
    import logging

    from somtorch.config import with_overrides
    from somtorch.disparity import load_scene
    from somtorch.pipeline import PipelineConfig, fallback_summary, run_pipeline

    from pathlib import Path

    import yaml

    scene = load_scene("motorcycle")
    conf = Path(__file__).resolve().parents[1] / "conf"
    paper = {f"{g}.{k}": v for g, name in (("objects", "paper"), ("reduction", "paper"), ("ground", "none"),
                                           ("features", "paper_or"), ("train", "online"), ("som", "grid4x7"))
             for k, v in (yaml.safe_load((conf / g / f"{name}.yaml").read_text()) or {}).items()}
    # the paper preset (one map per run), shorter
    cfg = with_overrides(PipelineConfig(), {**paper, "train.epochs": 2, "consensus": 1})
    with caplog.at_level(logging.WARNING, logger="somtorch.pipeline"):
        plain = [run_pipeline(scene, with_overrides(cfg, {"seed": s}), metrics=False) for s in range(4)]
        per_call = len(caplog.records)
        caplog.clear()
        with fallback_summary(scene.name) as counts:
            for s in range(4):
                run_pipeline(scene, with_overrides(cfg, {"seed": s}), metrics=False)
    flagged = sum(m.no_object or m.reduction.reduction_union < 1.0 for r in plain for m in r.members)
    assert flagged >= 2 and per_call == flagged  # the setting does trigger the warning, run after run
    assert len(caplog.records) == 1 and "of 4 runs" in caplog.records[0].getMessage()
    assert counts[2] == 4 and counts[0] + counts[1] == flagged


def test_the_thread_count_never_changes_a_result(motorcycle, monkeypatch):
    """run_pipeline and the video runner run on the cores other processes leave free
    (``somtorch.core.threads.contended``): the same bits whatever torch's thread count is."""
    from somtorch.disparity.resize import resize_scene
    from somtorch.video import SequenceRunner, pan_sequence

    before, out = torch.get_num_threads(), {}
    big = resize_scene(motorcycle, 790, 450)
    try:
        for n in (1, 2):
            monkeypatch.setenv("SOMTORCH_THREADS", str(n))  # explicit: what torch is set to, loaded machine or not
            torch.set_num_threads(n)
            r = run_pipeline(motorcycle, PipelineConfig(ensemble=3))
            runner = SequenceRunner(PipelineConfig(), warm=True)
            frames = [runner.step(f) for f in pan_sequence(big, 632, 360, 3)]
            out[n] = (r.labels, r.ref_disparity, [[a.box for a in m.kept] for m in r.members],
                      [m.reduction.reduction_union for m in r.members],
                      [([a.box for a in f.members[0].kept], f.members[0].reduction.reduction_union) for f in frames])
    finally:
        torch.set_num_threads(before)
    assert torch.equal(out[1][0], out[2][0]) and torch.equal(out[1][1], out[2][1])
    assert out[1][2:] == out[2][2:]


def _bad_maps() -> dict:
    """The issue's bad-input classes for step 1c, each as (disparity, valid) of 60 × 80."""
    g = torch.Generator().manual_seed(7)
    ys, xs = torch.meshgrid(torch.arange(60.0), torch.arange(80.0), indexing="ij")
    ones = torch.ones(60, 80, dtype=torch.bool)
    no_plane = 20.0 + 8.0 * torch.sin(xs / 7.0) * torch.cos(ys / 5.0)  # a bumpy surface, no plane in it
    one_piece = 10.0 + 0.3 * xs + 0.1 * ys  # one smooth ramp: one component covering everything
    streaky = torch.full((60, 80), 12.0)
    streaky[30:50, 25:45] = 20.0  # a box in front of a wall …
    rows = torch.randint(0, 60, (25,), generator=g)
    for r in rows.tolist():  # … and SGBM-like horizontal mismatch streaks with gaps
        x0 = int(torch.randint(0, 60, (1,), generator=g))
        streaky[r, x0:x0 + 20] = float(torch.randint(5, 30, (1,), generator=g))
    gaps = torch.rand(60, 80, generator=g) > 0.15
    bowl = 120.0 + 60.0 * torch.exp(-((xs - 40) ** 2 + (ys - 30) ** 2) / 300.0)  # smooth 8-bit "depth"
    eight_bit = torch.round(bowl.clamp(0, 255))
    return {"no plane": (no_plane, ones), "one component": (one_piece, ones),
            "streaky SGBM": (streaky, gaps), "smooth 8-bit": (eight_bit, ones)}


@pytest.mark.parametrize("kind", ["no plane", "one component", "streaky SGBM", "smooth 8-bit"])
def test_bad_maps_for_step_1c_run_and_say_which_rule_was_applied(kind):
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.outputs import summarize

    d, valid = _bad_maps()[kind]
    scene = scene_from_arrays(d, valid, name=kind.replace(" ", "_"))
    res = run_pipeline(scene, PipelineConfig(ensemble=2), metrics=False)
    assert all(m.kept for m in res.members)  # something is always kept (the whole map at worst)
    step = summarize(scene, res)["object_step"]
    assert step["mode"] in ("support", "contrast") and step["reason"]
    assert (step["mode"] == "support") == (res.ground is not None and res.ground.support)
    if res.ground is None:
        assert "no ground plane" in step["reason"]
