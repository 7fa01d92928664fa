"""The pipeline's fallback warnings: a member that kept (nearly) every valid pixel, found no object
and kept the whole map (``no_object``), or whose maps disagree on what to keep (an ``agreement``
under :data:`LOW_AGREEMENT`), is logged once per scene — or, inside :func:`fallback_summary` (the
many runs of a study job), counted and logged once at the end."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

__all__ = ["LOW_AGREEMENT", "fallback_summary", "warn_fallbacks"]
log = logging.getLogger("somtorch.pipeline")

#: A run whose kept map shares, on average, less than half of its pixels (IoU) with its other maps
#: (``MemberResult.agreement``, ``PipelineConfig.consensus``) has an answer that depends on the seed:
#: on the corpus 14 % of such real runs are useful, 47 % of the generated ones, against 73 % of all
#: runs (``docs/validation_log.md``, session 44).
LOW_AGREEMENT = 0.5

_summary: ContextVar[list[int] | None] = ContextVar("fallback_summary", default=None)


def warn_fallbacks(name: str, members: Sequence[Any]) -> None:
    """One warning line for the members (:class:`~somtorch.results.MemberResult`) that kept (nearly)
    everything, one for those that found no object, one for those whose maps disagree (``agreement``
    under :data:`LOW_AGREEMENT`); inside :func:`fallback_summary` only counted, for its one line at
    the end."""
    everything = [i for i, m in enumerate(members) if not m.no_object and m.reduction.reduction_union < 1.0]
    fallback = sum(m.no_object for m in members)
    divided = [i for i, m in enumerate(members) if m.agreement is not None and m.agreement < LOW_AGREEMENT]
    counts = _summary.get()
    if counts is not None:
        counts[0] += len(everything)
        counts[1] += fallback
        counts[2] += len(members)
        counts[3] += len(divided)
        return
    if everything:
        log.warning("scene %s: member(s) %s keep %s of the valid pixels (reduction < 1 %%): the kept areas cover "
                    "the whole map", name, everything[:5], "all or nearly all")
    if fallback:
        log.warning("scene %s: %d of %d member(s) found no convincing object area; the whole map is kept "
                    "(flagged no_object)", name, fallback, len(members))
    if divided:
        log.warning("scene %s: member(s) %s: the run's maps disagree on what to keep (agreement under %g): its "
                    "answer depends on the seed", name, divided[:5], LOW_AGREEMENT)


@contextmanager
def fallback_summary(name: str) -> Iterator[list[int]]:
    """Many pipeline calls on one scene (the separate runs of a study job) warn once, at the end:
    ``scene S: of N runs, A kept (nearly) all valid pixels, B found no object (whole map kept), C
    with maps that disagree``. Yields ``[kept all, no object, runs, maps disagree]``."""
    counts = [0, 0, 0, 0]
    token = _summary.set(counts)
    try:
        yield counts
    finally:
        _summary.reset(token)
    if counts[0] or counts[1] or counts[3]:
        log.warning("scene %s: of %d runs, %d kept all or nearly all of the valid pixels (reduction < 1 %%), %d found "
                    "no convincing object area (whole map kept, flagged no_object), %d with maps that disagree on "
                    "what to keep (agreement under %g)", name, counts[2], counts[0], counts[1], counts[3],
                    LOW_AGREEMENT)
