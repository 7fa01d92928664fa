"""The chunked batch map: memory-mapped data, DataLoader-style sources, chunked BMUs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from somtorch.core.som import SOM
from somtorch.core.streaming import bmu_chunked, chunk_rows, fit_batch_chunked


@pytest.fixture()
def data(tmp_path):
    x = torch.rand(5000, 3, generator=torch.Generator().manual_seed(3))
    path = tmp_path / "x.npy"
    np.save(path, x.numpy())
    return x, np.load(path, mmap_mode="r")


def _start(x, ensemble=1):
    som = SOM(6, 6, 3, seed=4, ensemble=ensemble)
    som.initialize(x)
    return som


def test_memory_map_chunks_equal_in_memory_chunks_and_fit(data):
    x, mm = data
    a, b = _start(x), _start(x)
    fit_batch_chunked(a, mm, epochs=5, chunk_size=777)
    fit_batch_chunked(b, x, epochs=5, chunk_size=777)
    assert torch.equal(a.weight, b.weight)
    plain = _start(x).fit(x, mode="batch", epochs=5, progress=False)
    assert (a.weight - plain.weight).abs().max() < 1e-5


def test_a_callable_source_is_walked_once_per_epoch(data):
    x, _ = data
    calls = []

    def loader():
        calls.append(1)
        return (x[i:i + 1000] for i in range(0, len(x), 1000))

    a, b = _start(x), _start(x)
    fit_batch_chunked(a, loader, epochs=3)
    fit_batch_chunked(b, x, epochs=3, chunk_size=1000)
    assert len(calls) == 3 and torch.equal(a.weight, b.weight)


def test_partitions_change_only_the_summation_order(data):
    x, _ = data
    one, two = _start(x, 2), _start(x, 2)
    fit_batch_chunked(one, x, epochs=4, chunk_size=2500)
    fit_batch_chunked(two, [x[:2500], x[2500:]], epochs=4)
    assert (one.weight - two.weight).abs().max() < 1e-6


def test_bad_sources_are_refused_before_work(data):
    x, _ = data
    with pytest.raises(ValueError, match="initialise"):
        fit_batch_chunked(SOM(3, 3, 3), x)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        fit_batch_chunked(_start(x), lambda: [torch.zeros(4, 2)])
    with pytest.raises(ValueError, match="no sample"):
        fit_batch_chunked(_start(x), lambda: [])
    with pytest.raises(ValueError, match="chunk_size"):
        list(chunk_rows(x, 0))


def test_chunked_bmus_equal_the_whole_pass(data, tmp_path):
    x, mm = data
    som = _start(x).fit(x, epochs=2, progress=False)
    out = np.lib.format.open_memmap(tmp_path / "labels.npy", mode="w+", dtype=np.int32, shape=(len(x),))
    bmu_chunked(som, mm, out, chunk_size=999)
    assert np.array_equal(out, som.bmu(x)[0].numpy())
