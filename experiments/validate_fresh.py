"""The protocol's fresh pass and its pixel grids (``experiments.validate``): the defaults, and an
adopted choice, scored again on runs nothing was chosen on — the next seeds, each frame on a pixel
grid shifted by ``fresh_shift`` px (session 40) — and the frames as the protocol reads them on
the shifted grids it decides on (``frame_shifts``, session 41)."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .validate_cache import Protocol, SceneCache, frames_progress, scorable, score_caches

if TYPE_CHECKING:
    from .validate import ValidateConfig


#: the key of a ``scores_out`` file that records the grid shifts its scores were read on
SHIFT_KEY = "__frame_shifts__"


def check_shifts(cfg: ValidateConfig) -> list[int]:
    """``cfg.frame_shifts`` as a list, checked before any work (with ``cfg.fresh_shift``): whole
    numbers of px, 0 or more, at least one grid and none twice; no ``sgbm:`` transform where the
    first grid is shifted (it matches a frame's stereo pair again at its full size)."""
    for name, values in (("fresh_shift", [cfg.fresh_shift]), ("frame_shifts", list(cfg.frame_shifts))):
        for v in values:
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name}: {v!r}: a grid shift must be a whole number of px, 0 or more "
                                 "(0 = the frames as given)")
    shifts = list(cfg.frame_shifts)
    if not shifts or len(set(shifts)) < len(shifts):
        raise ValueError(f"frame_shifts={shifts}: give each grid once, at least one "
                         "(0 = the frames as given)")
    if shifts[0] and any(k.startswith("sgbm:") for k in cfg.transforms):
        raise ValueError(f"frame_shifts={shifts} with an sgbm: transform: it matches each frame's stereo "
                         "pair again at its full size; run the sgbm: transforms with the first grid at 0")
    return shifts


def grid_name(frame: str, shift: int) -> str:
    """The key of ``frame`` read on the grid shifted by ``shift`` px in a ``scores_out`` file (the
    frame's name as given)."""
    return f"{frame}@{shift}" if shift else frame


def per_grid_macros(table: Any, on_grids: list[SceneCache], shifts: list[int]) -> dict[str, dict[str, float]]:
    """The defaults' useful-hit rates on each grid alone (``on_grids``: frame by frame, each on every
    grid of ``shifts``), keyed by the shift: the real and all-dataset macros and ``datasets``, the
    rate per dataset — how far apart the grids the protocol sums read the same rule, and where."""
    out = {}
    for j, shift in enumerate(shifts):
        v = np.array([(r := c.score({}))["useful_hits"] / r["runs"] for c in on_grids[j::len(shifts)]])
        out[str(shift)] = {"macro_real": table.macro(v, True)[0], "macro_all": table.macro(v, False)[0],
                           "datasets": table.per_dataset(v)}
    return out


def shifted_frame(spec: Any, data_dir: Path, shift: int) -> Any:
    """The frame of ``spec`` on a pixel grid shifted by ``shift`` px (``add_junk(scene, "shift:N")``;
    as given at 0): how the protocol (``frame_shifts``) and its fresh pass read it."""
    from .datasets import load_frame
    from .scenes import add_junk

    scene = load_frame(spec, data_dir)
    return add_junk(scene, f"shift:{shift}") if shift else scene


def shift_checked(scene: Any, spec: Any, shift: int, field: str) -> Any:
    """``scene`` on a grid shifted by ``shift`` px, checked before any work: the shift must leave the
    frame and a valid pixel of its main object (``ValueError`` naming ``field`` and the frame)."""
    if not shift:
        return scene
    from .scenes import add_junk

    try:
        moved = add_junk(scene, f"shift:{shift}")
    except ValueError as e:
        raise ValueError(f"{field}: a shift of {shift} px on frame {spec.name!r}: {e}") from None
    if not scorable(moved):
        raise ValueError(f"{field}: a shift of {shift} px leaves no valid pixel of the main object of frame "
                         f"{spec.name!r}: use a smaller shift")
    return moved


def score_fresh_seeds(specs: list[Any], cfg: ValidateConfig, grid: dict[str, list[Any]],
                      defaults: dict[str, Any], choice: dict[str, Any], data_dir: Path,
                      runs_log: Path | None = None) -> dict[str, Any]:
    """The defaults, and the in-sample ``choice`` where the protocol adopted one, scored again on the
    next ``ensemble`` seeds (``seed + ensemble`` …), each frame on a pixel grid shifted by
    ``cfg.fresh_shift`` px further than the largest of the main pass's grids
    (:func:`shifted_frame`): runs nothing was chosen on. Every rule of the project was chosen by
    looking at the runs of the first seeds on the frames as given, so their figures are fitted to
    those runs and to the pixels the strided steps read there (session 40: the real macro falls by
    4–5 points on a grid shifted by 3–7 px) as well as to the frames; the fresh pass says what the
    same scenes give on runs nobody looked at, and a choice is **confirmed** where the protocol
    adopts it again there. Per dataset and as macro averages: ``default_useful_hits``,
    ``default_all_objects_hits`` (and ``in_sample_…`` with a choice); ``decision``, ``confirmed``:
    None without a choice; ``shift``: the grid's shift (from the frames as given)."""
    from dataclasses import replace

    base = replace(cfg, seed=cfg.seed + cfg.ensemble)
    shift = max(cfg.frame_shifts) + cfg.fresh_shift
    caches = [SceneCache(s, None, base, loader=partial(shifted_frame, s, data_dir, shift), ceilings=False)
              for s in specs]
    keys = [({}, False)] + ([(choice, False)] if choice else [])
    progress = frames_progress(len(specs))
    score_caches(caches, {i: keys for i in range(len(caches))}, cfg.workers, runs_log, progress)
    progress.close()
    proto = Protocol(caches, base, grid, defaults)
    t = proto.table
    out: dict[str, Any] = {"seeds": [base.seed, base.seed + cfg.ensemble - 1], "shift": shift,
                           "choice": dict(choice),
                           "datasets": {d: {} for d in t.names}, "macro_real": {}, "macro_all": {},
                           "decision": None, "confirmed": None}
    for part, ov in [("default", {})] + ([("in_sample", choice)] if choice else []):
        for m in ("useful_hits", "all_objects_hits"):
            v = proto.rates(ov, m)
            for d, x in t.per_dataset(v).items():
                out["datasets"][d][f"{part}_{m}"] = x
            out["macro_real"][f"{part}_{m}"] = t.macro(v, True)[0]
            out["macro_all"][f"{part}_{m}"] = t.macro(v, False)[0]
    if choice:
        dec = proto.decide(choice, {})
        out["decision"], out["confirmed"] = dec.as_dict(), bool(dec.adopt)
    return out
