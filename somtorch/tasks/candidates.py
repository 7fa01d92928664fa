"""What became of each candidate of the object step (:func:`~somtorch.tasks.detect.kept_areas`):
a :class:`Candidate` per area the selection looked at, with one verdict line (``metrics.json``'s
``candidates``), and the count of the areas the ranking left out. The trace records; it never decides.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config import AreaConfig
from .objects import ObjectArea, rank_score

#: The kinds of :class:`Candidate` verdict: kept; refused by the purity or solidity check; skipped by
#: the keep budget; not tried (``max_areas`` kept already, or its segments joined to an earlier area);
#: left out beneath a verified support.
OUTCOMES = ("kept", "refused", "skipped", "not tried", "left out")

__all__ = ["OUTCOMES", "Candidate", "unranked_areas", "verdict"]


@dataclass
class Candidate:
    """An area the selection looked at, its rank score and what became of it (``verdict``: one line,
    e.g. ``"kept"``, ``"refused: purity 0.11 < min_purity 0.15"``, ``"skipped: the kept boxes would
    hold 61 % of the valid pixels > keep_budget 35 %"``). ``rank``: its place among the ranked
    candidates (0 = first), None for an area the ranking left out (beneath a verified support).
    ``outcome``: the verdict's kind, one of :data:`OUTCOMES` (for an area split into parts:
    ``"kept"`` if any part was kept, else the first part's)."""

    area: ObjectArea
    score: float
    rank: int | None
    verdict: str
    outcome: str = "kept"


def unranked_areas(areas: list[ObjectArea], standing: list[ObjectArea], trace: list[Candidate],
                   cfg: AreaConfig, on_support: bool) -> dict[str, int]:
    """Add to ``trace`` the areas beneath a verified support (not in ``standing``) that score above the
    last ranked candidate (they would have been tried), and count the areas left out of the ranking:
    beneath the support, behind their surroundings (contrast < 0), below the ``max_areas`` best."""
    if cfg.rule == "paper":
        return {}
    standing_ids = {id(a) for a in standing}
    beneath = [a for a in areas if id(a) not in standing_ids]
    full = len(trace) >= cfg.max_areas  # else a further candidate would have been tried, whatever its score
    floor = min((c.score for c in trace), default=float("-inf")) if full else float("-inf")
    scored = sorted(((rank_score(a, cfg, on_support=on_support), a) for a in beneath), key=lambda t: -t[0])
    for score, a in scored:
        if score > floor and a.contrast >= 0:
            line = "left out: it lies beneath the verified support"
            trace.append(Candidate(a, score, None, line, "left out"))
    behind = sum(a.contrast < 0 for a in standing)
    counts = {"beneath the verified support": len(beneath), "behind their surroundings": behind,
              "below the max_areas best": len(standing) - behind - sum(c.rank is not None for c in trace)}
    return {k: v for k, v in counts.items() if v > 0}


def verdict(outcomes: list[tuple[str, str]], joined: ObjectArea, cand: ObjectArea) -> tuple[str, str]:
    """``(verdict, outcome)`` of a candidate from the ``(outcome, line)`` of each of its parts, in order."""
    grown = len(joined.neurons) - len(cand.neurons)
    merged = f" (merge joined {grown} segment{'s' if grown != 1 else ''})" if grown else ""
    kinds = [k for k, _ in outcomes]
    kind = "kept" if "kept" in kinds else kinds[0]
    if len(outcomes) == 1:
        return outcomes[0][1] + merged, kind
    n_kept = kinds.count("kept")
    head = f"kept {n_kept} of {len(outcomes)} parts" if n_kept else f"none of {len(outcomes)} parts kept"
    rest = "; ".join(f"part {i + 1} {line}" for i, (k, line) in enumerate(outcomes) if k != "kept")
    return (f"{head}{merged}: {rest}" if rest else head + merged), kind
