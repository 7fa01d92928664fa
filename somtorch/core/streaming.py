"""The batch map over data that does not fit in memory, or that is split across processes.

Kohonen's batch map needs, per epoch, only two sums per unit: the sum of the samples it wins
and their count. Both add up over any split of the data, so an epoch can walk through chunks
(a memory-mapped ``.npy``, a DataLoader, tiles of a map) and, in data-parallel training, through
the shards of several processes whose sums are then all-reduced (:mod:`somtorch.core.distributed`).

This module only turns tensors, arrays, memory maps and DataLoaders into a chunk source
(:class:`~somtorch.core.training.Chunks`); the epochs run in the one batch engine of
:meth:`SOM.fit` (:func:`somtorch.core.training.run`), whose in-memory data is a single chunk.
Sums are kept in float64 between chunks; each chunk's sums come from the same kernel as
:meth:`SOM.fit` (``accumulate``). With a single chunk holding all data the result equals
``SOM.fit(mode="batch")`` up to the float64 target (``|Δw|`` ≲ 1e-6); with ``partitions`` the
partition totals are added in their order — the order in which two processes' all-reduce adds
them — so a single process reproduces a two-process run bitwise.

Memory: one chunk of samples, its BMU indices, and ``E·K·(D + 1)`` float64 sums.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from functools import partial
from typing import Any, Union

import numpy as np
import torch

from .. import interrupt
from ..config import TrainConfig
from .decay import DECAYS
from .grid import default_sigma
from .neighborhood import NEIGHBORHOODS
from .order import Schedules
from .training import Chunks, run

__all__ = ["Source", "chunk_rows", "chunk_source", "fit_batch_chunked"]

_T = TrainConfig

Source = Union[torch.Tensor, np.ndarray, Callable[[], Iterable[torch.Tensor]]]
"""Where one partition's samples come from: an ``(N, D)`` tensor or array (a ``np.memmap`` too),
read in chunks of ``chunk_size`` rows, or a callable returning a fresh iterable of ``(n, D)``
tensors per epoch (a DataLoader's ``__iter__``, a generator function)."""


def chunk_rows(data: torch.Tensor | np.ndarray, chunk_size: int, dtype: torch.dtype = torch.float32
               ) -> Iterator[torch.Tensor]:
    """``data`` ``(N, D)`` in consecutive row chunks of at most ``chunk_size``, as tensors of
    ``dtype`` (a memory map is read one chunk at a time)."""
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1; got {chunk_size}")
    n = int(data.shape[0])
    for s in range(0, n, chunk_size):
        part = data[s:s + chunk_size]
        if not isinstance(part, torch.Tensor):
            part = np.ascontiguousarray(part)
            if not part.flags.writeable:  # a read-only memory map: torch wants a writable buffer
                part = part.copy()
            part = torch.from_numpy(part)
        yield part.to(dtype)


def _chunks(source: Source, chunk_size: int, weight: torch.Tensor) -> Iterator[torch.Tensor]:
    """One pass over ``source`` as ``(n, D)`` chunks of the weights' dtype, on their device."""
    d = weight.shape[-1]
    if isinstance(source, (torch.Tensor, np.ndarray)):
        chunks: Iterable[Any] = chunk_rows(source, chunk_size, weight.dtype)
    else:
        chunks = source()
    for c in chunks:
        interrupt.checkpoint()  # a pending SIGINT / SIGTERM stops the epoch here (somtorch.interrupt)
        chunk = torch.as_tensor(c).to(device=weight.device, dtype=weight.dtype)
        if chunk.ndim != 2 or chunk.shape[1] != d:
            raise ValueError(f"a chunk must be (n, {d}); got shape {tuple(chunk.shape)}")
        yield chunk


def _check_source(source: Any) -> None:
    if isinstance(source, (torch.Tensor, np.ndarray)):
        if source.ndim != 2:
            raise ValueError(f"a sample array must be (N, D); got shape {tuple(source.shape)}")
    elif not callable(source):
        raise TypeError(f"a source is a tensor, an array or a callable returning chunks; got {type(source).__name__}")


def chunk_source(sources: Source | Sequence[Source], weight: torch.Tensor, *, chunk_size: int = 1 << 20,
                 all_reduce: Callable[[torch.Tensor], None] | None = None) -> Chunks:
    """The batch engine's data source for ``sources`` (one :data:`Source` or a list of partitions),
    read in chunks of ``chunk_size`` rows, sums in float64."""
    if isinstance(sources, (torch.Tensor, np.ndarray)) or callable(sources):
        sources = [sources]
    sources = list(sources)
    if not sources:
        raise ValueError("sources is empty")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1; got {chunk_size}")
    for source in sources:
        _check_source(source)
    return Chunks([partial(_chunks, src, chunk_size, weight) for src in sources], torch.float64, all_reduce)


def fit_batch_chunked(som: Any, sources: Source | Sequence[Source], *, epochs: int = _T.epochs,
                      sigma: float | None = None, sigma_final: float | None = None,
                      sigma_decay: str = _T.sigma_decay, neighborhood: str = _T.neighborhood,
                      chunk_size: int = 1 << 20, all_reduce: Callable[[torch.Tensor], None] | None = None,
                      callback: Callable[[int, torch.Tensor], None] | None = None) -> Any:
    """Train ``som`` (a :class:`~somtorch.core.som.SOM`, initialised) with the batch map, one
    pass over the chunks of ``sources`` per epoch; returns ``som``.

    Args:
        sources: one :data:`Source` or a list of them (partitions, summed separately and added in
            order; see the module docstring).
        epochs, sigma, sigma_final, sigma_decay, neighborhood: as :meth:`SOM.fit` in batch mode.
        chunk_size: rows per chunk for tensor / array sources.
        all_reduce: called in place on the float64 sums and counts of every epoch before the
            update (``torch.distributed.all_reduce``): the data-parallel hook.
        callback: ``callback(epoch, weight)`` after every epoch.

    Raises:
        ValueError: the map is not initialised, a chunk has the wrong width, or an epoch saw no
            sample anywhere.
    """
    if not som.initialized:
        raise ValueError("initialise the map first (som.initialize(sample) or set its weights): a chunked "
                         "pass has no single data tensor to initialise from")
    w = som.weight.data
    source = chunk_source(sources, w, chunk_size=chunk_size, all_reduce=all_reduce)
    if isinstance(epochs, bool) or not isinstance(epochs, int) or epochs < 1:
        raise ValueError(f"epochs must be a positive int; got {epochs!r}")
    s0 = float(default_sigma(som.rows, som.cols) if sigma is None else sigma)
    s1 = float(min(s0, 0.5) if sigma_final is None else sigma_final)
    ens = som.ensemble
    p0 = torch.full((ens,), s0, dtype=w.dtype, device=w.device)
    p1 = torch.full((ens,), s1, dtype=w.dtype, device=w.device)
    if sigma_decay not in DECAYS:
        raise ValueError(f"sigma_decay {sigma_decay!r}: choose from {sorted(DECAYS)}")
    if neighborhood not in NEIGHBORHOODS:
        raise ValueError(f"neighborhood {neighborhood!r}: choose from {sorted(NEIGHBORHOODS)}")
    decay = [DECAYS[sigma_decay]] * ens
    sched = Schedules(p0, p1, decay, p0, p1, decay)  # the batch map reads only the radius
    every = None if callback is None else (lambda info: callback(info.step, info.weight))
    run(w, source, mode="batch", steps=epochs, batch_size=1, order=None, sched=sched, grid_d2=som.grid_d2,
        neighborhood=NEIGHBORHOODS[neighborhood], progress=False, callback=every)
    return som


def bmu_chunked(som: Any, data: torch.Tensor | np.ndarray, out: np.ndarray | None = None, *,
                chunk_size: int = 1 << 20, member: int = 0) -> np.ndarray:
    """Best-matching unit of every row of ``data`` for one member, chunk by chunk, into ``out``
    (an int32 array or memory map of length N; allocated if None). Peak memory: one chunk."""
    n = int(data.shape[0])
    if out is None:
        out = np.empty(n, dtype=np.int32)
    if out.shape != (n,):
        raise ValueError(f"out must have shape ({n},); got {out.shape}")
    one = som.member(member) if som.ensemble > 1 else som
    pos = 0
    for chunk in chunk_rows(data, chunk_size, som.weight.dtype):
        b = one.bmu(chunk.to(som.device))[0]
        out[pos:pos + len(b)] = b.cpu().numpy().astype(np.int32, copy=False)
        pos += len(b)
    return out
