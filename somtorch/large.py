"""Maps larger than memory: train and segment a disparity map held in a memory-mapped file.

:func:`train_segment_large` runs steps 1a (features, OR subsample) and 1b (the batch map) and
the segmentation of step 1c on a map of any size with a bounded working set: the map is read in
blocks of rows whose size follows ``memory_budget``, the training features are written once to
a memory-mapped file and every epoch streams through it (:func:`somtorch.core.streaming.
fit_batch_chunked`), and the BMU labels of all pixels go block by block into an ``int16``
memory map. Nothing of size ``H × W`` is ever held in RAM.

The features are those of :func:`somtorch.disparity.features.make_features` for the same
:class:`~somtorch.config.FeatureConfig`, bitwise: the first pass gathers the statistics the scaling
needs (disparity range, first and last valid row and column), :func:`~somtorch.disparity.features.
feature_scaling` turns them into the same affine map, and every block goes through the same
:func:`~somtorch.disparity.features.pixel_features`. The training set is the valid pixels on the
grid of ``stride_at(train_stride)`` (``reference_pixels`` honoured; ``y % s == 0`` and ``x % s ==
0``, the paper's OR mode) in row-major order, as ``Features.subsample`` takes it. Colour features
and speckle removal need the whole map (or an image) and are refused, as are the ground plane and
the object step; ``docs/scaling.md`` reports time and peak memory up to 100 M pixels.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .config import FeatureConfig, SOMConfig, TrainConfig
from .core import SOM
from .core.streaming import fit_batch_chunked
from .disparity.features import feature_scaling, pixel_features

__all__ = ["LargeResult", "train_segment_large"]

_BYTES_PER_PX = 96  # disparity, mask, features, coordinates, BMU temporaries of one block pixel


@dataclass
class LargeResult:
    """What :func:`train_segment_large` returns.

    Attributes:
        som: the trained map.
        labels: BMU per pixel ``(H, W)``, int16 (a memory map on disk, or an array); -1 = invalid.
        n_valid: valid pixels of the map.
        n_train: pixels the SOM was trained on.
        block_rows: image rows per block of the streamed passes.
        timings: seconds per stage.
    """

    som: SOM
    labels: np.ndarray  # (H, W) int16 memory map (or array): BMU per pixel, -1 invalid
    n_valid: int
    n_train: int
    block_rows: int
    timings: dict[str, float] = field(default_factory=dict)


def _block_rows(w: int, budget: int) -> int:
    return max(1, int(budget // 2 // (w * _BYTES_PER_PX)))


def _valid(block: np.ndarray) -> np.ndarray:
    return np.isfinite(block) & (block >= 0) & (block != 0)


def train_segment_large(disparity: np.ndarray, workdir: str | Path, *, som: SOMConfig | None = None,
                        train: TrainConfig | None = None, features: FeatureConfig | None = None,
                        memory_budget: int = 2 << 30, seed: int = 0, zero_invalid: bool = True) -> LargeResult:
    """Train a SOM on a (memory-mapped) disparity map ``(H, W)`` and label every pixel.

    Args:
        disparity: float map; non-finite and negative values are invalid, and so is 0 with
            ``zero_invalid`` (the convention of KITTI / OAK-D PNGs).
        workdir: where the training features (``train_features.npy``) and the labels
            (``labels.npy``) are written.
        som, train, features: the configs (defaults: the library's); ``train`` runs the batch
            map whatever its ``mode``; ``features`` as :func:`~somtorch.disparity.features.make_features`
            reads it (``color_weight`` must be 0).
        memory_budget: bytes the working set may use (the block size follows it).
    """
    som_cfg, tc, fc = som or SOMConfig(), train or TrainConfig(), features or FeatureConfig()
    if disparity.ndim != 2:
        raise ValueError(f"disparity must be (H, W); got shape {disparity.shape}")
    if memory_budget < 64 << 20:
        raise ValueError(f"memory_budget must be at least 64 MiB; got {memory_budget}")
    if fc.color_weight > 0:
        raise ValueError(f"features.color_weight={fc.color_weight}: the large-map path reads a disparity map "
                         "only, without the left image; set color_weight=0")
    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    h, w = disparity.shape
    rows = _block_rows(w, memory_budget)
    t: dict[str, float] = {}
    valid_of = _valid if zero_invalid else (lambda b: np.isfinite(b) & (b >= 0))

    # pass 1: valid count and what the scaling needs (disparity range, valid rows and columns)
    t0 = time.perf_counter()
    stride = fc.stride_at(fc.train_stride, h, w)
    n_valid, n_train, d_lo, d_hi = 0, 0, np.inf, -np.inf
    y_lo, y_hi, col_any = -1, -1, np.zeros(w, dtype=bool)
    for r in range(0, h, rows):
        b = np.asarray(disparity[r:r + rows], dtype=np.float32)
        v = valid_of(b)
        n_valid += int(v.sum())
        n_train += int(v[(-r) % stride::stride, ::stride].sum())
        if v.any():
            d_lo, d_hi = min(d_lo, float(b[v].min())), max(d_hi, float(b[v].max()))
            in_rows = np.nonzero(v.any(1))[0]
            y_lo = r + int(in_rows[0]) if y_lo < 0 else y_lo
            y_hi = r + int(in_rows[-1])
            col_any |= v.any(0)
    if n_valid == 0:
        raise ValueError("the disparity map has no valid pixel")
    cols = np.nonzero(col_any)[0]
    offset, scale = feature_scaling((h, w), normalize=fc.normalize, d_weight=fc.d_weight, d_range=(d_lo, d_hi),
                                    y_range=(y_lo, y_hi), x_range=(int(cols[0]), int(cols[-1])))
    t["scan"] = time.perf_counter() - t0

    def block_features(r: int, b: np.ndarray, v: np.ndarray) -> torch.Tensor:
        ys, xs = np.nonzero(v)
        columns = [torch.from_numpy(ys + r), torch.from_numpy(xs), torch.from_numpy(b[v])]
        return pixel_features(columns, offset, scale, torch.float32)

    # pass 2: the training features, the valid pixels of the stride grid in row-major order, to disk
    t0 = time.perf_counter()
    tf = np.lib.format.open_memmap(work / "train_features.npy", mode="w+", dtype=np.float32, shape=(n_train, 3))
    pos = 0
    for r in range(0, h, rows):
        b = np.asarray(disparity[r:r + rows], dtype=np.float32)
        grid = np.zeros(b.shape, dtype=bool)
        grid[(-r) % stride::stride, ::stride] = True
        take = block_features(r, b, valid_of(b) & grid).numpy()
        tf[pos:pos + len(take)] = take
        pos += len(take)
    tf.flush()
    t["features"] = time.perf_counter() - t0

    # training: initialise from a regular sample, then the chunked batch map over the memory map
    t0 = time.perf_counter()
    model = SOM.from_config(som_cfg, 3, seed=seed)
    sample = torch.from_numpy(np.ascontiguousarray(tf[:: max(1, n_train // 100_000)]))
    model.initialize(sample, som_cfg.init)
    chunk = max(1024, int(memory_budget // 4 // (3 * 4 + 8 * model.num_neurons + 64)))
    fit_batch_chunked(model, tf, epochs=tc.epochs, sigma=tc.sigma, sigma_decay=tc.sigma_decay,
                      neighborhood=tc.neighborhood, chunk_size=chunk)
    t["train"] = time.perf_counter() - t0

    # segmentation: BMU of every valid pixel, block by block, into an int16 memory map
    t0 = time.perf_counter()
    labels = np.lib.format.open_memmap(work / "labels.npy", mode="w+", dtype=np.int16, shape=(h, w))
    for r in range(0, h, rows):
        b = np.asarray(disparity[r:r + rows], dtype=np.float32)
        v = valid_of(b)
        out = np.full(b.shape, -1, dtype=np.int16)
        if v.any():
            bmu = model.bmu(block_features(r, b, v))[0]
            out[v] = bmu.numpy().astype(np.int16)
        labels[r:r + rows] = out
    labels.flush()
    t["segment"] = time.perf_counter() - t0
    return LargeResult(model, labels, n_valid, n_train, rows, t)
