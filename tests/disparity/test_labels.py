"""Polygon label files: rasterised exactly, lower id wins, every malformed field named."""

from __future__ import annotations

import json

import pytest
import torch

from somtorch.disparity.labels import read_polygon_labels
from somtorch.validation import DataFileError


def _write(tmp_path, objects, **extra):
    p = tmp_path / "labels.json"
    p.write_text(json.dumps({"objects": objects, **extra}))
    return p


def test_square_polygon_fills_its_pixels(tmp_path):
    p = _write(tmp_path, [{"id": 1, "name": "box", "main": True, "polygons": [[[2, 3], [6, 3], [6, 5], [2, 5]]]}],
               size_hw=[10, 12])
    objects, info = read_polygon_labels(p, (10, 12))
    assert objects.dtype == torch.int64 and objects.shape == (10, 12)
    assert int((objects == 1).sum()) == 5 * 3  # columns 2..6, rows 3..5 inclusive
    assert bool((objects[3:6, 2:7] == 1).all())
    assert info[0].name == "box" and info[0].main


def test_overlapping_pieces_of_one_object_unite_and_do_not_cancel(tmp_path):
    a = [[2, 2], [8, 2], [8, 8], [2, 8]]
    b = [[5, 5], [12, 5], [12, 12], [5, 12]]  # overlaps a in [5..8] x [5..8]
    holes = [[[3, 3], [6, 3], [6, 6], [3, 6]], [[4, 4], [7, 4], [7, 7], [4, 7]]]  # overlapping exclusions
    p = _write(tmp_path, [{"id": 1, "name": "two_pieces", "polygons": [a, b], "exclude": holes}], size_hw=[16, 16])
    objects, _ = read_polygon_labels(p, (16, 16))
    # the pieces' overlap outside the holes stays filled (one fillPoly call would cancel it)
    assert int(objects[8, 8]) == 1 and int(objects[8, 5]) == 1 and int(objects[5, 8]) == 1
    assert int(objects[12, 12]) == 1 and int(objects[2, 2]) == 1
    assert bool((objects[3:7, 3:7] == 0).all()) and bool((objects[4:8, 4:8] == 0).all())  # both holes cut


def test_overlap_goes_to_the_lower_id_and_exclusions_cut(tmp_path):
    p = _write(tmp_path, [
        {"id": 2, "name": "back", "polygons": [[[0, 0], [9, 0], [9, 9], [0, 9]]]},
        {"id": 1, "name": "front", "main": True, "polygons": [[[2, 2], [5, 2], [5, 5], [2, 5]]],
         "exclude": [[[3, 3], [4, 3], [4, 4], [3, 4]]]},
    ])
    objects, info = read_polygon_labels(p, (10, 10))
    assert int((objects == 1).sum()) == 16 - 4
    assert bool((objects[3:5, 3:5] == 2).all())  # the gap shows what lies behind
    assert int((objects == 2).sum()) == 100 - 12
    assert [o.id for o in info] == [2, 1]


@pytest.mark.parametrize("objects, extra, field", [
    ([{"id": 1, "polygons": [[[0, 0], [20, 0], [5, 5]]]}], {}, "outside"),
    ([{"id": 1, "polygons": [[[0, 0], [5, 0]]]}], {}, "polygons[0]"),
    ([{"id": 0, "polygons": [[[0, 0], [5, 0], [5, 5]]]}], {}, ".id"),
    ([{"id": 1, "polygons": [[[0, 0], [5, 0], [5, 5]]]}, {"id": 1, "polygons": [[[0, 0], [5, 0], [5, 5]]]}], {},
     "used twice"),
    ([{"id": 1, "polygons": [[[0, 0], ["a", 0], [5, 5]]]}], {}, "polygons[0]"),
    ([], {}, "'objects'"),
    ([{"id": 1, "polygons": [[[0, 0], [5, 0], [5, 5]]]}], {"size_hw": [8, 8]}, "size_hw"),
    ([{"id": 1, "polygons": [[[0, 0], [9, 0], [9, 9], [0, 9]]]}, {"id": 2, "polygons": [[[1, 1], [2, 1], [2, 2]]]}],
     {}, "wholly covered"),
])
def test_malformed_files_name_the_field(tmp_path, objects, extra, field):
    p = _write(tmp_path, objects, **extra)
    with pytest.raises(DataFileError, match="labels.json") as e:
        read_polygon_labels(p, (10, 10))
    assert field in str(e.value)


def test_repository_labels_fit_their_scenes(shared_data):
    """The labels of conf/labels: each object lies mostly on valid disparity and the main one is
    the one of most valid pixels among those that are not mostly in the no-disparity columns."""
    from experiments.datasets import frames, load_frame

    specs = [s for s in frames(synthetic=False) if s.labels and s.disparity == "gt"]
    assert len(specs) >= 4
    for spec in specs:
        scene = load_frame(spec, shared_data)
        assert scene.main_object_mask is not None and sum(o.main for o in scene.object_info) == 1
        for o in scene.object_info:
            m = scene.object_mask(o.id)
            share = float((m & scene.valid).sum()) / float(m.sum())
            assert share > 0.35, (spec.name, o.name, share)
        main = scene.main_object_mask
        assert float((main & scene.valid).sum()) / float(main.sum()) > 0.5


def test_ids_above_255_and_huge_ids(tmp_path):
    """Found by the fuzzer: ids beyond uint8 must not wrap, ids beyond int32 are refused."""
    p = _write(tmp_path, [{"id": 300, "name": "big", "polygons": [[[0, 0], [3, 0], [3, 3], [0, 3]]]}])
    objects, _ = read_polygon_labels(p, (10, 10))
    assert int(objects.max()) == 300
    p = _write(tmp_path, [{"id": 10 ** 30, "polygons": [[[0, 0], [3, 0], [3, 3]]]}])
    with pytest.raises(DataFileError, match="id must be an integer"):
        read_polygon_labels(p, (10, 10))
