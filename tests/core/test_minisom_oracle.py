"""MiniSom (2.3.x) is the numerical oracle for the online rule and for the quality measures.

Both maps start from MiniSom's own initial weights, use the gaussian neighbourhood and MiniSom's
default asymptotic decay for α and σ, and see the samples in the same order: sequential, or MiniSom's
shuffled ``random_order=True`` stream reproduced exactly and passed to ``order=`` as a tensor.

Data: (a) 300 points from two 2-D Gaussian blobs; (b) the real Middlebury 2014 Motorcycle ground-truth
disparity map, subsampled with stride 10 to (y, x, d) vectors of its finite pixels (3,685 rows),
min-max scaled per column, on a 4x7 map for T = 2N steps.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
import torch
from minisom import MiniSom, _build_iteration_indexes

from somtorch import SOM

from .conftest import two_blobs

SEED = 3
LR, SIGMA = 0.5, 1.5
PFM = Path("middlebury2014") / "Motorcycle_Q" / "disp0GT.pfm"

# float32 tolerance. Measured max |ours − MiniSom| over 24 runs (seeds 0–5 × sequential/random order × both
# data sets, torch 2.13 CPU): 2.3e-6 (disparity, sequential); blobs ≤ 1.0e-6. That is ~20 float32 ulps at
# 1.0 accumulated over up to 7,370 updates, plus the rounding of MiniSom's float64 initial weights to
# float32. 1e-5 keeps a 4x margin, while one differently chosen BMU would move weights by ~1e-2.
F32_ATOL = 1e-5
F64_ATOL = 1e-12  # the brief asks 1e-5; measured: ≤ 4.5e-16 (same operations, same order, float64)


def read_pfm(path: Path) -> np.ndarray:
    """Minimal PFM reader (grey or colour, either endianness); rows returned top to bottom ``(H, W)``."""
    with open(path, "rb") as f:
        kind = f.readline().strip()
        if kind not in (b"Pf", b"PF"):
            raise ValueError(f"{path}: not a PFM file (header {kind!r})")
        width, height = (int(v) for v in f.readline().split())
        scale = float(f.readline())
        channels = 3 if kind == b"PF" else 1
        data = np.fromfile(f, dtype="<f4" if scale < 0 else ">f4", count=width * height * channels)
    img = data.reshape(height, width, channels)[..., 0]
    return np.ascontiguousarray(img[::-1])  # PFM stores the bottom row first


def _disparity_features(root: Path) -> np.ndarray:
    d = read_pfm(root / PFM)
    assert d.shape == (497, 741)
    sub = d[::10, ::10]  # (50, 75)
    yy, xx = np.mgrid[0:sub.shape[0], 0:sub.shape[1]]
    ok = np.isfinite(sub)  # inf = no ground truth
    feats = np.stack([yy[ok], xx[ok], sub[ok]], axis=1).astype(np.float64)  # (N, 3): y, x, d
    lo, hi = feats.min(0), feats.max(0)
    return (feats - lo) / (hi - lo)


@pytest.fixture(scope="module")
def disparity(shared_data: Path) -> np.ndarray:
    """(y, x, d) features of the real map; ``shared_data`` (tests/conftest.py) skips with
    "../shared/data not found ..." when the data folder is absent."""
    if not (shared_data / PFM).is_file():
        pytest.skip(f"../shared/data has no {PFM}; the MiniSom oracle on the real disparity map is skipped")
    return _disparity_features(shared_data)


@functools.lru_cache(maxsize=None)
def _minisom_run(name: str, data_bytes: bytes, shape: tuple, rows: int, cols: int, random_order: bool):
    """Train MiniSom once per case: (initial weights (K, D), order (T,) or None, final weights (K, D))."""
    data = np.frombuffer(data_bytes, dtype=np.float64).reshape(shape)
    n, d = shape
    t = 2 * n
    ms = MiniSom(rows, cols, d, sigma=SIGMA, learning_rate=LR, neighborhood_function="gaussian",
                 random_seed=SEED)
    w0 = ms.get_weights().reshape(rows * cols, d).copy()
    order = None
    if random_order:
        # MiniSom.train shuffles with self._random_generator, already advanced by the weight initialisation:
        # replay a copy of its state taken right before training
        rng = np.random.RandomState()
        rng.set_state(ms._random_generator.get_state())
        order = np.asarray(_build_iteration_indexes(n, t, random_generator=rng))
        # ... which is the same as a fresh generator advanced by MiniSom's own init draw
        rng2 = np.random.RandomState(SEED)
        rng2.rand(rows, cols, d)
        assert np.array_equal(order, _build_iteration_indexes(n, t, random_generator=rng2))
    ms.train(data, t, random_order=random_order)
    return w0, order, ms.get_weights().reshape(rows * cols, d).copy()


def _grid(which: str) -> tuple[int, int]:
    return (5, 6) if which == "blobs" else (4, 7)


def _ours(data: np.ndarray, rows: int, cols: int, w0: np.ndarray, order, dtype, members: int = 1) -> SOM:
    n, d = data.shape
    som = SOM(rows, cols, d, dtype=dtype, seed=SEED, ensemble=members)
    som.weight = torch.from_numpy(np.stack([w0] * members)).to(dtype)
    return som.fit(torch.from_numpy(data).to(dtype), mode="online", iterations=2 * n,
                   order="sequential" if order is None else torch.from_numpy(order).long(),
                   lr=LR, sigma=SIGMA, lr_decay="asymptotic", sigma_decay="asymptotic", progress=False)


def _get_data(which: str, request) -> np.ndarray:
    return two_blobs() if which == "blobs" else request.getfixturevalue("disparity")


@pytest.mark.parametrize("which", ["blobs", "disparity"])
@pytest.mark.parametrize("random_order", [False, True], ids=["sequential", "random"])
@pytest.mark.parametrize("dtype,atol", [(torch.float64, F64_ATOL), (torch.float32, F32_ATOL)],
                         ids=["float64", "float32"])
@pytest.mark.parametrize("members", [1, 9], ids=["solo", "ensemble"])
def test_online_training_equals_minisom(which, random_order, dtype, atol, members, request):
    # members = 9: the compiled loop's vector-lane layout (8 float32 / 4 float64 members per vector, a
    # partly filled last block); every member must equal MiniSom as the solo map does
    data = _get_data(which, request)
    rows, cols = _grid(which)
    w0, order, want = _minisom_run(which, data.tobytes(), data.shape, rows, cols, random_order)
    got = _ours(data, rows, cols, w0, order, dtype, members).weight.detach().double().numpy()
    assert np.abs(want - w0).max() > 0.1  # training moved the weights: the comparison is not trivial
    for member in got:
        np.testing.assert_allclose(member, want, rtol=0, atol=atol)


@pytest.mark.parametrize("which", ["blobs", "disparity"])
def test_random_and_sequential_orders_really_differ(which, request):
    data = _get_data(which, request)
    rows, cols = _grid(which)
    _, order, seq = _minisom_run(which, data.tobytes(), data.shape, rows, cols, False)
    _, _, rnd = _minisom_run(which, data.tobytes(), data.shape, rows, cols, True)
    assert not np.array_equal(order, np.arange(2 * data.shape[0]) % data.shape[0])
    assert np.abs(seq - rnd).max() > 1e-3


@pytest.mark.parametrize("which", ["blobs", "disparity"])
def test_quality_measures_equal_minisom_on_the_same_weights(which, request):
    data = _get_data(which, request)
    rows, cols = _grid(which)
    w0, order, _ = _minisom_run(which, data.tobytes(), data.shape, rows, cols, True)
    som = _ours(data, rows, cols, w0, order, torch.float64)
    ms = MiniSom(rows, cols, data.shape[1], sigma=SIGMA, random_seed=SEED)
    ms._weights = som.weight.detach()[0].numpy().reshape(rows, cols, -1).copy()
    x = torch.from_numpy(data)

    qe_ms = ms.quantization_error(data)
    assert abs(float(som.quantization_error(x)[0]) - qe_ms) <= 1e-6
    te_ms = ms.topographic_error(data)
    assert float(som.topographic_error(x)[0]) == te_ms
    assert 0.0 < te_ms < 0.1  # a non-trivial value (0.03 blobs, 0.023 disparity): "exactly" can fail

    u = som.umatrix()[0].numpy()
    np.testing.assert_allclose(u / u.max(), ms.distance_map(scaling="mean"), rtol=0, atol=1e-12)

    # and on untrained (MiniSom-initialised) weights, where the errors are large
    ms._weights = w0.reshape(rows, cols, -1).copy()
    som.weight = torch.from_numpy(w0)
    assert abs(float(som.quantization_error(x)[0]) - ms.quantization_error(data)) <= 1e-6
    te_init = ms.topographic_error(data)
    assert float(som.topographic_error(x)[0]) == te_init and te_init > 0.5


def test_local_pfm_reader_on_the_real_file(disparity):
    n, d = disparity.shape
    assert d == 3 and 3000 < n < 3750  # 50 x 75 pixels of which ~2 % have no ground truth
    assert disparity.min(0).tolist() == [0.0, 0.0, 0.0] and disparity.max(0).tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize("rows", [5, 6])
def test_hexagonal_measures_equal_minisom_transposed(rows):
    """MiniSom staggers columns, we stagger rows: MiniSom's (i, j) is our (r = j, c = i) when the number of
    rows is odd, and (r = j, c = cols − 1 − i) (mirrored) when it is even. The hexagonal U-matrix is compared
    for odd rows only: for an even count MiniSom's ``distance_map`` uses the neighbour offsets of the other
    row parity (inconsistent with its own coordinates, a MiniSom quirk), so it is not an oracle there."""
    cols, d = 6, 3
    data = np.random.RandomState(0).rand(400, d)
    x = torch.from_numpy(data)
    som = SOM(rows, cols, d, topology="hexagonal", dtype=torch.float64, seed=0).fit(
        x, mode="batch", epochs=10, sigma=2.0, progress=False)
    w = som.weight.detach()[0].numpy().reshape(rows, cols, d)
    ms = MiniSom(cols, rows, d, topology="hexagonal", random_seed=0)
    mirrored = rows % 2 == 0
    ms._weights = np.ascontiguousarray((w[:, ::-1] if mirrored else w).transpose(1, 0, 2))
    te_ms = ms.topographic_error(data)  # computed as 1 − mean(...): equal up to one rounding
    assert float(som.topographic_error(x)[0]) == pytest.approx(te_ms, abs=1e-12) and 0.0 < te_ms < 0.5
    assert float(som.quantization_error(x)[0]) == pytest.approx(ms.quantization_error(data), abs=1e-12)
    if not mirrored:
        u = som.umatrix()[0].numpy()
        np.testing.assert_allclose(u / u.max(), ms.distance_map(scaling="mean").T, rtol=0, atol=1e-12)
