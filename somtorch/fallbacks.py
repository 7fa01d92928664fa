"""The pipeline's fallback warnings: a member that kept (nearly) every valid pixel, or found no
object and kept the whole map (``no_object``), is logged once per scene — or, inside
:func:`fallback_summary` (the many runs of a study job), counted and logged once at the end."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

__all__ = ["fallback_summary", "warn_fallbacks"]
log = logging.getLogger("somtorch.pipeline")

_summary: ContextVar[list[int] | None] = ContextVar("fallback_summary", default=None)


def warn_fallbacks(name: str, members: Sequence[Any]) -> None:
    """One warning line for the members (:class:`~somtorch.results.MemberResult`) that kept (nearly)
    everything, one for those that found no object; inside :func:`fallback_summary` only counted, for
    its one line at the end."""
    everything = [i for i, m in enumerate(members) if not m.no_object and m.reduction.reduction_union < 1.0]
    fallback = sum(m.no_object for m in members)
    counts = _summary.get()
    if counts is not None:
        counts[0] += len(everything)
        counts[1] += fallback
        counts[2] += len(members)
        return
    if everything:
        log.warning("scene %s: member(s) %s keep %s of the valid pixels (reduction < 1 %%): the kept areas cover "
                    "the whole map", name, everything[:5], "all or nearly all")
    if fallback:
        log.warning("scene %s: %d of %d member(s) found no convincing object area; the whole map is kept "
                    "(flagged no_object)", name, fallback, len(members))


@contextmanager
def fallback_summary(name: str) -> Iterator[list[int]]:
    """Many pipeline calls on one scene (the separate runs of a study job) warn once, at the end:
    ``scene S: of N runs, A kept (nearly) all valid pixels, B found no object (whole map kept)``.
    Yields ``[kept all, no object, runs]``."""
    counts = [0, 0, 0]
    token = _summary.set(counts)
    try:
        yield counts
    finally:
        _summary.reset(token)
    if counts[0] or counts[1]:
        log.warning("scene %s: of %d runs, %d kept all or nearly all of the valid pixels (reduction < 1 %%), %d found "
                    "no convincing object area (whole map kept, flagged no_object)", name, counts[2], counts[0],
                    counts[1])
