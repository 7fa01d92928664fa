"""The statistics of the leave-one-dataset-out protocol: paired differences over frames, a bootstrap
that resamples scenes within datasets, and the adoption rule.

Everything here is pure numpy on per-frame rates (hits / runs), so that the rule can be tested on
tables whose answer is known, apart from any segmentation.

The rule (``decide``), for a candidate against the defaults on the same frames and seeds:

* **adopt** when the macro average over the *real* datasets (each dataset counts once, whatever
  its frame count) of the paired main-object difference is positive with its 95 % bootstrap
  interval excluding zero, the all-objects reading does not drop (its real macro difference has a
  lower bound above ``-ni_margin``), and no dataset, real or synthetic, loses more than
  ``loss_margin`` of its useful-hit rate in either reading;
* **or** (the second path, ``path="all"``) when the candidate is *non-inferior on the real data*
  (the real macro difference's lower bound above ``-ni_margin`` in both readings) and *superior over
  every dataset* (the macro average over all datasets, synthetic included, of the paired main-object
  difference has its interval above zero, and its all-objects reading's lower bound stays above
  ``-ni_margin``), with the same per-dataset loss bound. A change the wider evidence supports and a
  small real corpus cannot refute is adopted; where not one real frame changes this is the old
  "evidence decides" clause (the real difference is then exactly zero);
* a knob whose *neutral* value (the check switched off) passes the non-inferiority test —
  lower bound of the real macro difference above ``-ni_margin`` in both readings and no dataset
  losing more than ``loss_margin`` — is not needed and is **removed**, unless the wider evidence
  refutes the removal: the macro average over every dataset of the paired main-object difference
  has its whole interval below zero (``Decision.removable``; the second path's mirror, session 31:
  the real corpus cannot tell, every dataset can).

The bootstrap resamples, within each dataset, its groups (the underlying scenes: a GT and an SGBM
version of one scene move together) with replacement; the per-dataset means are then averaged. A
dataset of a single scene resamples its frames instead (else it would carry no uncertainty, and a
change of one of its frames would look certain).
A fix that helps one failure class and harms none has small paired variance, so its interval
clears zero even when the class is a few frames of one dataset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Decision", "FrameTable", "decide", "non_inferior"]

N_BOOT = 2000
LOSS_MARGIN = 0.10  # the largest drop of one dataset's hit rate a change may cost (either reading)
#: Rates are means of per-frame run fractions (6 of 60 runs lost reads −0.10000000000000002): a loss
#: is "more than" a margin only beyond this rounding slack.
_ROUNDING = 1e-9
NI_MARGIN = 0.02  # non-inferiority: the real macro difference's lower bound must stay above -2 points


@dataclass
class FrameTable:
    """Frames in a fixed order with their dataset, group (scene) and whether the dataset is real;
    precomputes the bootstrap resampling weights once (``n_boot`` × groups), seeded."""

    datasets: list[str]
    groups: list[str]
    real: list[bool]
    n_boot: int = N_BOOT
    seed: int = 0
    _w: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not (len(self.datasets) == len(self.groups) == len(self.real)):
            raise ValueError("datasets, groups and real must have one entry per frame")
        rng = np.random.default_rng(self.seed)
        self.names = list(dict.fromkeys(self.datasets))
        self.real_names = [d for d in self.names if self.real[self.datasets.index(d)]]
        for d in self.names:
            idx = np.flatnonzero(np.array(self.datasets) == d)
            gnames = list(dict.fromkeys(self.groups[i] for i in idx))
            if len(gnames) < 2:  # one scene (in several versions): its frames are the units, else
                gnames = [str(i) for i in idx]  # the dataset would count as certain, whatever it shows
                g_names_of = dict(zip(idx.tolist(), gnames))
            else:
                g_names_of = {int(i): self.groups[i] for i in idx}
            # (frames of d) -> group index; a group's value is the mean of its frames
            g_of = np.array([gnames.index(g_names_of[int(i)]) for i in idx])
            draws = rng.integers(0, len(gnames), size=(self.n_boot, len(gnames)))
            counts = np.zeros((self.n_boot, len(gnames)))
            np.add.at(counts, (np.repeat(np.arange(self.n_boot), len(gnames)), draws.ravel()), 1.0)
            self._w[d] = (idx, g_of, counts / len(gnames))

    def subset(self, keep: list[str]) -> FrameTable:
        """The table of the frames of the datasets in ``keep`` (a fold), with fresh seeded weights."""
        sel = [i for i, d in enumerate(self.datasets) if d in keep]
        t = FrameTable([self.datasets[i] for i in sel], [self.groups[i] for i in sel],
                       [self.real[i] for i in sel], self.n_boot, self.seed)
        t.index = sel  # type: ignore[attr-defined]
        return t

    def per_dataset(self, values: np.ndarray) -> dict[str, float]:
        """Mean of ``values`` (one per frame) per dataset, frames weighted through their groups."""
        out = {}
        for d, (idx, g_of, _) in self._w.items():
            g = np.bincount(g_of, weights=values[idx]) / np.bincount(g_of)
            out[d] = float(g.mean())
        return out

    def macro(self, values: np.ndarray, real_only: bool = True) -> tuple[float, float, float]:
        """Macro average over the (real) datasets and its 95 % percentile bootstrap interval."""
        names = self.real_names if real_only else self.names
        if not names:
            return float("nan"), float("nan"), float("nan")
        point = float(np.mean([self.per_dataset(values)[d] for d in names]))
        boots = np.zeros(self.n_boot)
        for d in names:
            idx, g_of, w = self._w[d]
            g = np.bincount(g_of, weights=values[idx]) / np.bincount(g_of)
            boots += w @ g
        boots /= len(names)
        lo, hi = np.percentile(boots, [2.5, 97.5])
        return point, float(lo), float(hi)


@dataclass
class Decision:
    """The verdict on one candidate against the defaults, with the figures it rests on."""

    adopt: bool
    non_inferior: bool
    useful: tuple[float, float, float]  # real macro paired difference, 95 % interval
    all_objects: tuple[float, float, float]
    useful_all: tuple[float, float, float]  # over every dataset (synthetic included): evidence
    worst: tuple[str, float]  # the dataset of the largest loss (either reading) and that loss
    reasons: list[str]
    path: str = ""  # "real": adopted by the real macro gain; "all": non-inferior on real, superior on all
    removable: bool = False  # as a neutral value: non-inferior on real, and not worse over every dataset

    def as_dict(self) -> dict[str, Any]:
        return {"adopt": self.adopt, "non_inferior": self.non_inferior, "useful": self.useful,
                "all_objects": self.all_objects, "useful_all": self.useful_all, "worst": self.worst,
                "reasons": self.reasons, "path": self.path, "removable": self.removable}


def decide(table: FrameTable, cand_useful: np.ndarray, base_useful: np.ndarray, cand_all: np.ndarray,
           base_all: np.ndarray, *, loss_margin: float = LOSS_MARGIN, ni_margin: float = NI_MARGIN
           ) -> Decision:
    """The adoption rule of the module docstring; arrays hold one rate per frame of ``table``."""
    du, da = cand_useful - base_useful, cand_all - base_all
    useful, allobj = table.macro(du), table.macro(da)
    useful_all = table.macro(du, real_only=False)
    per_u, per_a = table.per_dataset(du), table.per_dataset(da)
    worst_d = min(table.names, key=lambda d: min(per_u[d], per_a[d]))
    worst = (worst_d, min(per_u[worst_d], per_a[worst_d]))
    reasons = []
    if not useful[1] > 0:
        reasons.append(f"real macro useful gain {useful[0]:+.3f} [{useful[1]:+.3f}, {useful[2]:+.3f}] "
                       "does not exclude 0")
    if not allobj[1] > -ni_margin:
        reasons.append(f"all-objects reading drops: {allobj[0]:+.3f} [{allobj[1]:+.3f}, {allobj[2]:+.3f}]")
    within = worst[1] >= -loss_margin - _ROUNDING
    if not within:
        reasons.append(f"{worst[0]} loses {-worst[1]:.3f} > {loss_margin}")
    ni = useful[1] > -ni_margin and allobj[1] > -ni_margin and within
    path = "real" if not reasons else ""
    if not path and ni and useful_all[1] > 0 and table.macro(da, real_only=False)[1] > -ni_margin:
        # the second path: non-inferior on the real datasets, superior over every dataset
        path, reasons = "all", []
    return Decision(adopt=bool(path), non_inferior=ni, useful=useful, all_objects=allobj,
                    useful_all=useful_all, worst=worst, reasons=reasons, path=path,
                    removable=ni and useful_all[2] >= 0)


def non_inferior(d: Decision) -> bool:
    """Whether a simplification (a check switched off) costs nothing the protocol can see: non-inferior
    on the real datasets, and not shown to cost over every dataset (:attr:`Decision.removable`)."""
    return d.removable
