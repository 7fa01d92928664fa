"""Data- and member-parallel training in real torch.distributed processes (gloo, 2 ranks)."""

from __future__ import annotations

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from somtorch.core.distributed import fit_data_parallel, fit_members_parallel, shard_range
from somtorch.core.som import SOM
from somtorch.core.streaming import fit_batch_chunked

pytestmark = pytest.mark.skipif(not dist.is_available(), reason="torch.distributed not built")


def _data():
    return torch.rand(3001, 3, generator=torch.Generator().manual_seed(0))


def _w0():
    som = SOM(5, 6, 3, seed=2, ensemble=2)
    som.initialize(_data())
    return som.weight.detach().clone()


def _worker(rank: int, world: int, init: str, out: str) -> None:
    dist.init_process_group("gloo", init_method=init, rank=rank, world_size=world)
    try:
        x = _data()
        a, b = shard_range(len(x), rank, world)
        som = SOM(5, 6, 3, seed=2, ensemble=2)
        if rank == 0:
            som.weight = _w0()  # only rank 0 holds the start: the others get it by broadcast
        fit_data_parallel(som, x[a:b], epochs=6, chunk_size=500)
        members = fit_members_parallel(4, 4, x, ensemble=3, seed=7,
                                       fit_kwargs={"mode": "online", "epochs": 1, "order": "random"})
        torch.save({"data": som.weight.detach(), "members": members.weight.detach()}, f"{out}.{rank}")
    finally:
        dist.destroy_process_group()


@pytest.fixture(scope="module")
def ranks(tmp_path_factory):
    d = tmp_path_factory.mktemp("dist")
    mp.spawn(_worker, args=(2, f"file://{d / 'rendezvous'}", str(d / "w")), nprocs=2, join=True)
    return [torch.load(d / f"w.{r}") for r in range(2)]


def test_ranks_agree_and_equal_the_sharded_single_process_bitwise(ranks):
    assert torch.equal(ranks[0]["data"], ranks[1]["data"])
    x = _data()
    ref = SOM(5, 6, 3, seed=2, ensemble=2)
    ref.weight = _w0()
    shards = [x[slice(*shard_range(len(x), r, 2))] for r in range(2)]
    fit_batch_chunked(ref, shards, epochs=6, chunk_size=500)
    assert torch.equal(ranks[0]["data"], ref.weight.detach())


def test_data_parallel_matches_plain_batch_training(ranks):
    x = _data()
    plain = SOM(5, 6, 3, seed=2, ensemble=2)
    plain.weight = _w0()
    plain.fit(x, mode="batch", epochs=6, progress=False)
    assert (ranks[0]["data"] - plain.weight.detach()).abs().max() < 1e-3  # float64 vs float32 sums


def test_members_dealt_to_ranks_equal_one_ensemble_bitwise(ranks):
    ref = SOM(4, 4, 3, ensemble=3, seed=7).fit(_data(), mode="online", epochs=1, order="random", progress=False)
    assert torch.equal(ranks[0]["members"], ref.weight.detach())
    assert torch.equal(ranks[1]["members"], ref.weight.detach())


def test_shard_ranges_partition_the_rows():
    for n, world in [(10, 3), (2, 4), (3001, 2)]:
        parts = [shard_range(n, r, world) for r in range(world)]
        assert parts[0][0] == 0 and parts[-1][1] == n
        assert all(parts[i][1] == parts[i + 1][0] for i in range(world - 1))
    with pytest.raises(ValueError):
        shard_range(5, 2, 2)


def test_without_a_process_group_the_error_says_how_to_launch():
    with pytest.raises(RuntimeError, match="torchrun"):
        fit_data_parallel(SOM(2, 2, 3), _data())
