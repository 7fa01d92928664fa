"""Exact BMU search across batch-map epochs that skips the samples whose BMU provably stays.

In the spirit of Hamerly's exact k-means (scikit-learn's ``_k_means_elkan`` / Hamerly): every
sample keeps an upper bound ``u`` on the distance to its BMU and a lower bound ``l`` on the distance
to every other unit. After the weights move, the triangle inequality moves the bounds by the units'
drift (``u += drift[bmu]``, ``l -= max drift``); where ``u < l`` still holds the BMU cannot have
changed and no distance is computed; the other samples are searched again. The bookkeeping, the
search and the sums are one pass of the native kernel (:func:`~somtorch.core.native.native_bounded`).

**Exact, ties included.** A skipped BMU is the one the fused kernel (:func:`native_bmu`) would
return: the kernel sums ``(x_d − w_d)²`` in the weights' precision, whose relative error is at most
``(D + 2)·eps``, so a bound proves the BMU only with room for that error on both sides
(``u·(1 + ρ) + α < l·(1 − ρ)``, ``ρ = 2(D + 2)·eps``, ``α`` for underflow); the bounds are float64
and rounded outwards after every update. A tie, or any margin the rounding could flip, fails the test
and is searched again by the same tile kernel (lowest index on ties). The sums are added in sample
order, so they equal :func:`~somtorch.core.native.native_accumulate`'s bitwise. The bounds need the kernel's per-sample
determinism: elsewhere (GPU, ``SOMTORCH_NATIVE=0``) they are not used.

**When they are used.** A bounded epoch pays only when nearly every search is skipped, and a
fresh start (a top-2 search of every sample) costs several plain epochs; measured on the embedded
motorcycle (``benchmarks/bench_bounds.py``, ``docs/scaling.md``): a bounded epoch beats the fused
kernel from about 90 % skipped searches (2.4–4× at 94 %), a start costs 8–18 plain epochs, and
the batch map moves the units far more per epoch than the gaps between first and second BMU (at
most 2 % skipped in the default 10-epoch job, 37 % in the 30th epoch of a 30-epoch one). So the
bounds start only when a probe predicts they pay: while they are off, a fixed subsample of
``N / 16`` (at most 4,096) samples gets its two nearest units, and the share whose gap survives the
last epoch's largest drift twice (``u + δ``, ``l − δ``) predicts the share the bounds would skip.
The probe runs only while at least :data:`START_EPOCHS` epochs remain to repay a start (so never in
the default 10-epoch job), the bounds start when its share is at least :data:`START_SHARE`, and stop
again when an epoch skips less than :data:`STOP_SHARE`.

Memory: per member and sample one index and two float64 bounds (24 bytes).
"""

from __future__ import annotations

import logging

import torch

from .native import native_bmu, native_bounded

__all__ = ["BmuBounds"]

log = logging.getLogger(__name__)

_EPS64 = torch.finfo(torch.float64).eps
# measured on the motorcycle, every pixel (benchmarks/bench_bounds.py, two runs under load, docs/scaling.md):
# a bounded epoch costs 0.3-0.4x the fused kernel's at 94-100 % skipped searches, 0.25-1.5x at 78-88 %;
# a start (top-2 search of every sample) costs 8-18 fused epochs
START_SHARE = 0.9  # predicted share of skipped searches from which the bounds start
STOP_SHARE = 0.8  # an epoch that skips less stops them (below break-even)
START_EPOCHS = 20  # epochs that must remain to repay a start
PROBE = 4096  # at most this many probe samples (and at most N / 16)


def _slack(weight: torch.Tensor) -> tuple[float, float, float]:
    """``(rho, alpha, grow)``: the kernel's relative and absolute distance error, and the outward
    rounding of a computed distance, for the weights' dtype."""
    d = weight.shape[-1]
    eps = torch.finfo(weight.dtype).eps
    return 2 * (d + 2) * eps, d * torch.finfo(weight.dtype).tiny ** 0.5, 2 * (d + 2) * eps


