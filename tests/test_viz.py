"""Tests of somtorch.viz: PNG writing and the pictures of the pipeline, read back from real files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from somtorch import viz


def _rgb(h: int = 24, w: int = 32, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _turbo(g: int) -> np.ndarray:
    """RGB colour of grey level ``g`` in OpenCV's TURBO map."""
    return cv2.cvtColor(cv2.applyColorMap(np.uint8([[g]]), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)[0, 0]


def test_save_png_round_trips_rgb_through_cv2(tmp_path):
    img = _rgb()
    path = viz.save_png(img, tmp_path / "a.png")
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.shape == img.shape and back.dtype == np.uint8
    np.testing.assert_array_equal(cv2.cvtColor(back, cv2.COLOR_BGR2RGB), img)  # RGB in, RGB out
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


def test_save_png_round_trips_grey(tmp_path):
    img = _rgb()[..., 0]
    back = cv2.imread(str(viz.save_png(img, tmp_path / "g.png")), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(back, img)


def test_save_png_rejects_non_uint8_and_writes_nothing(tmp_path):
    with pytest.raises(TypeError, match="uint8"):
        viz.save_png(np.zeros((4, 4, 3), np.float32), tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []


def test_colorize_uses_the_range_and_blacks_out_invalid_pixels():
    v = torch.tensor([[0.0, 5.0, 10.0], [float("nan"), 2.0, 7.0]])
    valid = torch.tensor([[True, True, True], [True, False, True]])
    rgb = viz.colorize(v, valid)
    assert rgb.shape == (2, 3, 3) and rgb.dtype == np.uint8
    assert (rgb[1, 0] == 0).all() and (rgb[1, 1] == 0).all()  # NaN and masked
    np.testing.assert_array_equal(rgb[0, 0], _turbo(0))
    np.testing.assert_array_equal(rgb[0, 2], _turbo(255))
    fixed = viz.colorize(v, valid, lo=0.0, hi=20.0)  # explicit range: 10 is mid-scale
    np.testing.assert_array_equal(fixed[0, 2], _turbo(127))
    assert (viz.colorize(v, torch.zeros(2, 3, dtype=torch.bool)) == 0).all()


def test_grey_is_brighter_for_nearer_pixels_and_black_where_invalid():
    v = torch.tensor([[1.0, 2.0, 3.0, float("nan")]])
    g = viz.grey(v)
    assert g.shape == (1, 4, 3) and (g[..., 0] == g[..., 1]).all() and (g[..., 0] == g[..., 2]).all()
    assert g[0, 0, 0] == 40 and g[0, 2, 0] == 255 and g[0, 0, 0] < g[0, 1, 0] < g[0, 2, 0]
    assert (g[0, 3] == 0).all()


def test_draw_areas_tints_kept_segments_and_draws_boxes_without_touching_the_input():
    back = np.full((40, 50, 3), 100, np.uint8)
    labels = torch.zeros(40, 50, dtype=torch.long)
    labels[10:20, 10:20] = 3
    obj = torch.zeros(40, 50, dtype=torch.bool)
    obj[12:18, 12:18] = True
    out = viz.draw_areas(back, labels, [[3]], [(5, 5, 30, 30)], obj)
    assert out.shape == back.shape and out.dtype == np.uint8
    assert (back == 100).all()
    assert tuple(out[5, 15]) == (255, 255, 0)  # box edge in yellow
    assert tuple(out[14, 14]) != (100, 100, 100)  # tinted kept segment
    assert tuple(out[35, 45]) == (100, 100, 100)  # untouched background
    assert (out[:, :, 1] == 255).any()  # object outline in green


def test_draw_reference_vectors_draws_on_a_copy():
    back = np.zeros((60, 80, 3), np.uint8)
    ref = torch.tensor([[10.0, 10.0, 1.0], [10.0, 60.0, 2.0], [50.0, 10.0, 3.0], [50.0, 60.0, 4.0]])
    grid_d2 = torch.tensor([[0.0, 1, 1, 2], [1, 0, 2, 1], [1, 2, 0, 1], [2, 1, 1, 0]])
    out = viz.draw_reference_vectors(back, ref, grid_d2)
    assert (back == 0).all() and out.shape == back.shape
    assert out[10, 10].any() and out[50, 60].any()  # a dot at each neuron's (x, y)
    assert out[10, 35].any()  # the line between grid neighbours 0 and 1
    assert not out[30, 35].any()  # no line across the diagonal 0–3


def test_image_or_disparity():
    img = torch.randint(0, 256, (3, 5, 7), dtype=torch.uint8)
    ok = torch.ones(5, 7, dtype=torch.bool)
    np.testing.assert_array_equal(viz.image_or_disparity(img, torch.zeros(5, 7), ok),
                                  img.permute(1, 2, 0).numpy())
    d = torch.arange(35.0).view(5, 7)
    np.testing.assert_array_equal(viz.image_or_disparity(None, d, ok), viz.grey(d))


@pytest.mark.parametrize("fraction, text", [(0.9980125606169011, "99.8 %"), (0.99996, "99.9 %"), (1.0, "100 %"),
                                            (0.29, "29.0 %"), (0.0, "0.0 %")])
def test_identified_percent_never_rounds_up_to_complete(fraction, text):
    from somtorch.viz import identified_percent

    assert identified_percent(fraction) == text


def test_summary_legends_sit_below_the_x_labels_of_a_wide_map():
    """A KITTI-like strip (741 x 170): the legends under (d) and (e) do not cover the x label."""
    from somtorch.disparity import load_scene
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.pipeline import run_pipeline
    from somtorch.viz import draw_summary

    full = load_scene("motorcycle")
    scene = scene_from_arrays(full.disparity[240:410], full.valid[240:410], name="strip")
    fig = draw_summary(scene, run_pipeline(scene, metrics=False))
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    for ax in fig.axes[:6]:
        if ax.get_legend() is not None:
            legend, label = ax.get_legend().get_window_extent(r), ax.xaxis.label.get_window_extent(r)
            assert legend.y1 <= label.y0, (ax.get_title(), legend, label)
    import matplotlib.pyplot as plt

    plt.close(fig)
