"""Decompression bombs and large maps (issue 34): refused from the header before any decode, with
a DataFileError naming the file and the problem; a reader's peak memory stays within 2x the
arrays it returns (measured as the growth of ``VmHWM`` in a fresh subprocess); real files read as
the whole-array conversion reads them, byte for byte."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from somtorch import DataFileError
from somtorch.disparity.io import read_disparity
from somtorch.disparity.pfm import write_pfm
from tests.fuzz import bombs

# each bomb: its builder and what the refusal says
BOMBS = {
    "zeros.npz": (lambda p: bombs.npz_zeros(p, 4000, 4000), r"zeros\.npz: array 'disparity'.*compression ratio"),
    "zeros32.npz": (lambda p: bombs.npz_zeros(p, 6000, 6000, "<f4"), r"zeros32\.npz: .*compression ratio"),
    "bomb.png": (lambda p: bombs.png16(p, 6000, 6000), r"bomb\.png: the PNG header claims 6000x6000.*compression ratio"),
    "bomb.tif": (lambda p: bombs.tiff_striped(p, 14000, 14000), r"bomb\.tif: the TIFF header claims 14000x14000.*ratio"),
    "overrun.png": (lambda p: bombs.png16(p, 500, 500, inflated=300_000_000),
                    r"overrun\.png: the PNG's compressed image data runs past the 500x500 image"),
}

_PROBE = r"""
import json, sys
from somtorch.disparity.io import read_disparity


def hwm():  # this process's peak RSS, kB (not ru_maxrss: it also holds the parent's peak before exec)
    return int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1])


read_disparity(sys.argv[1])  # imports and first-use allocations before the baseline
rows = []
for path in sys.argv[2:]:
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # the peak RSS restarts from the current RSS (Linux >= 4.0)
    base = hwm()
    d = v = None
    try:
        d, v = read_disparity(path)
        returned, outcome = d.numel() * d.element_size() + v.numel(), "read"
    except ValueError as e:
        returned, outcome = 0, str(e)
    grown = (hwm() - base) * 1024
    rows.append({"path": path, "outcome": outcome, "grown": grown, "returned": returned})
    del d, v
