"""Linking segments by depth continuity across their shared boundary (``objects.link="continuity"``).

The maps are built by hand so that the answer is known: a ramp cut into strips (continuous at every
strip boundary, though each strip's mean disparity differs), a box standing in front of a wall (a
step at its outline), a staircase of small steps.
"""

from __future__ import annotations

import pytest
import torch

from somtorch.tasks.detect import MapContext, find_objects
from somtorch.tasks.objects import (AreaConfig, continuity_links, continuous_step, find_object_areas, neuron_stats,
                                    select_areas)

CONT = AreaConfig(link="continuity")
STEP = (CONT.step_frac, CONT.step_px)


def _reference_continuous(labels: torch.Tensor, disp: torch.Tensor, k: int) -> torch.Tensor:
    """Pixel by pixel: continuous 4-connected pairs between different valid segments, symmetric."""
    out = torch.zeros(k, k, dtype=torch.float64)
    h, w = labels.shape
    for y in range(h):
        for x in range(w):
            for yy, xx in ((y, x + 1), (y + 1, x)):
                if yy >= h or xx >= w:
                    continue
                a, b = int(labels[y, x]), int(labels[yy, xx])
                if a < 0 or b < 0 or a == b:
                    continue
                da, db = float(disp[y, x]), float(disp[yy, xx])
                if abs(da - db) <= max(STEP[1], STEP[0] * max(da, db)):
                    out[a, b] += 1
                    out[b, a] += 1
    return out


def test_boundary_continuity_counts_match_a_pixel_by_pixel_reference():
    g = torch.Generator().manual_seed(0)
    labels = torch.randint(-1, 6, (23, 31), generator=g)
    disp = 10 + 20 * torch.rand(23, 31, generator=g, dtype=torch.float64)
    stats = neuron_stats(labels, disp, 6, step=STEP)
    assert torch.equal(stats.continuous, _reference_continuous(labels, disp, 6))
    assert bool((stats.continuous <= stats.boundary).all()) and stats.continuous.sum() > 0
    assert neuron_stats(labels, disp, 6).continuous is None  # not asked, not computed


def test_continuous_step_is_relative_to_disparity_with_a_floor():
    a = torch.tensor([100.0, 100.0, 5.0, 5.0])
    b = torch.tensor([104.0, 106.0, 5.9, 6.5])
    assert continuous_step(a, b, 0.05, 1.0).tolist() == [True, False, True, False]


def _ramp_and_box(h: int = 60, w: int = 80) -> tuple[torch.Tensor, torch.Tensor]:
    """A floor-like ramp (disparity 10 → 40 from top to bottom) cut into 6 horizontal strips, and a box
    (disparity 60, segment 6) standing in front of it."""
    ys = torch.arange(h, dtype=torch.float64)[:, None].expand(h, w)
    disp = 10 + 30 * ys / (h - 1)
    labels = (torch.arange(h)[:, None] * 6 // h).expand(h, w).clone()
    labels[20:40, 30:50] = 6
    disp = disp.clone()
    disp[20:40, 30:50] = 60.0
    return labels, disp


def test_a_ramp_cut_into_strips_is_one_area_and_a_box_in_front_of_it_another():
    labels, disp = _ramp_and_box()
    stats = neuron_stats(labels, disp, 7, step=STEP)
    ref = stats.mean_d
    areas = find_object_areas(ref, None, stats, CONT)
    groups = sorted(sorted(a.neurons) for a in areas)
    assert groups == [[0, 1, 2, 3, 4, 5], [6]], groups
    # the similarity rule cuts the same ramp into parts: its strips' means differ by 6 px each
    sim = find_object_areas(ref, None, stats, AreaConfig(link="image", similarity=0.05))
    assert max(len(a.neurons) for a in sim) < 6
    assert bool(continuity_links(stats, CONT)[0, 1]) and not bool(continuity_links(stats, CONT)[2, 6])


def test_the_geometric_rank_prefers_a_big_near_area_inside_the_frame():
    labels, disp = _ramp_and_box()
    stats = neuron_stats(labels, disp, 7, step=STEP)
    areas = find_object_areas(stats.mean_d, None, stats, CONT)
    ranked = select_areas(areas, stats, AreaConfig(link="continuity", select="geometric", max_area_frac=1.0))
    assert ranked[0].neurons == [6]  # the box: in front, not touching the frame
    box = next(a for a in areas if a.neurons == [6])
    ramp = next(a for a in areas if 0 in a.neurons)
    assert box.frame_contact == 0.0 and ramp.frame_contact > 0.3


def test_the_contrast_rule_decides_when_continuity_finds_nothing_and_it_is_flagged():
    # one smooth surface everywhere: continuity links all segments into one area covering the map,
    # which max_area_frac refuses; the fallback (image link, salient rank) has the last word
    h, w = 40, 60
    xs = torch.arange(w, dtype=torch.float64)[None, :].expand(h, w)
    disp = (20 + 0.2 * xs).clone()
    labels = (torch.arange(w)[None, :] * 5 // w).expand(h, w).clone()
    valid = torch.ones(h, w, dtype=torch.bool)
    cfg = AreaConfig(link="continuity")
    ctx = MapContext.build(disp, valid, valid, None, cfg)
    res = find_objects(labels, torch.tensor([21.0, 23.0, 25.0, 27.0, 29.0]), None, ctx, cfg)
    assert res.fallback
    plain = find_objects(labels, torch.tensor([21.0, 23.0, 25.0, 27.0, 29.0]), None, ctx, AreaConfig(link="image"))
    assert not plain.fallback
    assert [a.box for a in res.kept] == [a.box for a in plain.kept] and res.no_object == plain.no_object


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 1)])
def test_tiny_and_degenerate_maps_never_crash(shape):
    labels = torch.zeros(shape, dtype=torch.long)
    disp = torch.full(shape, 3.0, dtype=torch.float64)
    stats = neuron_stats(labels, disp, 1, step=STEP)
    assert stats.continuous.shape == (1, 1) and float(stats.continuous.sum()) == 0.0
    assert len(find_object_areas(torch.tensor([3.0]), None, stats, CONT)) == 1


