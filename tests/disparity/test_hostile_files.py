"""Regression tests from the reproducers of issue 14: hostile files give a DataFileError naming the
file, before any large allocation, never a raw exception or a wrong result."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from somtorch import SOM, DataFileError
from somtorch.disparity.io import read_disparity, read_json


@pytest.mark.parametrize("name, data", [
    ("b.npz", b"PK\x03\x04" + bytes(100)),         # a zip header and nothing else
    ("b.npy", b"\x93NUMPY\x01\x00" + b"{'descr'"),  # a truncated header
    ("c.npz", b"garbage" * 10),
])
def test_corrupt_npy_and_npz_are_data_file_errors(tmp_path, name, data):
    p = tmp_path / name
    p.write_bytes(data)
    with pytest.raises(DataFileError, match=name):
        read_disparity(p)


def test_an_npz_named_npy_is_refused_with_the_fix(tmp_path):
    p = tmp_path / "z.npz"
    np.savez(p, disparity=np.ones((3, 4)))
    q = tmp_path / "z.npy"
    q.write_bytes(p.read_bytes())
    with pytest.raises(DataFileError, match="rename it to .npz"):
        read_disparity(q)


def test_float64_beyond_float32_is_invalid_not_infinite(tmp_path):
    p = tmp_path / "b.npy"
    np.save(p, np.array([[1.0, 1e300], [2.0, 3.0]]))
    disp, valid = read_disparity(p)
    assert valid.tolist() == [[True, False], [True, True]]
    assert bool(torch.isfinite(disp).all()) and disp[0, 0] == 1.0


def test_deeply_nested_or_huge_json_names_the_file(tmp_path):
    p = tmp_path / "deep.json"
    p.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(DataFileError, match="deep.json.*nested too deeply"):
        read_json(p)
    q = tmp_path / "big.json"
    q.write_text('{"a": ' + "9" * 5000 + "}")
    with pytest.raises(DataFileError, match="big.json"):
        read_json(q)


def test_checkpoint_metadata_is_checked_against_the_stored_tensor_before_building(tmp_path):
    p = tmp_path / "som.safetensors"
    cfg = {"format": "somtorch.som/1", "rows": 2000, "cols": 2000, "dim": 3, "ensemble": 1, "topology": "rectangular",
           "toroidal": False, "seeds": [0], "dtype": "float32"}
    save_file({"weight": torch.zeros(1, 4, 3)}, str(p), metadata={"config": json.dumps(cfg)})
    with pytest.raises(DataFileError, match=r"rows=2000.*\(1, 4000000, 3\).*\(1, 4, 3\)"):
        SOM.load(p)
    save_file({"weight": torch.zeros(1, 4, 3)}, str(p),
              metadata={"config": json.dumps({**cfg, "rows": 2, "cols": 2, "seeds": [0] * 10})})
    with pytest.raises(DataFileError, match="seeds"):
        SOM.load(p)
    save_file({"weight": torch.zeros(1, 4, 3)}, str(p), metadata={"config": "[" * 100000 + "]" * 100000})
    with pytest.raises(DataFileError, match="metadata"):
        SOM.load(p)


def test_identical_maps_give_identical_checkpoint_bytes(tmp_path):
    digests = set()
    for i in range(4):
        som = SOM(3, 4, 3, ensemble=2, seed=7)
        som.fit(torch.rand(40, 3, generator=torch.Generator().manual_seed(1)), epochs=2, progress=False)
        path = som.save(tmp_path / f"m{i}.safetensors")
        digests.add(hashlib.sha256(path.read_bytes()).hexdigest())
    assert len(digests) == 1
    assert torch.equal(SOM.load(tmp_path / "m0.safetensors").weight, som.weight)


def test_huge_shapes_in_npy_npz_and_png_headers_are_refused_before_reading(tmp_path):
    import struct
    import zipfile
    import zlib

    # a 128-byte .npy claiming 100000 x 100000 float32
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000), }"
    header += " " * (118 - len(header) - 1) + "\n"
    p = tmp_path / "huge.npy"
    p.write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode())
    with pytest.raises(DataFileError, match="huge.npy.*100000, 100000"):
        read_disparity(p)
    # the same header as the member of an .npz
    z = tmp_path / "huge.npz"
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr("disparity.npy", p.read_bytes())
    with pytest.raises(DataFileError, match="huge.npz.*100000, 100000"):
        read_disparity(z)
    # a PNG whose IHDR claims 100000 x 100000
    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 16, 0, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    png = tmp_path / "huge.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk)
    with pytest.raises(DataFileError, match="huge.png.*100000x100000"):
        read_disparity(png)
    short = tmp_path / "short.png"
    short.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 4)
    with pytest.raises(DataFileError, match="short.png"):
        read_disparity(short)
