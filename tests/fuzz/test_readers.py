"""Seeded mutation fuzzing of every reader (issue 14) and of the decompression bombs of issue 34.

Each case mutates a small valid file (flipped and inserted bytes, truncation, spliced chunks, text
headers with huge or non-numeric values, random bytes) and calls the reader. It must return a valid
result or raise a documented error — a ``ValueError`` / ``OSError`` (``DataFileError`` is both a
``SomtorchError`` and a ``ValueError``) whose message names the file (no time bound: timings belong in benchmarks/). The
normal suite runs ``FUZZ_CASES`` cases per reader (default 2,000); ``pytest -m fuzz`` runs 20,000.
"""

from __future__ import annotations

import json
import os
import random
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

import somtorch.disparity.headers as headers
from somtorch import SOM
from somtorch.disparity.camera import _oakd_camera, read_middlebury_camera
from somtorch.disparity.io import read_disparity, read_image, read_json, read_mask, write_pfm
from somtorch.disparity.labels import read_polygon_labels
from somtorch.disparity.loading import load_scene
from somtorch.disparity.stereo import SGBMParams, load_stereo_pair
from tests.fuzz import bombs

CASES = int(os.environ.get("FUZZ_CASES", 2000))


def _seeds(tmp: Path) -> dict[str, Path]:
    """One small valid file per reader."""
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 40, (12, 16)).astype(np.float32)
    files = {}
    files["pfm"] = write_pfm(tmp / "s.pfm", d)
    cv2.imwrite(str(tmp / "s16.png"), (d * 256).astype(np.uint16))
    files["png16"] = tmp / "s16.png"
    cv2.imwrite(str(tmp / "s8.png"), rng.integers(0, 255, (12, 16, 3), dtype=np.uint8))
    files["png8"] = tmp / "s8.png"
    cv2.imwrite(str(tmp / "mask.png"), rng.integers(0, 3, (12, 16), dtype=np.uint8))
    files["mask"] = tmp / "mask.png"
    cv2.imwrite(str(tmp / "s.tif"), d)
    files["tiff"] = tmp / "s.tif"
    np.save(tmp / "s.npy", d)
    files["npy"] = tmp / "s.npy"
    np.savez_compressed(tmp / "s.npz", disparity=d)
    files["npz"] = tmp / "s.npz"
    (tmp / "calib.txt").write_text("cam0=[1000.5 0 300.25; 0 1000.5 200.75; 0 0 1]\n"
                                   "cam1=[1000.5 0 330.25; 0 1000.5 200.75; 0 0 1]\ndoffs=30.0\nbaseline=193.0\n"
                                   "width=16\nheight=12\nndisp=128\n")
    files["calib"] = tmp / "calib.txt"
    (tmp / "stereodemo_calibration.json").write_text(json.dumps(
        {"width": 16, "height": 12, "fx": 451.0, "cx0": 8.0, "cx1": 9.0, "cy": 6.0, "baseline_meters": 0.075}))
    files["oakd"] = tmp / "stereodemo_calibration.json"
    (tmp / "objects.json").write_text(json.dumps({"objects": [{"id": 1, "name": "a", "main": True}]}))
    files["json"] = tmp / "objects.json"
    # a stereo pair (right image mutated) and a scene folder (its objects.json mutated)
    left = rng.integers(0, 255, (12, 48, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp / "left.png"), left)
    cv2.imwrite(str(tmp / "right.png"), np.roll(left, -3, axis=1))
    files["stereo"] = tmp / "right.png"
    scene = tmp / "scene"
    scene.mkdir()
    write_pfm(scene / "disp0GT.pfm", d)
    cv2.imwrite(str(scene / "objects.png"), (d > 20).astype(np.uint8))
    (scene / "objects.json").write_text(json.dumps({"objects": [{"id": 1, "name": "a", "main": True}]}))
    files["scene"] = scene / "objects.json"
    (tmp / "labels.json").write_text(json.dumps({"size_hw": [12, 16], "objects": [
        {"id": 1, "name": "a", "main": True, "polygons": [[[1, 1], [10, 1], [10, 8], [1, 8]]]}]}))
    files["labels"] = tmp / "labels.json"
    # the reproducers of issue 34, small: each claims 4-8 MB from a few kB
    files["npz_bomb"] = bombs.npz_zeros(tmp / "zeros.npz", 1000, 1000)
    files["png_bomb"] = bombs.png16(tmp / "bomb.png", 2000, 2000)
    files["tiff_bomb"] = bombs.tiff_striped(tmp / "bomb.tif", 1000, 1000)
    files["png_overrun"] = bombs.png16(tmp / "overrun.png", 100, 100, inflated=20_000_000)
    som = SOM(2, 3, 3, ensemble=2, seed=0)
    som.weight = torch.rand(2, 6, 3, generator=torch.Generator().manual_seed(0))
    files["checkpoint"] = som.save(tmp / "m.safetensors")
    return files


