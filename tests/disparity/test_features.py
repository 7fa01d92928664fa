"""Tests of somtorch.disparity.features (paper step 1a: valid pixels → scaled (y, x, d) vectors).

(They live here because this suite's brief covers tests/tasks only; they belong in tests/disparity.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from somtorch.disparity.features import make_features

NAN, INF = float("nan"), float("inf")


def _ramp(h: int, w: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """A disparity map with a distinct value at every pixel: d = 1 + y + 0.5·x. Shape (H, W)."""
    y, x = torch.meshgrid(torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij")
    return 1.0 + y + 0.5 * x


# ------------------------------------------------------------------------ usable pixels, order


def test_invalid_negative_and_nonfinite_pixels_are_dropped_and_counted():
    d = torch.tensor([[1.0, NAN, 3.0, 4.0],
                      [-1.0, 6.0, INF, 8.0],
                      [9.0, 10.0, 11.0, -INF]])
    valid = torch.ones(3, 4, dtype=torch.bool)
    valid[2, 1] = False  # a finite, positive value the mask rejects
    f = make_features(d, valid, normalize="none", d_weight=1.0)
    expected = [(y, x) for y in range(3) for x in range(4)
                if valid[y, x] and math.isfinite(d[y, x]) and d[y, x] >= 0]
    assert f.pixels.tolist() == [list(p) for p in expected]  # row-major, exactly the usable pixels
    assert f.n_invalid == 12 - len(expected) == 5  # NaN, -1, inf, -inf and the masked 10
    assert len(f) == len(expected)
    assert f.shape == (3, 4)
    assert f.x[:, 2].tolist() == [d[y, x].item() for y, x in expected]
    assert bool(torch.isfinite(f.x).all())


def test_zero_disparity_is_usable():
    d = torch.tensor([[0.0, 2.0]])
    f = make_features(d, torch.ones(1, 2, dtype=torch.bool), normalize="none", d_weight=1.0)
    assert len(f) == 2 and f.n_invalid == 0


def test_pixels_are_in_row_major_order_for_a_random_mask():
    g = torch.Generator().manual_seed(0)
    valid = torch.rand(37, 53, generator=g) > 0.4
    f = make_features(_ramp(37, 53), valid)
    flat = f.pixels[:, 0] * 53 + f.pixels[:, 1]
    assert bool((flat[1:] > flat[:-1]).all())
    assert torch.equal(f.pixels, valid.nonzero())
    assert f.pixels.dtype == torch.long


# ----------------------------------------------------------------------------- normalisation


@pytest.mark.parametrize("normalize", ["image", "minmax", "none"])
@pytest.mark.parametrize("d_weight", [1.0, 2.5])
def test_to_pixel_units_inverts_to_features(normalize, d_weight):
    d = _ramp(9, 14)
    f = make_features(d, d > 3.0, normalize=normalize, d_weight=d_weight, dtype=torch.float64)
    v = torch.tensor([[0.0, 0.0, 0.0], [3.0, 7.5, 12.0], [-2.0, 100.0, 0.25]], dtype=torch.float64)
    torch.testing.assert_close(f.to_pixel_units(f.to_features(v)), v)
    # the feature vectors themselves map back to the pixels' (y, x, d)
    raw = torch.cat([f.pixels.double(), d[d > 3.0][:, None]], dim=1)
    torch.testing.assert_close(f.to_pixel_units(f.x), raw)
    torch.testing.assert_close(f.to_features(raw), f.x)


def test_image_normalisation_keeps_the_aspect_ratio():
    h, w = 20, 50
    d = _ramp(h, w)
    f = make_features(d, torch.ones(h, w, dtype=torch.bool), normalize="image", d_weight=3.0)
    y, x, dd = f.x.double().unbind(1)
    assert float(y.min()) == 0.0 and float(x.min()) == 0.0
    assert float(x.max()) == pytest.approx(1.0)  # the longer side spans [0, 1]
    assert float(y.max()) == pytest.approx((h - 1) / (w - 1))  # the shorter one keeps the same px scale
    # one pixel step is the same length along y and x
    assert float(f.scale[0]) == pytest.approx(float(f.scale[1]))
    assert float(dd.min()) == pytest.approx(0.0, abs=1e-6)
    assert float(dd.max()) == pytest.approx(3.0)  # d min-max scaled, then times d_weight


def test_minmax_normalisation_scales_every_column_to_unit_range():
    h, w = 20, 50
    d = _ramp(h, w)
    valid = torch.zeros(h, w, dtype=torch.bool)
    valid[5:15, 10:40] = True  # min-max over the valid pixels only
    f = make_features(d, valid, normalize="minmax", d_weight=1.0)
    torch.testing.assert_close(f.x.amin(0), torch.zeros(3))
    torch.testing.assert_close(f.x.amax(0), torch.ones(3))
    g = make_features(d, valid, normalize="minmax", d_weight=0.5)
    assert float(g.x[:, 2].max()) == pytest.approx(0.5)
    torch.testing.assert_close(g.x[:, :2], f.x[:, :2])


def test_none_normalisation_keeps_pixel_units_and_weights_d():
    d = _ramp(6, 8)
    f = make_features(d, torch.ones(6, 8, dtype=torch.bool), normalize="none", d_weight=2.0,
                      dtype=torch.float64)
    expected = torch.cat([f.pixels.double(), 2.0 * d.flatten()[:, None]], dim=1)
    torch.testing.assert_close(f.x, expected)


def test_constant_disparity_gives_finite_features():
    d = torch.full((5, 6), 7.0)
    for mode in ("image", "minmax"):
        f = make_features(d, torch.ones(5, 6, dtype=torch.bool), normalize=mode)
        assert bool(torch.isfinite(f.x).all())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_output_dtype_follows_the_argument(dtype):
    f = make_features(_ramp(4, 4, torch.float32), torch.ones(4, 4, dtype=torch.bool), dtype=dtype)
    assert f.x.dtype == dtype and f.offset.dtype == dtype and f.scale.dtype == dtype


# ------------------------------------------------------------------------------- subsampling


def test_subsample_stride_10_on_a_720x1264_map_keeps_72x127_pixels():
    h, w = 720, 1264
    f = make_features(torch.ones(h, w), torch.ones(h, w, dtype=torch.bool))
    s = f.subsample(10)
    assert len(s) == 72 * 127 == 9144
    assert s.stride == 10
    assert bool((s.pixels % 10 == 0).all())


def test_subsample_keeps_exactly_the_grid_pixels():
    g = torch.Generator().manual_seed(3)
    h, w = 41, 67
    valid = torch.rand(h, w, generator=g) > 0.3
    f = make_features(_ramp(h, w), valid)
    for stride in (2, 3, 7):
        s = f.subsample(stride)
        expected = [[y, x] for y in range(h) for x in range(w)
                    if valid[y, x] and y % stride == 0 and x % stride == 0]
        assert s.pixels.tolist() == expected
        # the kept rows of x are the same rows as in the full set (same scaling)
        keep = (f.pixels[:, 0] % stride == 0) & (f.pixels[:, 1] % stride == 0)
        assert torch.equal(s.x, f.x[keep])
        assert torch.equal(s.offset, f.offset) and torch.equal(s.scale, f.scale)
        assert s.n_invalid == f.n_invalid and s.shape == f.shape


def test_subsample_strides_compose_and_stride_1_is_identity():
    f = make_features(_ramp(30, 40), torch.ones(30, 40, dtype=torch.bool))
    assert f.subsample(1) is f
    twice = f.subsample(2).subsample(5)
    assert twice.stride == 10
    assert torch.equal(twice.pixels, f.subsample(10).pixels)


@pytest.mark.parametrize("stride, error",
                         [(0, ValueError), (-3, ValueError), (2.5, TypeError), (True, TypeError)])
def test_subsample_rejects_bad_strides(stride, error):
    f = make_features(_ramp(4, 4), torch.ones(4, 4, dtype=torch.bool))
    with pytest.raises(error, match="stride"):
        f.subsample(stride)


# ------------------------------------------------------------------------------------ errors


@pytest.mark.parametrize("d", [torch.full((3, 3), NAN), torch.full((3, 3), -1.0), torch.full((3, 3), INF)])
def test_no_usable_pixel_is_a_value_error(d):
    with pytest.raises(ValueError, match="no valid"):
        make_features(d, torch.ones(3, 3, dtype=torch.bool))


def test_all_masked_is_a_value_error():
    with pytest.raises(ValueError, match="no valid"):
        make_features(torch.ones(3, 3), torch.zeros(3, 3, dtype=torch.bool))


def test_bad_shapes_and_dtypes_are_rejected_with_named_arguments():
    ok_d, ok_v = torch.ones(3, 4), torch.ones(3, 4, dtype=torch.bool)
    with pytest.raises(ValueError, match=r"valid has shape \(4, 3\).*\(3, 4\)"):
        make_features(ok_d, torch.ones(4, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="disparity must have 2 dimensions"):
        make_features(torch.ones(1, 3, 4), ok_v)
    with pytest.raises(TypeError, match="disparity must be a floating-point"):
        make_features(torch.ones(3, 4, dtype=torch.int32), ok_v)
    with pytest.raises(TypeError, match="valid has dtype"):
        make_features(ok_d, ok_v.to(torch.uint8))
    with pytest.raises(TypeError, match="disparity must be a torch.Tensor"):
        make_features(np.ones((3, 4)), ok_v)
    with pytest.raises(ValueError, match="normalize='zscore' is not known; valid names: image, minmax, none"):
        make_features(ok_d, ok_v, normalize="zscore")
    with pytest.raises(ValueError, match="d_weight"):
        make_features(ok_d, ok_v, d_weight=0.0)
    with pytest.raises(ValueError, match="d_weight"):
        make_features(ok_d, ok_v, d_weight=float("nan"))


def test_colour_features_append_ycbcr_times_their_weight():
    from somtorch.disparity.features import ycbcr

    d = torch.full((4, 5), 10.0)
    d[0, 0] = 20.0
    valid = torch.ones(4, 5, dtype=torch.bool)
    image = torch.zeros(3, 4, 5, dtype=torch.uint8)
    image[0] = 255  # pure red
    f = make_features(d, valid, image=image, color_weight=2.0)
    assert f.x.shape == (20, 6)
    y, cb, cr = ycbcr(torch.tensor([[255], [0], [0]], dtype=torch.uint8))[:, 0].tolist()
    assert f.x[0, 3:].tolist() == pytest.approx([2 * y, 2 * cb, 2 * cr], abs=1e-6)
    assert f.to_pixel_units(f.x)[0, 3:].tolist() == pytest.approx([y, cb, cr], abs=1e-6)
    assert torch.equal(f.x[:, :3], make_features(d, valid).x)  # (y, x, d) unchanged
    with pytest.raises(ValueError, match="needs the left image"):
        make_features(d, valid, color_weight=1.0)
