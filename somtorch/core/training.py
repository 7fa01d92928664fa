"""The SOM training engine: one loop, three update rules.

The engine walks through ``T`` steps in blocks; at each step an update rule consumes the samples of
that step and changes the weights in place:

* online (Kohonen's sequential rule, one sample per step):
  ``m_i ← m_i + α(t) h(‖r_c − r_i‖², σ(t)) (x(t) − m_i)``;
* batch map (all N samples per step = epoch): ``m_i ← Σ_n h_{c(n) i} x_n / Σ_n h_{c(n) i}``;
* mini-batch (B samples per step): ``m_i ← m_i + α(t) (m̂_i − m_i)`` with ``m̂`` the batch-map
  target of the mini-batch (units no sample reaches keep their weights).

Everything is vectorised over the ensemble dimension E: member e uses its own schedule values, its
own sample order and its own random generator, so it evolves exactly as a solo map with that member's
seed would.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import torch

from .. import interrupt
from .bounds import BmuBounds
from .distance import DEFAULT_CHUNK_ELEMENTS, bmu_search
from .native import native_accumulate, native_online
from .neighborhood import NeighborhoodFn, gaussian
from .order import Order, Schedules

log = logging.getLogger(__name__)

BLOCK_STEPS = 4096  # steps whose samples and schedule values are prepared at once (online rule)
USE_BOUNDS = True  # the in-memory batch map may skip BMU searches its bounds prove (exact either way)


@dataclass
class StepInfo:
    """What a training callback receives.

    Attributes:
        step: number of steps done (1 … total).
        total: number of steps of this ``fit``.
        epoch: passes over the data done so far (fractional for the online rule).
        lr: learning rate at this step, ``(E,)``.
        sigma: radius at this step, ``(E,)``.
        weight: the current weights ``(E, K, D)`` (a live view: copy it to keep it).
        skipped: batch map: share of the samples whose BMU search the bounds skipped in this step
            (:mod:`somtorch.core.bounds`); 0 otherwise.
    """

    step: int
    total: int
    epoch: float
    lr: torch.Tensor
    sigma: torch.Tensor
    weight: torch.Tensor
    skipped: float = 0.0


Callback = Callable[[StepInfo], None]


def _take(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Samples at ``idx``: x ``(N, D)`` or ``(E, N, D)``, idx ``(1 | E, S)`` → ``(1 | E, S, D)``."""
    if x.ndim == 2:
        return x[idx]
    if idx.shape[0] == 1:
        idx = idx.expand(x.shape[0], -1)
    return torch.gather(x, 1, idx[..., None].expand(-1, -1, x.shape[-1]))


# ----------------------------------------------------------------------------- update rules
def online_block(weight: torch.Tensor, xs: torch.Tensor, lr: torch.Tensor, sigma: torch.Tensor,
                 grid_d2: torch.Tensor, neighborhood: NeighborhoodFn, idx: torch.Tensor | None = None) -> None:
    """Apply the online rule for S consecutive steps, in place.

    Shape:
        ``weight`` ``(E, K, D)``; ``xs`` ``(1 | E, S, D)`` — or, with ``idx`` ``(1 | E, S)``, the data
        ``(N, D)`` or ``(E, N, D)`` whose rows ``idx`` the steps use; ``lr``, ``sigma`` ``(S, E)``;
        ``grid_d2`` ``(K, K)``.
    """
    if neighborhood is gaussian:
        # h = α exp(−d²/2σ²) = exp(log α + d² · (−1/2σ²)): two kernels per step instead of four
        coef = (-0.5 / (sigma * sigma)).unsqueeze(-1)  # (S, E, 1)
        log_lr = torch.log(lr).unsqueeze(-1)  # (S, E, 1)
        if native_online(weight.data, xs, coef, log_lr, grid_d2, idx):  # the compiled loop (CPU)
            return
    if idx is not None:
        xs = _take(xs, idx)  # (1 | E, S, D)
    if neighborhood is gaussian:
        if weight.shape[0] == 1 and weight.device.type == "cpu":
            _online_solo_cpu(weight[0], xs[0], coef.view(-1), log_lr.view(-1), grid_d2)
            return
        for x_t, c_t, l_t in zip(xs.unbind(1), coef.unbind(0), log_lr.unbind(0)):
            diff = x_t.unsqueeze(1) - weight  # (E, K, D)
            c = torch.linalg.vector_norm(diff, dim=-1).argmin(-1)  # (E,)
            h = torch.addcmul(l_t, grid_d2.index_select(0, c), c_t).exp_()  # (E, K)
            weight.addcmul_(h.unsqueeze(-1), diff)
        return
    sig = sigma.unsqueeze(-1)
    for x_t, s_t, l_t in zip(xs.unbind(1), sig.unbind(0), lr.unbind(0)):
        diff = x_t.unsqueeze(1) - weight
        c = torch.linalg.vector_norm(diff, dim=-1).argmin(-1)
        h = neighborhood(grid_d2.index_select(0, c), s_t) * l_t.unsqueeze(-1)
        weight.addcmul_(h.unsqueeze(-1), diff)


