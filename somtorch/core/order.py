"""What each step of training uses: the members' schedules of α(t) and σ(t), and the sample orders.

:class:`Schedules` gives ``(lr, sigma)`` for a range of steps, one column per member;
:class:`Order` gives the sample indices of a range of steps (sequential as MiniSom, a fresh
permutation per epoch and member, or explicit). The training engine (:mod:`.training`) reads both
in blocks of steps.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import torch

from .decay import DecayFn, schedule
from .threads import kernel_threads

__all__ = ["Order", "Schedules"]


@dataclass
class Schedules:
    """Per-member schedule parameters; every tensor has shape ``(E,)``."""

    lr: torch.Tensor
    lr_final: torch.Tensor
    lr_decay: list[DecayFn]
    sigma: torch.Tensor
    sigma_final: torch.Tensor
    sigma_decay: list[DecayFn]

    def values(self, start: int, stop: int, total: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(lr, sigma)`` for steps start … stop−1, each ``(S, E)``."""
        return (_member_schedule(self.lr_decay, self.lr, self.lr_final, start, stop, total),
                _member_schedule(self.sigma_decay, self.sigma, self.sigma_final, start, stop, total))


def _member_schedule(fns: list[DecayFn], p0, p_end, start, stop, total) -> torch.Tensor:
    if all(f is fns[0] for f in fns):
        return schedule(fns[0], p0, p_end, start, stop, total)
    out = torch.empty(stop - start, p0.shape[0], dtype=p0.dtype, device=p0.device)
    for f in dict.fromkeys(fns):
        members = torch.tensor([i for i, g in enumerate(fns) if g is f], device=p0.device)
        out[:, members] = schedule(f, p0[members], p_end[members], start, stop, total)
    return out


class Order:
    """Which samples each step uses, per member.

    ``kind`` is ``"sequential"`` (0, 1, …, N−1, 0, … as MiniSom), ``"random"`` (a fresh permutation
    of the data per epoch and member, from that member's generator) or ``"explicit"`` (a given index
    tensor ``(T,)`` shared by all members or ``(E, T)``).
    """

    def __init__(self, kind: str, n: int, members: int, generators: list[torch.Generator],
                 device: torch.device, explicit: torch.Tensor | None = None) -> None:
        self.kind, self.n, self.members = kind, n, members
        self.generators, self.device = generators, device
        self.explicit = explicit
        self._epoch = -1
        self._perm: torch.Tensor | None = None

    def indices(self, start: int, stop: int) -> torch.Tensor:
        """Sample indices of positions start … stop−1 of the stream: ``(1 | E, stop − start)``."""
        if self.kind == "explicit":
            idx = self.explicit[..., start:stop]
            return idx[None] if idx.ndim == 1 else idx
        if self.kind == "sequential":
            return (torch.arange(start, stop, device=self.device) % self.n)[None]
        parts = []
        pos = start
        while pos < stop:
            epoch, off = divmod(pos, self.n)
            if epoch != self._epoch:
                # int32 on the CPU where N allows: the same permutations as int64 (torch's CPU
                # Fisher–Yates does not depend on the dtype), half the memory traffic
                dtype = torch.int32 if self.device.type == "cpu" and self.n < 2 ** 31 else torch.long
                self._perm = _permutations(self.generators, self.n, dtype, self.device)  # (E, N)
                self._epoch = epoch
            take = min(stop - pos, self.n - off)
            parts.append(self._perm[:, off:off + take])
            pos += take
        return torch.cat(parts, dim=1).long()


PERM_THREAD_ELEMENTS = 1 << 20  # E·N from which the members' permutations are drawn on several threads


def _permutations(generators: list[torch.Generator], n: int, dtype: torch.dtype,
                  device: torch.device) -> torch.Tensor:
    """One ``randperm(n)`` per generator, each drawn into its row of an ``(E, n)`` table.

    On the CPU, large tables are drawn by ``kernel_threads()`` Python threads (torch releases the
    GIL inside ``randperm``); each row still comes from its own generator alone, so the table is
    the same whatever the thread count.
    """
    out = torch.empty(len(generators), n, dtype=dtype, device=device)
    jobs = list(zip(generators, out))

    def draw(job: tuple[torch.Generator, torch.Tensor]) -> None:
        torch.randperm(n, generator=job[0], out=job[1])

    workers = min(kernel_threads(), len(jobs)) if device.type == "cpu" and out.numel() >= PERM_THREAD_ELEMENTS else 1
    if workers > 1:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(draw, jobs))
    else:
        for job in jobs:
            draw(job)
    return out
