"""Decay ("disintegration") schedules for the learning rate α(t) and the radius σ(t).

A schedule maps the initial value ``p0``, the step ``t`` (0 … T−1), the number of steps ``T`` and a
final value ``p_end`` to the value at step t. Every function broadcasts, so ``p0``/``p_end`` of shape
``(E,)`` and ``t`` of shape ``(S, 1)`` give per-member schedules of shape ``(S, E)``.

* asymptotic: ``p0 / (1 + t / (T/2))`` — MiniSom's default; reaches p0/3 at the end, ignores p_end.
* linear: ``p0 + (p_end − p0) · t/T``.
* exponential: ``p0 · (p_end/p0)^(t/T)``.
* inverse_time: ``p0 / (1 + c·t)`` with ``c = (p0/p_end − 1)/T`` so that it reaches p_end at t = T
  (MiniSom's ``inverse_decay_to_one`` for σ with p_end = 1).
* constant: ``p0``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

DecayFn = Callable[[torch.Tensor, torch.Tensor, int, torch.Tensor], torch.Tensor]


def asymptotic(p0: torch.Tensor, t: torch.Tensor, total: int, p_end: torch.Tensor) -> torch.Tensor:
    """MiniSom's asymptotic decay ``p0 / (1 + t/(T/2))``."""
    return p0 / (1.0 + t / (total / 2.0))


def linear(p0: torch.Tensor, t: torch.Tensor, total: int, p_end: torch.Tensor) -> torch.Tensor:
    """Linear interpolation from p0 (t = 0) to p_end (t = T)."""
    return p0 + (p_end - p0) * (t / total)


def exponential(p0: torch.Tensor, t: torch.Tensor, total: int, p_end: torch.Tensor) -> torch.Tensor:
    """Geometric decay from p0 (t = 0) to p_end (t = T)."""
    return p0 * torch.pow(p_end / p0, t / total)


def inverse_time(p0: torch.Tensor, t: torch.Tensor, total: int, p_end: torch.Tensor) -> torch.Tensor:
    """Inverse-time decay ``p0 / (1 + c·t)`` reaching p_end at t = T."""
    return p0 / (1.0 + (p0 / p_end - 1.0) / total * t)


def constant(p0: torch.Tensor, t: torch.Tensor, total: int, p_end: torch.Tensor) -> torch.Tensor:
    """No decay."""
    return p0 + 0.0 * t


DECAYS: dict[str, DecayFn] = {
    "asymptotic": asymptotic,
    "linear": linear,
    "exponential": exponential,
    "inverse_time": inverse_time,
    "constant": constant,
}


def schedule(fn: DecayFn, p0: torch.Tensor, p_end: torch.Tensor, start: int, stop: int,
             total: int) -> torch.Tensor:
    """Values of a schedule for steps ``start … stop−1``.

    Shape:
        ``p0``, ``p_end``: ``(E,)`` → returns ``(stop − start, E)``.
    """
    t = torch.arange(start, stop, dtype=torch.float64, device=p0.device)[:, None]  # (S, 1)
    out = fn(p0.double()[None, :], t, total, p_end.double()[None, :])
    return out.to(p0.dtype)