def _mutate(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    kind = rng.randrange(8)
    if kind == 0 and b:  # flip bytes
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif kind == 1:  # truncate
        b = b[:rng.randrange(len(b) + 1)]
    elif kind == 2:  # insert random bytes
        i = rng.randrange(len(b) + 1)
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 32)))
    elif kind == 3 and b:  # duplicate or drop a chunk
        i, j = sorted(rng.randrange(len(b) + 1) for _ in range(2))
        b = b[:i] + b[i:j] * rng.randint(0, 3) + b[j:]
    elif kind == 4:  # numbers in the text parts made huge, negative or not numbers
        text = bytes(b).decode("latin-1")
        digits = [i for i, c in enumerate(text) if c.isdigit()]
        if digits:
            i = rng.choice(digits)
            text = text[:i] + rng.choice(["9" * rng.randint(5, 40), "-", "nan", "1e999", "x", "0", "-1"]) + text[i + 1:]
        b = bytearray(text.encode("latin-1"))
    elif kind == 5:  # random bytes of random length
        b = bytearray(rng.randbytes(rng.randint(0, 300)))
    elif kind == 6 and b:  # bit flips in the first 64 bytes (headers)
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(min(64, len(b)))
            b[i] ^= 1 << rng.randrange(8)
    else:  # JSON-ish splices
        b += rng.choice([b"[" * 5000, b'{"a":', b"\x00" * 50, b"]]]"])
    return bytes(b)


READERS = {
    "pfm": lambda p: read_disparity(p),
    "png16": lambda p: read_disparity(p),
    "png8": lambda p: read_image(p),
    "mask": lambda p: read_mask(p),
    "npy": lambda p: read_disparity(p),
    "tiff": lambda p: read_disparity(p),
    "npz": lambda p: read_disparity(p),
    "npz_bomb": lambda p: read_disparity(p),
    "png_bomb": lambda p: read_disparity(p),
    "tiff_bomb": lambda p: read_disparity(p),
    "png_overrun": lambda p: read_disparity(p),
    "calib": lambda p: read_middlebury_camera(p),
    "oakd": lambda p: _oakd_camera(p.parent, (12, 16)),
    "json": lambda p: read_json(p),
    "checkpoint": lambda p: SOM.load(p),
    "stereo": lambda p: load_stereo_pair(p.parent / "left.png", p, SGBMParams(numDisparities=16, blockSize=3)),
    "scene": lambda p: load_scene(p.parent),
    "labels": lambda p: read_polygon_labels(p, (12, 16)),
}


def _check_result(kind: str, out) -> None:
    """A returned result must be sound."""
    if kind in ("pfm", "png16", "npy", "npz", "tiff") or kind.endswith(("_bomb", "_overrun")):
        disp, valid = out
        assert disp.shape == valid.shape and disp.dtype == torch.float32 and valid.dtype == torch.bool
        assert bool(torch.isfinite(disp).all()) and bool((disp[valid] >= 0).all())
    elif kind in ("stereo", "scene"):
        assert out.disparity.shape == out.valid.shape and bool(torch.isfinite(out.disparity).all())
    elif kind == "labels":
        objects, info = out
        assert objects.shape == (12, 16) and {o.id for o in info} >= set(objects.unique().tolist()) - {0}
    elif kind == "checkpoint":
        assert bool(torch.isfinite(out.weight).all()) and out.weight.shape[1] == out.rows * out.cols


def _fuzz(kind: str, cases: int, tmp_path: Path, monkeypatch) -> dict[str, int]:
    monkeypatch.setattr(headers, "MAX_PIXELS", 10_000_000)  # small limit: a case may never allocate much
    seed_file = _seeds(tmp_path)[kind]
    original = seed_file.read_bytes()
    rng = random.Random(f"{kind}-{cases}")
    counts = {"ok": 0, "error": 0}
    for case in range(cases):
        data = _mutate(original, rng)
        seed_file.write_bytes(data)
        try:  # no time bound: a loaded CI machine is not a failing reader
            out = READERS[kind](seed_file)
        except (ValueError, OSError) as e:
            assert seed_file.name in str(e), f"case {case}: {type(e).__name__} without the file name: {e}"
            counts["error"] += 1
        except Exception as e:  # noqa: BLE001 - what the test is for
            pytest.fail(f"{kind} case {case}: undocumented {type(e).__name__}: {e} (input {data[:80]!r})")
        else:
            _check_result(kind, out)
            counts["ok"] += 1
    seed_file.write_bytes(original)
    assert counts["ok"] + counts["error"] == cases
    return counts


@pytest.mark.parametrize("kind", list(READERS))
def test_reader_survives_mutations(kind, tmp_path, monkeypatch):
    counts = _fuzz(kind, CASES, tmp_path, monkeypatch)
    assert counts["error"] > 0  # the mutations do reach the checks


@pytest.mark.fuzz
@pytest.mark.parametrize("kind", list(READERS))
def test_reader_survives_20000_mutations(kind, tmp_path, monkeypatch):
    _fuzz(kind, 20_000, tmp_path, monkeypatch)