def _online_solo_cpu(w: torch.Tensor, xs: torch.Tensor, coef: torch.Tensor, log_lr: torch.Tensor,
                     grid_d2: torch.Tensor) -> None:
    """Gaussian online rule for one map on the CPU: the same kernels as :func:`online_block` (so
    the result is bitwise the same) with the winner as a Python int and row views of the grid
    distances instead of an index kernel, which saves a third of the time per step.

    Shape:
        ``w`` ``(K, D)``, ``xs`` ``(S, D)``, ``coef``/``log_lr`` ``(S,)``, ``grid_d2`` ``(K, K)``.
    """
    rows = grid_d2.unbind(0)
    for x_t, c_t, l_t in zip(xs.unbind(0), coef.unbind(0), log_lr.unbind(0)):
        diff = x_t - w  # (K, D)
        c = torch.linalg.vector_norm(diff, dim=-1).argmin().item()
        h = torch.addcmul(l_t, rows[c], c_t).exp_()  # (K,)
        w.addcmul_(h.unsqueeze(-1), diff)


def accumulate(x: torch.Tensor, weight: torch.Tensor,
               chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-unit sums and counts of the samples each unit wins.

    Shape:
        ``x`` ``(N, D)`` or ``(E, N, D)``, ``weight`` ``(E, K, D)`` → sums ``(E, K, D)``, counts ``(E, K)``.
    """
    fused = native_accumulate(x, weight)  # the same sums, bitwise, in one pass (CPU kernel)
    if fused is not None:
        return fused
    e, k, d = weight.shape
    sums = torch.zeros(e * k, d, dtype=weight.dtype, device=weight.device)
    counts = torch.zeros(e * k, dtype=weight.dtype, device=weight.device)
    offs = (torch.arange(e, device=weight.device) * k)[:, None]  # (E, 1)
    n = x.shape[-2]
    step = max(1, chunk_elements // max(e * k, 1))
    for s in range(0, n, step):
        xs = x[s:s + step] if x.ndim == 2 else x[:, s:s + step]
        flat = (bmu_search(xs, weight, chunk_elements=chunk_elements) + offs).reshape(-1)  # (E*n,)
        xe = xs.expand(e, -1, -1) if xs.ndim == 2 else xs
        sums.index_add_(0, flat, xe.reshape(-1, d))
        counts += torch.bincount(flat, minlength=e * k).to(counts.dtype)
    return sums.view(e, k, d), counts.view(e, k)


def fixed_order_bmm(a: torch.Tensor, b: torch.Tensor, *, chunk_elements: int = DEFAULT_CHUNK_ELEMENTS
                    ) -> torch.Tensor:
    """``a @ b`` per batch member, summed in one fixed order: the same bits in every process, at
    every thread count.

    A BLAS product (``torch.bmm``) may sum in another order from one call to the next (MKL picks its
    kernel and its split by the process's threading state): bitwise-equal inputs then give
    different last bits, and a SOM trained for ten epochs drifts apart (docs/reliability.md). Here
    every product ``a[e, i, j] b[e, j, c]`` is one rounded multiply, and the terms are added as a
    balanced tree over ``j`` (first half + second half, level by level), one rounded add each: no
    fused multiply-add, no order left to a library. Rows of the output are computed in chunks of
    at most ``chunk_elements`` products; a row's sum does not depend on the chunking.

    Shape:
        ``a`` ``(E, M, J)``, ``b`` ``(E, J, C)`` → ``(E, M, C)``.
    """
    e, m, j = a.shape
    c = b.shape[-1]
    out = torch.empty(e, m, c, dtype=torch.result_type(a, b), device=a.device)
    rows = max(1, chunk_elements // max(1, e * j * c))
    at = a.transpose(1, 2)  # (E, J, M): the summed index leading, so every level adds contiguous blocks
    for r in range(0, m, rows):
        terms = at[:, :, r:r + rows, None] * b[:, :, None, :]  # (E, J, m', C): one rounding each
        n = j
        while n > 1:  # in place: terms[:half] += terms[half:2 half]; an odd last term moves up
            half = n // 2
            terms[:, :half] += terms[:, half:2 * half]
            if n % 2:
                terms[:, half] = terms[:, n - 1]
            n = half + n % 2
        out[:, r:r + rows] = terms[:, 0]
    return out


def batch_target(sums: torch.Tensor, counts: torch.Tensor, sigma: torch.Tensor, grid_d2: torch.Tensor,
                 neighborhood: NeighborhoodFn) -> tuple[torch.Tensor, torch.Tensor]:
    """Kohonen's batch-map target: neighbourhood-weighted means of the won samples.

    Shape:
        ``sums`` ``(E, K, D)``, ``counts`` ``(E, K)``, ``sigma`` ``(E,)`` → target ``(E, K, D)`` and
        the denominator ``(E, K)`` (0 where no sample reaches the unit).
    """
    e = sigma.shape[0]
    if e > 1 and bool((sigma == sigma[0]).all()):  # one radius for the ensemble: one (K, K) table
        h = neighborhood(grid_d2.unsqueeze(0), sigma[:1].view(1, 1, 1)).expand(e, -1, -1)  # (E, K, K)
    else:
        h = neighborhood(grid_d2.unsqueeze(0), sigma.view(-1, 1, 1))  # (E, K, K), symmetric
    # one product for numerators and denominators (the counts ride along as an extra column); every
    # member is its own product, so member e equals the solo map bitwise (tests/core check it)
    both = fixed_order_bmm(h, torch.cat([sums, counts.unsqueeze(-1)], dim=-1))  # (E, K, D + 1)
    num, den = both[..., :-1], both[..., -1]
    return num / den.clamp_min(torch.finfo(den.dtype).tiny).unsqueeze(-1), den


def _apply(weight: torch.Tensor, target: torch.Tensor, den: torch.Tensor, lr: torch.Tensor | None) -> None:
    """``weight`` ← target (``lr`` None) or ``weight + lr (target − weight)``, where some sample
    reaches the unit (``den`` > 0); in place. Shape: ``(E, K, D)``, ``den`` ``(E, K)``, ``lr`` ``(E,)``."""
    reached = (den > 1e-12).unsqueeze(-1)
    if lr is None:
        torch.where(reached, target.to(weight.dtype), weight, out=weight)
    else:
        delta = torch.where(reached, target - weight, torch.zeros_like(weight))
        weight.addcmul_(lr.view(-1, 1, 1), delta)


def batch_step(weight: torch.Tensor, x: torch.Tensor, lr: torch.Tensor | None, sigma: torch.Tensor,
               grid_d2: torch.Tensor, neighborhood: NeighborhoodFn) -> None:
    """One batch-map step on the samples ``x`` held in memory (a mini-batch with learning rate
    ``lr``, or all data with ``lr`` None), in place.

    Shape:
        ``weight`` ``(E, K, D)``, ``x`` ``(N, D)`` or ``(E, N, D)``, ``lr`` ``(E,)`` or None (= 1),
        ``sigma`` ``(E,)``.
    """
    sums, counts = accumulate(x, weight)
    target, den = batch_target(sums, counts, sigma, grid_d2, neighborhood)
    _apply(weight, target, den, lr)


@dataclass
class Chunks:
    """The samples of one batch-map epoch as chunks: the data source of the batch engine.

    In-memory data is one chunk (:meth:`of`); :mod:`somtorch.core.streaming` builds chunk sources
    from memory maps, arrays and DataLoaders, and :mod:`somtorch.core.distributed` adds the
    all-reduce of data-parallel training.

    Attributes:
        parts: partitions, each a callable returning a fresh iterable of chunks ``(n, D)`` or
            ``(E, n, D)`` per epoch; each partition's sums are formed on their own and the
            partition totals added in order (the order in which an all-reduce of two processes adds them).
        stats_dtype: dtype of the sums carried between chunks and of the batch-map target (None =
            the weights' dtype, which an in-memory epoch uses; float64 for many chunks).
        all_reduce: called in place on the epoch's sums and counts before the update.
        bounds: per chunk, the bound state that lets the BMU search skip samples across epochs
            (:class:`~somtorch.core.bounds.BmuBounds`); only for sources that yield the same chunks
            every epoch (None: no bounds).
    """

    parts: Sequence[Callable[[], Iterable[torch.Tensor]]]
    stats_dtype: torch.dtype | None = None
    all_reduce: Callable[[torch.Tensor], None] | None = None
    bounds: list[BmuBounds] | None = None

    @classmethod
    def of(cls, x: torch.Tensor) -> Chunks:
        """Samples held in memory, ``(N, D)`` or ``(E, N, D)``: one partition of one chunk, with
        bounds (the same samples every epoch)."""
        return cls([lambda: (x,)], bounds=[BmuBounds()] if USE_BOUNDS else None)


def _add(total: tuple[torch.Tensor, torch.Tensor] | None, sums: torch.Tensor, counts: torch.Tensor,
         dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    if total is None:  # the first term as it is (0 + s would turn a −0.0 into +0.0)
        return sums.to(dtype), counts.to(dtype)
    total[0].add_(sums.to(dtype))
    total[1].add_(counts.to(dtype))
    return total


def batch_epoch(weight: torch.Tensor, source: Chunks, sigma: torch.Tensor, grid_d2: torch.Tensor,
                neighborhood: NeighborhoodFn, remaining: int = 1) -> float:
    """One epoch of Kohonen's batch map over every chunk of ``source``, in place; returns the share
    of BMU searches the bounds skipped (0 without bounds). ``remaining``: epochs left in the
    schedule, this one included (the bounds start only when enough remain to repay the start).

    Shape:
        ``weight`` ``(E, K, D)``, ``sigma`` ``(E,)``, ``grid_d2`` ``(K, K)``.

    Raises:
        ValueError: the epoch saw no sample (and there is no all-reduce to bring any).
    """
    dt = source.stats_dtype or weight.dtype
    total, seen, skipped, i = None, 0, 0.0, 0
    for part in source.parts:
        sub = None
        for chunk in part():
            if chunk.shape[-2] == 0:
                continue
            stats, bounds = None, source.bounds[i] if source.bounds and i < len(source.bounds) else None
            if bounds is not None and bounds.plan(chunk, weight, remaining):
                stats = bounds.accumulate(chunk, weight)  # None: the kernel cannot serve
                skipped += bounds.skipped * chunk.shape[-2] if stats is not None else 0.0
            i += 1
            stats = stats or accumulate(chunk, weight)
            if bounds is not None:
                bounds.counts = stats[1]
            sub = _add(sub, *stats, dt)
            seen += int(chunk.shape[-2])
        if sub is not None:
            total = _add(total, *sub, dt)
    if total is None:
        e, k, d = weight.shape
        total = (torch.zeros(e, k, d, dtype=dt, device=weight.device),
                 torch.zeros(e, k, dtype=dt, device=weight.device))
    sums, counts = total
    if source.all_reduce is not None:
        source.all_reduce(sums)
        source.all_reduce(counts)
    elif seen == 0:
        raise ValueError("the sources yielded no sample in this epoch")
    target, den = batch_target(sums, counts, sigma.to(dt), grid_d2.to(dt), neighborhood)
    _apply(weight, target, den, None)
    return skipped / max(seen, 1)


# ----------------------------------------------------------------------------- the engine
def _epochs(x: float) -> str:
    """Epochs for a message: ``3`` or ``2.4`` (the online rule stops within an epoch)."""
    return f"{x:.0f}" if abs(x - round(x)) < 1e-9 else f"{x:.1f}"


def _blocks(total: int, size: int, every: int | None) -> Iterator[tuple[int, int]]:
    """Consecutive ``(start, stop)`` ranges of at most ``size`` steps that also end at every multiple
    of ``every`` (so that callbacks fire exactly there)."""
    start = 0
    while start < total:  # lazily: a schedule of 10^9 steps must not build 10^9 cuts first
        stop = min(total, (start // size + 1) * size)
        if every:
            stop = min(stop, (start // every + 1) * every)
        yield start, stop
        start = stop


HEARTBEAT_S = 60.0  # a training without a bar (a log file, --quiet) logs its progress this often


class _Heartbeat:
    """Logs (INFO) how far a long training got, at most every :data:`HEARTBEAT_S` seconds."""

    def __init__(self, desc: str, steps: int, where: Callable[[int], str]) -> None:
        import time

        self.desc, self.steps, self.where, self.clock = desc, steps, where, time.monotonic
        self.t0 = self.clock()
        self.next = self.t0 + HEARTBEAT_S

    def __call__(self, done: int) -> None:
        now = self.clock()
        if now < self.next or done <= 0:
            return
        self.next = now + HEARTBEAT_S
        spent = now - self.t0
        log.info("%s: %s, %.0f s so far, ~%.0f s left", self.desc, self.where(done), spent,
                 spent * (self.steps - done) / done)


def run(weight: torch.Tensor, x: torch.Tensor | Chunks, *, mode: str, steps: int, batch_size: int,
        order: Order, sched: Schedules, grid_d2: torch.Tensor, neighborhood: NeighborhoodFn,
        progress: bool = True, callback: Callback | None = None, callback_every: int | None = None,
        desc: str = "SOM", offset: int = 0, total: int | None = None) -> list[float]:
    """Train ``weight`` in place for ``steps`` steps of the given mode (see the module docstring).

    ``offset`` / ``total``: the steps are steps ``offset … offset + steps − 1`` of a schedule of
    ``total`` steps (default: the schedule is these ``steps``), so that training in parts
    continues the decay instead of restarting it (:meth:`SOM.partial_fit`).

    ``x``: the samples ``(N, D)`` or ``(E, N, D)``; in batch mode also a :class:`Chunks` source
    (memory maps, partitions, an all-reduce): the batch map is one engine for all of them.

    Returns the share of samples whose BMU search the bounds skipped, per step (batch mode; empty
    for the other modes).
    """
    from tqdm.auto import tqdm

    if mode == "batch" and isinstance(x, torch.Tensor):
        x = Chunks.of(x)
    n = 1 if isinstance(x, Chunks) else x.shape[-2]  # batch mode: a step is an epoch
    planned = steps if total is None else total
    if offset < 0 or offset + steps > planned:
        raise ValueError(f"steps {offset}..{offset + steps} lie outside the schedule of {planned} steps")
    per_step = {"online": 1, "batch": 1, "minibatch": batch_size}[mode]
    every = callback_every
    block = BLOCK_STEPS if mode == "online" else 1
    cut_every = every if every else (n if mode == "online" else None)
    skipped: list[float] = []
    bar = tqdm(total=steps, desc=desc, unit="step", disable=not progress, delay=0.5, leave=False)
    epochs_total = planned * per_step / n
    beat = _Heartbeat(desc, steps, lambda done: f"epoch {_epochs((offset + done) * per_step / n)} of "
                                                f"{_epochs(epochs_total)}")
    try:
        with torch.no_grad(), interrupt.deferred():  # a signal stops the loop at the next block's end
            for start, stop in _blocks(steps, block, cut_every if callback is not None else None):
                lr, sigma = sched.values(offset + start, offset + stop, planned)  # (S, E)
                if mode == "online":
                    idx = order.indices(offset + start, offset + stop)  # (1 | E, S)
                    online_block(weight, x, lr, sigma, grid_d2, neighborhood, idx)
                elif mode == "batch":
                    left = planned - offset - start  # epochs left in the schedule, this one included
                    skipped.append(batch_epoch(weight, x, sigma[0], grid_d2, neighborhood, left))
                    log.debug("batch epoch %d: BMU search skipped for %.1f %% of the samples", offset + stop,
                              100 * skipped[-1])
                else:
                    xs = _take(x, order.indices((offset + start) * batch_size, (offset + stop) * batch_size))
                    if xs.shape[0] == 1 and x.ndim == 2:
                        xs = xs[0]  # one order shared by all members: shared samples (B, D)
                    batch_step(weight, xs, lr[0], sigma[0], grid_d2, neighborhood)
                bar.update(stop - start)
                interrupt.checkpoint(f"after epoch {_epochs((offset + stop) * per_step / n)}/"
                                     f"{_epochs(epochs_total)}")
                if not progress:
                    beat(stop)
                if every:
                    fire = stop % every == 0
                else:  # once per completed epoch
                    fire = (stop * per_step) // n > (start * per_step) // n
                if callback is not None and (fire or stop == steps):
                    callback(StepInfo(step=stop, total=steps, epoch=stop * per_step / n,
                                      lr=lr[-1], sigma=sigma[-1], weight=weight,
                                      skipped=skipped[-1] if mode == "batch" else 0.0))
    finally:
        bar.close()
    return skipped
