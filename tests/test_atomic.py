"""Tests of somtorch.atomic: a target is either absent/old or complete, never half-written."""

from __future__ import annotations

import json
import math
import os
import stat

import pytest

from somtorch.atomic import atomic_path, write_bytes, write_json


class _Boom(RuntimeError):
    pass


def test_atomic_path_moves_the_temporary_file_onto_the_target(tmp_path):
    target = tmp_path / "sub" / "out.txt"  # missing folders are created
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp != target
        assert tmp.suffix == ".txt"  # writers that dispatch on the suffix still work
        tmp.write_text("complete")
        assert not target.exists()  # nothing visible before the body finishes
    assert target.read_text() == "complete"
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.txt"]


@pytest.mark.parametrize("error", [_Boom, KeyboardInterrupt])
def test_atomic_path_leaves_no_file_when_the_body_raises(tmp_path, error):
    target = tmp_path / "out.bin"
    with pytest.raises(error):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise error()
    assert list(tmp_path.iterdir()) == []  # neither the target nor the temporary file


def test_atomic_path_keeps_the_old_file_when_the_body_raises(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(_Boom):
        with atomic_path(target) as tmp:
            tmp.write_text("new but broken")
            raise _Boom()
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_atomic_path_replaces_an_existing_file(tmp_path):
    target = write_bytes(tmp_path / "a.bin", b"one")
    write_bytes(target, b"two")
    assert target.read_bytes() == b"two"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_atomic_files_get_the_same_permissions_as_plain_files(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    atomic = write_bytes(tmp_path / "atomic.txt", b"x")
    assert stat.S_IMODE(os.stat(atomic).st_mode) == stat.S_IMODE(os.stat(plain).st_mode)


def test_write_json_round_trips_with_sorted_keys(tmp_path):
    obj = {"b": [1, 2.5, None, True], "a": {"z": "text", "y": -3}}
    path = write_json(tmp_path / "m.json", obj)
    text = path.read_text()
    assert json.loads(text) == obj
    assert text.index('"a"') < text.index('"b"') and text.endswith("\n")


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_write_json_rejects_non_finite_numbers_and_writes_nothing(tmp_path, bad):
    with pytest.raises(ValueError, match="JSON compliant"):
        write_json(tmp_path / "m.json", {"ok": 1.0, "nested": [bad]})
    assert list(tmp_path.iterdir()) == []


def test_write_json_failure_keeps_the_previous_file(tmp_path):
    path = write_json(tmp_path / "m.json", {"run": 1})
    with pytest.raises(TypeError):
        write_json(path, {"run": object()})  # not serialisable
    assert json.loads(path.read_text()) == {"run": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]


def test_checkpoints_get_the_usual_file_mode(tmp_path):
    import os
    import stat

    import torch

    from somtorch import SOM
    from somtorch.atomic import _UMASK

    path = SOM(2, 2, 3).save(tmp_path / "m.safetensors")
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o666 & ~_UMASK
    assert stat.S_IMODE(os.stat(path.with_suffix(".json")).st_mode) == 0o666 & ~_UMASK
    assert torch.equal(SOM.load(path).weight, torch.zeros(1, 4, 3))


def test_write_staged_moves_everything_in_with_the_last_entry_last(tmp_path):
    import json

    from somtorch.atomic import write_staged

    write_staged(tmp_path, {"a.md": b"table\n", "metrics.json": {"x": 1}})
    assert (tmp_path / "a.md").read_bytes() == b"table\n"
    assert json.loads((tmp_path / "metrics.json").read_text()) == {"x": 1}
    assert not list(tmp_path.glob(".partial-*"))
    with pytest.raises(ValueError):  # NaN is not JSON: nothing lands, no staging folder stays
        write_staged(tmp_path / "bad", {"a.md": b"x", "metrics.json": {"x": float("nan")}})
    assert not list((tmp_path / "bad").iterdir())
