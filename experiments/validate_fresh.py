"""The protocol's fresh pass and its pixel grids (``experiments.validate``): the defaults, and an
adopted choice, scored again on runs nothing was chosen on — the next seeds, each frame on a pixel
grid shifted by ``fresh_shift`` px (session 40) — and the frames as the protocol reads them on a
shifted grid (``frame_shift``)."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .validate_cache import Protocol, SceneCache, frames_progress, scorable, score_caches

if TYPE_CHECKING:
    from .validate import ValidateConfig


#: the key of a ``scores_out`` file that records the grid shift its scores were read on
SHIFT_KEY = "__frame_shift__"


def shifted_frame(spec: Any, data_dir: Path, shift: int) -> Any:
    """The frame of ``spec`` on a pixel grid shifted by ``shift`` px (``add_junk(scene, "shift:N")``;
    as given at 0): how the protocol (``frame_shift``) and its fresh pass read it."""
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
    ``cfg.fresh_shift`` px further than the main pass's (:func:`shifted_frame`): runs nothing was
    chosen on. Every rule of the project was chosen by looking at the runs of the first seeds on
    the frames as given, so their figures are fitted to those runs and to the pixels the strided
    steps read there (session 40: the real macro falls by 4–5 points on a grid shifted by 3–7 px)
    as well as to the frames; the fresh pass says what the same scenes give on runs nobody looked
    at, and a choice is **confirmed** where the protocol adopts it again there. Per dataset and as
    macro averages: ``default_useful_hits``, ``default_all_objects_hits`` (and ``in_sample_…`` with
    a choice); ``decision``, ``confirmed``: None without a choice; ``shift``: the grid's shift (from
    the frames as given)."""
    from dataclasses import replace

    base = replace(cfg, seed=cfg.seed + cfg.ensemble)
    shift = cfg.frame_shift + cfg.fresh_shift
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