def test_an_object_that_is_all_the_ground_cut_leaves_is_kept():
    # a floor (not segmented: the ground plane) fills 80 % of the map; a staircase of 4 steps, each
    # its own segment and continuous with the next, is everything else. Its size is a share of the
    # valid pixels (20 %), not of the segmented ones (100 %), so max_area_frac does not refuse it.
    h, w = 50, 100
    labels = torch.full((h, w), -1, dtype=torch.long)
    disp = torch.full((h, w), 5.0, dtype=torch.float64)
    ys = torch.arange(10, 30, dtype=torch.float64)[:, None]
    disp[10:30, 40:90] = 10 + 0.5 * (ys - 10)  # a ramp of steps, continuous
    for i in range(4):
        labels[10 + 5 * i:15 + 5 * i, 40:90] = i
    valid = torch.ones(h, w, dtype=torch.bool)
    cfg = AreaConfig(link="continuity", select="geometric", min_purity=0.0, min_solidity=0.0)
    ctx = MapContext.build(disp, valid, labels >= 0, None, cfg)
    res = find_objects(labels, torch.tensor([11.0, 13.5, 16.0, 18.5]), None, ctx, cfg)
    assert not res.no_object and not res.fallback
    assert sorted(res.kept[0].neurons) == [0, 1, 2, 3] and res.kept[0].area_frac == pytest.approx(0.2)
    assert res.kept[0].box == (40, 10, 89, 29)


def test_a_segment_straddling_a_depth_edge_links_by_similarity_instead():
    # segment 1 straddles the edge between a wall (d 20, segment 0) and a box (d 40, segment 2): it
    # is continuous with both, so continuity alone chains wall and box; with ``coherent`` its inner
    # edge marks it torn, and its links fall back to the similarity rule
    h, w = 30, 90
    disp = torch.full((h, w), 20.0, dtype=torch.float64)
    disp[:, 45:] = 40.0
    labels = torch.zeros(h, w, dtype=torch.long)
    labels[:, 30:60] = 1
    labels[:, 60:] = 2
    stats = neuron_stats(labels, disp, 3, step=STEP)
    assert stats.inner_edge.tolist() == [0.0, float(h), 0.0]
    chained = find_object_areas(stats.mean_d, None, stats, AreaConfig(link="continuity"))
    assert len(chained) == 1
    split = find_object_areas(stats.mean_d, None, stats, AreaConfig(link="continuity", coherent=True))
    assert sorted(sorted(a.neurons) for a in split) == [[0], [1], [2]]
