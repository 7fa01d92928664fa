"""The optional image-edge term of the salient ranking: a depth boundary that no edge of the left
image follows (a matching artefact) loses salience; an outlined object keeps it."""

from __future__ import annotations

import numpy as np
import torch

from somtorch.config import AreaConfig
from somtorch.tasks.detect import image_edges
from somtorch.tasks.ground import GroundPlane
from somtorch.tasks.objects import find_object_areas, neuron_stats, select_areas


def _scene():
    h, w = 80, 120
    labels = torch.zeros(h, w, dtype=torch.long)
    disp = torch.full((h, w), 10.0)
    labels[10:40, 10:40], disp[10:40, 10:40] = 1, 14.0  # nearer, but the image shows nothing there
    labels[40:70, 70:100], disp[40:70, 70:100] = 2, 13.0  # less near, a visible object
    img = np.full((h, w), 90, np.uint8)
    img[40:70, 70:100] = 200  # only area 2 has an outline in the image
    rng = np.random.default_rng(0)
    img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)  # sensor noise, no edges
    image = torch.from_numpy(np.stack([img] * 3))
    return labels, disp, image


def test_image_edges_follow_the_outline_only():
    _, _, image = _scene()
    near = image_edges(image)
    assert near.shape == (80, 120) and near.dtype == torch.bool
    assert bool(near[40, 85]) and bool(near[55, 70])  # on the drawn square's outline
    assert not bool(near[25, 25]) and not bool(near[10, 25])  # textureless where area 1's border is
    assert not bool(near[55, 85])  # inside the square, away from its outline


def test_edge_term_reorders_areas_only_when_switched_on():
    labels, disp, image = _scene()
    edges = image_edges(image)
    stats = neuron_stats(labels, disp, 3, edges=edges)
    assert stats.edge_boundary is not None
    assert bool((stats.edge_boundary <= stats.boundary).all())
    assert float(stats.edge_boundary[0, 2]) > 0.9 * float(stats.boundary[0, 2])  # outlined border
    assert float(stats.edge_boundary[0, 1]) < 0.1 * float(stats.boundary[0, 1])  # not outlined
    ref = torch.tensor([10.0, 14.0, 13.0])
    pick = AreaConfig(max_areas=2)
    plain = select_areas(find_object_areas(ref, None, stats, AreaConfig(similarity=0.01)), stats, pick)
    assert [a.neurons for a in plain] == [[1], [2]]  # depth contrast alone: the artefact first
    cfg = AreaConfig(similarity=0.01, edge_rank=1.0)
    areas = find_object_areas(ref, None, stats, cfg)
    assert [a.neurons for a in select_areas(areas, stats, pick)] == [[2], [1]]
    by = {tuple(a.neurons): a for a in areas}
    assert by[(2,)].salience == by[(2,)].contrast  # better outlined than the map: unchanged (capped at 1)
    assert by[(1,)].salience < 0.2 * by[(1,)].contrast


def test_ground_plane_disparity_is_computed_once_per_size():
    g = GroundPlane(0.01, 0.2, 1.0, 0.5, torch.zeros(4, 5, dtype=torch.bool), 0.3)
    a = g.disparity(40, 50)
    assert g.disparity(40, 50) is a  # cached
    assert float(a[10, 20]) == float(torch.tensor(0.01 * 20 + 0.2 * 10 + 1.0, dtype=torch.float64).float())
    b = g.disparity(20, 25)
    assert b.shape == (20, 25) and g.disparity(40, 50) is not a  # another size replaced the cache
    assert torch.equal(g.disparity(40, 50), a)