print(json.dumps(rows))
"""


def _peaks(tmp_path: Path, files: list[Path]) -> list[dict]:
    """Read ``files`` one after another in a fresh interpreter: the growth of its peak RSS during
    each read above the RSS before it (the peak is reset before each read)."""
    warm = bombs.png16(tmp_path / "warm.png", 8, 8)
    root = Path(__file__).resolve().parents[2]
    p = subprocess.run([sys.executable, "-c", _PROBE, str(warm), *map(str, files)], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(root)), check=True)
    return json.loads(p.stdout)


@pytest.mark.parametrize("name", list(BOMBS))
def test_a_bomb_is_refused_from_its_header(tmp_path, name):
    build, message = BOMBS[name]
    path = build(tmp_path / name)
    assert path.stat().st_size < 400_000  # a small file ...
    with pytest.raises(DataFileError, match=message):  # ... that would inflate to 32 MB - 784 MB
        read_disparity(path)


def test_refusing_the_bombs_allocates_nothing_like_what_they_claim(tmp_path):
    files = [build(tmp_path / name) for name, (build, _) in BOMBS.items()]
    rows = _peaks(tmp_path, files)
    for row in rows:
        assert row["outcome"] != "read", row
        # they claim 32 MB - 784 MB; the old readers peaked at 4-7x that (issue 34)
        assert row["grown"] < 24 << 20, row


def test_a_header_beyond_the_memory_budget_is_refused_even_under_the_pixel_limit(tmp_path):
    # 200000 x 200000 float64: under a raised pixel limit, but 200 GB to hold
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (200000, 200000), }"
    path = tmp_path / "wide.npy"
    path.write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + bytes(64))
    code = "import sys; from somtorch.disparity.io import read_disparity; read_disparity(sys.argv[1])"
    p = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True,
                       env=dict(os.environ, SOMTORCH_MAX_PIXELS=str(10**11)))
    assert p.returncode == 1
    assert "wide.npy: the .npy header claims shape (200000, 200000)" in p.stderr
    assert "more than the memory budget" in p.stderr and "available" in p.stderr


def _large_files(folder: Path, n: int) -> list[Path]:
    """Legitimate n x n maps in every format, compressible as real maps are (a ramp plus noise)."""
    rng = np.random.default_rng(0)
    d = (np.add.outer(np.arange(n), np.arange(n)) / 50.0 + rng.uniform(0, 1, (n, n))).astype(np.float64)
    np.savez_compressed(folder / "big.npz", disparity=d)
    np.save(folder / "big.npy", d)
    np.save(folder / "fortran.npy", np.asfortranarray(d.astype(np.float32)))
    write_pfm(folder / "big.pfm", d)
    cv2.imwrite(str(folder / "big.png"), (d * 256).astype(np.uint16))
    cv2.imwrite(str(folder / "big.tif"), d.astype(np.float32))
    return [folder / f for f in ("fortran.npy", "big.npz", "big.npy", "big.pfm", "big.png", "big.tif")]


def test_a_reader_peaks_within_twice_the_arrays_it_returns(tmp_path):
    files = _large_files(tmp_path, 3000)  # 45 MB returned (float32 map + bool mask)
    for row in _peaks(tmp_path, files):
        assert row["outcome"] == "read", row
        assert 0 < row["grown"] <= 2 * row["returned"], row


def test_streamed_reads_equal_the_whole_array_conversion(tmp_path):
    files = _large_files(tmp_path, 300)
    d = np.load(files[2])
    for f in files:
        disp, valid = read_disparity(f)
        stored = d.astype(np.float32) if f.suffix in (".pfm", ".tif") or f.name == "fortran.npy" else d
        if f.suffix == ".png":
            stored = (d * 256).astype(np.uint16)
        np.testing.assert_array_equal(disp.numpy(), _reference(stored, 1 / 256 if f.suffix == ".png" else 1.0,
                                                               f.suffix == ".png")[0], err_msg=f.name)


def _reference(raw: np.ndarray, scale: float, zero_is_invalid: bool) -> tuple[np.ndarray, np.ndarray]:
    """The whole-array conversion the readers did before they streamed (the oracle)."""
    values = raw.astype(np.float64) * scale
    with np.errstate(over="ignore"):
        valid = np.isfinite(values.astype(np.float32)) & (values >= 0)
    if zero_is_invalid:
        valid &= raw != 0
    return np.where(valid, values, 0.0).astype(np.float32), valid


def test_real_files_read_byte_for_byte_as_the_whole_array_conversion(shared_data):
    files = sorted(shared_data.glob("**/disp*.p*"))
    assert len(files) > 50
    for f in files:
        if f.suffix == ".pfm":
            head = f.read_bytes()
            lines = head.split(b"\n", 3)
            w, h = map(int, lines[1].split())
            dtype = "<f4" if float(lines[2]) < 0 else ">f4"
            raw = np.frombuffer(lines[3][:w * h * 4], dtype=dtype).reshape(h, w)[::-1]
        else:
            raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        scale = 1.0 if f.suffix == ".pfm" else 1 / 256 if raw.dtype == np.uint16 else 1 / 3
        disp, valid = read_disparity(f, scale=None if raw.dtype != np.uint8 else scale)
        ref_d, ref_v = _reference(raw, scale, f.suffix == ".png")
        assert disp.numpy().tobytes() == ref_d.tobytes() and np.array_equal(valid.numpy(), ref_v), f


def test_a_negative_shape_in_an_npy_header_names_the_file(tmp_path):  # found by the fuzzer
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (-3, -4), }"
    path = tmp_path / "neg.npy"
    path.write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + bytes(48))
    with pytest.raises(DataFileError, match=r"neg\.npy: the header claims a negative size"):
        read_disparity(path)
