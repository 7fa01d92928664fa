"""Data-parallel and member-parallel SOM training on ``torch.distributed``.

* :func:`fit_data_parallel` — every rank holds a shard of the samples; each epoch of the batch
  map, every rank sums its shard's BMU statistics (:mod:`somtorch.core.streaming`) and the float64
  numerators and denominators are ``all_reduce``-d, so every rank applies the same update. With two
  ranks the result equals a single process that adds the two shards' totals in order
  (``fit_batch_chunked(som, [shard0, shard1])``) **bitwise** (floating-point addition of two
  values commutes); with more ranks the reduction order is the backend's, and the weights agree
  within float64 rounding (|Δw| ≲ 1e-6 on float32 maps).
* :func:`fit_members_parallel` — the ensemble dimension: members are dealt to ranks
  (member ``e`` on rank ``e mod world``), trained on all samples with their own seeds, and
  gathered; because each member evolves exactly as a solo map with its seed, the gathered
  ensemble equals ``SOM(ensemble=E, seed=s).fit(x)`` bitwise.

Launch with ``torchrun`` (``gloo`` on CPU, ``nccl`` on GPU; ``docs/scaling.md`` has a multi-node
and an ``srun`` example). Functions here only need an initialised default process group.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from .som import SOM
from .streaming import fit_batch_chunked

__all__ = ["fit_data_parallel", "fit_members_parallel", "shard_range"]


def _dist() -> Any:
    import torch.distributed as dist

    if not dist.is_available() or not dist.is_initialized():
        raise RuntimeError("torch.distributed is not initialised: launch with torchrun (or call "
                           "torch.distributed.init_process_group) before data-parallel training")
    return dist


def shard_range(n: int, rank: int, world: int) -> tuple[int, int]:
    """The contiguous rows ``[start, stop)`` of rank ``rank`` of ``world`` over ``n`` samples (the
    first ``n mod world`` ranks get one row more)."""
    if world < 1 or not 0 <= rank < world:
        raise ValueError(f"rank {rank} of world {world}")
    base, extra = divmod(n, world)
    start = rank * base + min(rank, extra)
    return start, start + base + (1 if rank < extra else 0)


def fit_data_parallel(som: SOM, x_local: Any, *, epochs: int | None = None, init: str = "random",
                      chunk_size: int = 1 << 20, **kwargs: Any) -> SOM:
    """Batch-map training of ``som`` on the union of every rank's ``x_local`` (see the module
    docstring); returns ``som`` with identical weights on every rank.

    Args:
        x_local: this rank's samples: an ``(n, D)`` tensor / array / memory map, or a callable
            returning chunks (:data:`~somtorch.core.streaming.Source`).
        epochs: default :class:`~somtorch.config.TrainConfig` ``epochs``.
        init: if the map is not initialised, rank 0 initialises it from its shard with this
            method and broadcasts the weights (so every rank starts alike).
        kwargs: ``sigma``, ``sigma_final``, ``sigma_decay``, ``neighborhood`` of
            :func:`~somtorch.core.streaming.fit_batch_chunked`.
    """
    dist = _dist()
    from ..config import TrainConfig

    if not som.initialized:
        if dist.get_rank() == 0:
            sample = x_local if isinstance(x_local, torch.Tensor) else torch.as_tensor(x_local[: 1 << 20])
            som.initialize(sample.to(som.weight.dtype), init)
        w = som.weight.data
        dist.broadcast(w, src=0)
        som.weight = w
    else:  # the caller's weights must agree across ranks; rank 0's are authoritative
        dist.broadcast(som.weight.data, src=0)

    def reduce(t: torch.Tensor) -> None:
        dist.all_reduce(t, op=dist.ReduceOp.SUM)

    return fit_batch_chunked(som, x_local, epochs=epochs or TrainConfig.epochs, chunk_size=chunk_size,
                             all_reduce=reduce, **kwargs)


def fit_members_parallel(rows: int, cols: int, x: torch.Tensor, *, ensemble: int, seed: int = 0,
                         fit_kwargs: dict[str, Any] | None = None, som_kwargs: dict[str, Any] | None = None
                         ) -> SOM:
    """Train an ensemble of ``ensemble`` maps with members dealt across the ranks; every rank
    returns the full ensemble (``seeds = seed, seed + 1, …``). ``fit_kwargs`` go to
    :meth:`SOM.fit` (``progress`` is off), ``som_kwargs`` to the constructor."""
    dist = _dist()
    rank, world = dist.get_rank(), dist.get_world_size()
    dim = int(x.shape[-1])
    mine = list(range(rank, ensemble, world))
    som_kwargs = dict(som_kwargs or {})
    fit_kwargs = {"progress": False, **(fit_kwargs or {})}
    local: torch.Tensor | None = None
    if mine:
        part = SOM(rows, cols, dim, ensemble=len(mine), seeds=[seed + e for e in mine], **som_kwargs)
        part.fit(x, **fit_kwargs)
        local = part.weight.detach().cpu()
    gathered: list[Any] = [None] * world
    dist.all_gather_object(gathered, (mine, local))
    full = SOM(rows, cols, dim, ensemble=ensemble, seed=seed, **som_kwargs)
    w = torch.empty_like(full.weight.data)
    for members, weights in gathered:
        for j, e in enumerate(members):
            w[e] = weights[j].to(w.device)
    full.weight = w
    return full


def gather_shards(local: torch.Tensor, sizes: Sequence[int]) -> torch.Tensor:
    """Concatenate every rank's ``local`` rows (``sizes`` per rank, in rank order) on every rank."""
    dist = _dist()
    world = dist.get_world_size()
    if len(sizes) != world:
        raise ValueError(f"sizes has {len(sizes)} entries for a world of {world}")
    longest = max(sizes)
    pad = torch.zeros((longest, *local.shape[1:]), dtype=local.dtype)
    pad[: local.shape[0]] = local
    out = [torch.empty_like(pad) for _ in range(world)]
    dist.all_gather(out, pad)
    return torch.cat([o[:s] for o, s in zip(out, sizes)])