class BmuBounds:
    """Bound state of one fixed set of samples (a chunk seen every epoch) for one set of maps.

    Attributes:
        bmu: the BMU of every sample ``(E, N)`` long (valid after :meth:`accumulate`).
        skipped: share of the (member, sample) searches of the last call that the bounds skipped.
    """

    def __init__(self) -> None:
        self.bmu: torch.Tensor | None = None
        self._upper: torch.Tensor | None = None  # (E, N) float64
        self._lower: torch.Tensor | None = None  # (E, N) float64
        self._weight: torch.Tensor | None = None  # (E, K, D) float64: the weights the bounds hold for
        self._last: torch.Tensor | None = None  # (E, K, D) float64: the weights of the previous epoch
        self.skipped = 0.0
        self.active = False
        self.counts: torch.Tensor | None = None  # (E, K): samples per unit in the last epoch (set by the engine)

    def reset(self) -> None:
        """Forget the bounds (a new start searches every sample)."""
        self.bmu = self._upper = self._lower = self._weight = None
        self.active = False

    def predict(self, x: torch.Tensor, weight: torch.Tensor) -> float:
        """Share of searches the bounds would skip if the weights moved again as far as in the
        last epoch (0 at the first epoch): the probe of the module docstring, preceded by a free
        upper bound from the units' nearest-neighbour distances (returned when it is already
        below :data:`START_SHARE`)."""
        w64 = weight.detach().double()
        last, self._last = self._last, w64
        n = x.shape[-2]
        if last is None or last.shape != w64.shape or n < 32:
            return 0.0
        delta = (w64 - last).square_().sum(-1).sqrt_().amax(1, keepdim=True)  # (E, 1)
        if self.counts is not None and self.counts.shape == w64.shape[:2]:
            # free upper bound first: a sample's gap is at most its BMU's distance to the nearest other
            # unit, so only samples of units whose nearest neighbour lies beyond 2δ can be skipped
            nn = torch.cdist(w64, w64)
            nn.diagonal(dim1=1, dim2=2).fill_(float("inf"))
            c = self.counts.double()
            most = float(((c * (nn.amin(2) > 2 * delta)).sum(1) / c.sum(1).clamp_min(1)).mean())
            if most < START_SHARE:
                return most
        step = max(16, -(-n // PROBE))
        xs = x[::step] if x.ndim == 2 else x[:, ::step]
        top = native_bmu(xs, weight, k=2)  # (E, S, 2)
        if top is None:
            return 0.0
        xe = (xs.expand(weight.shape[0], -1, -1) if xs.ndim == 2 else xs).double()
        near = [(xe - torch.gather(w64, 1, top[..., j, None].expand(-1, -1, w64.shape[-1]))).norm(dim=-1)
                for j in (0, 1)]  # (E, S) each
        rho, alpha, _ = _slack(weight)
        return float(((near[0] + delta) * (1 + rho) + alpha < (near[1] - delta) * (1 - rho)).double().mean())

    def plan(self, x: torch.Tensor, weight: torch.Tensor, remaining: int) -> bool:
        """Whether this epoch (with ``remaining`` epochs left, this one included) uses the bounds."""
        if not self.active and remaining >= START_EPOCHS:  # fewer left: no start could repay itself
            share = self.predict(x, weight)
            if share >= START_SHARE:
                self.reset()  # a start searches every sample
                self.active = True
                log.debug("bounds start: probe predicts %.1f %% skipped searches, %d epochs left",
                          100 * share, remaining)
        return self.active

    def accumulate(self, x: torch.Tensor, weight: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Per-unit sums and counts of the samples each unit wins, bitwise those of
        :func:`~somtorch.core.native.native_accumulate`; None where the kernel cannot serve (the
        state is dropped then).

        Shape: ``x`` ``(N, D)`` or ``(E, N, D)`` (the same samples at every call), ``weight``
        ``(E, K, D)`` → sums ``(E, K, D)``, counts ``(E, K)``.
        """
        e, k, d = weight.shape
        n = x.shape[-2]
        w64 = weight.detach().double()  # float32 differences: exact in float64 or within the outward rounding
        drift = None
        if self._weight is not None and self._weight.shape == w64.shape and self.bmu.shape == (e, n):
            drift = (w64 - self._weight).square_().sum(-1).sqrt_().mul_(1 + 2 * (d + 2) * _EPS64)  # (E, K)
        else:
            self.bmu = torch.zeros(e, n, dtype=torch.long)
            self._upper = torch.zeros(e, n, dtype=torch.float64)
            self._lower = torch.zeros(e, n, dtype=torch.float64)
        out = native_bounded(x, weight, (self.bmu, self._upper, self._lower), drift, _slack(weight))
        if out is None:
            self.reset()
            return None
        sums, counts, searched = out
        self._weight = self._last = w64
        self.skipped = 1.0 - float(searched.sum()) / max(e * n, 1)
        if drift is not None and self.skipped < STOP_SHARE:
            log.debug("bounds stop: %.1f %% skipped searches", 100 * self.skipped)
            self.active = False
        return sums, counts
