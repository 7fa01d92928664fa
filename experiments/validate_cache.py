"""Frame caches and the protocol's choices of ``python -m experiments.validate``.

:class:`SceneCache` holds one frame's segmentations (one per upstream setting of the grid) and
the scores of every candidate on it; :class:`Protocol` turns the scores into per-frame rates and
makes the choices (adoption of each knob, then the greedy join) on a set of frames.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

# the config groups whose change needs a new segmentation (the rest re-runs only the object step)
UPSTREAM = ("features", "ground", "som", "train", "baseline", "method", "ensemble", "seed", "consensus")


def _key(overrides: dict[str, Any]) -> str:
    return ",".join(f"{k}={overrides[k]}" for k in sorted(overrides)) or "default"


class SceneCache:
    """One development scene: its segmentations per upstream setting, scores per candidate."""

    def __init__(self, spec: Any, scene: Any, base: Any, loader: Any = None, ceilings: bool = True) -> None:
        self.spec, self._scene, self.base, self._loader = spec, scene, base, loader
        self.ceilings = ceilings  # the defaults' scores carry the ceilings (seconds per frame)
        self._seg: dict[str, Any] = {}
        self.labels: Any = None  # the label maps of the members last scored (the consensus' kept maps)
        self._target: Any = None  # the scene's all-objects target, computed once
        self.scores: dict[str, dict[str, Any]] = {}

    @property
    def scene(self) -> Any:
        """The frame's scene (loaded on first use when the cache was built from scores alone)."""
        if self._scene is None:
            self._scene = self._loader()
        return self._scene

    def release(self) -> None:
        """Keep the scores, forget what scoring built: the segmentations, the kept labels, the
        all-objects target and, where the cache loads its frame itself, the frame (a later score
        builds them again, deterministically). The parent process holds a cache per frame and grid:
        one int16 segmentation each outgrew 24 GiB (session 43: 920 caches, a ground candidate)."""
        self._seg.clear()
        self.labels = self._target = None
        if self._loader is not None:
            self._scene = None

    def source(self) -> Any:
        """What a worker process reads the frame from: the cache's loader (a picklable callable, such
        as ``partial(load_frame, spec, data_dir)``), or the scene itself where it has none."""
        return self._loader if self._loader is not None else self.scene

    def fresh_scene(self) -> Any:
        """The frame's scene, loaded again (and not kept) where this cache does not hold it."""
        return self._scene if self._scene is not None else self._loader()

    def members(self, overrides: dict[str, Any], first_place: bool = False) -> tuple[Any, list]:
        """``(ground plane, member results)`` of the base config with ``overrides``; the segmentation
        is computed once per upstream setting (features, ground, SOM, training). ``first_place``:
        each member's :attr:`~somtorch.results.MemberResult.first_place` is set too."""
        from dataclasses import replace

        from somtorch.config import with_overrides
        from somtorch.consensus import compact
        from somtorch.disparity.filters import median_filter
        from somtorch.pipeline import detect_runs, on_support, prepare, read_map, segment_runs

        cfg = with_overrides(self.base, overrides)
        up = _key({k: v for k, v in overrides.items() if k.split(".")[0] in UPSTREAM})
        if up not in self._seg:
            scene, window, sigma = read_map(self.scene, cfg)
            valid, ground, usable, feats, train = prepare(scene, cfg, sigma=sigma)
            segs = segment_runs(feats, train, on_support(scene, ground, cfg.features)[0], usable, cfg)
            # kept as int16 (a SOM has far fewer neurons): 30 members x 22 scenes x every upstream
            # setting of the grid as int64 label maps outgrew 24 GiB
            small = [replace(compact(g), som=None) for g in segs]
            # (the object step reads no map; of the median only its window is kept, not a filtered copy)
            self._seg[up] = (ground, small, window)
        ground, segs, window = self._seg[up]
        scene = self.scene
        if window:  # the map the segmentation read (features.median): only a noisy frame's
            scene = replace(scene, disparity=median_filter(scene.disparity, scene.valid, window))
        seg, members = detect_runs(scene, segs, ground, cfg, first_place_ceiling=first_place)  # (int16 held)
        self.labels = seg.labels  # the kept maps' labels (PipelineConfig.consensus), for the ceilings
        return ground, members

    def score(self, overrides: dict[str, Any], saliency: bool = False) -> dict[str, Any]:
        """Counts over the members with ``overrides`` (cached per key); ``saliency`` adds the mean
        F-measure / MAE / S-measure of the kept masks against the union of the objects."""
        from somtorch.evaluation import all_objects, ground_object_share

        key = _key(overrides)
        if key in self.scores and (not saliency or "saliency" in self.scores[key]):
            return self.scores[key]
        ceilings = self.ceilings and not overrides  # the defaults: the ceilings
        ground, members = self.members(overrides, first_place=ceilings)
        if self._target is None:
            self._target = all_objects(self.scene)
        target = self._target
        s = [m.score for m in members]
        self.scores[key] = {
            "runs": len(s), "useful_hits": sum(x.useful_hit for x in s),
            "identified_95": sum(x.identified_95 for x in s),
            "all_objects_hits": sum(target.hit(m.reduction) for m in members),
            "no_object": sum(m.no_object for m in members),
            # how the other runs missed: the wrong object (< 50 % of the main object kept), partial
            # (50-95 %), too much kept (>= 95 % but a reduction under 0.75 x x_opt)
            "misses": {"wrong": sum(x.identified_fraction < 0.5 for x in s),
                       "partial": sum(0.5 <= x.identified_fraction < 0.95 for x in s),
                       "too_much": sum(x.identified_95 and not x.useful_hit for x in s)},
            "mean_reduction": sum(x.reduction_union for x in s) / len(s), "x_opt": s[0].x_opt,
            "ground_object_frac": ground_object_share(ground, self.scene),
            "n_objects": len(target.masks), "valid_share": float(self.scene.valid.float().mean()),
        }
        if ceilings:  # the defaults: how far a perfect choice among the step's areas would go
            from somtorch.evaluation import grouping_ceiling, selection_ceiling, selection_gap

            r = self.base.reduction
            args = (members, self.scene.scored_mask(self.base.object_id), self.scene.valid, s[0].x_opt)
            tol = {"tolerance_px": r.tolerance_px, "tolerance_frac": r.tolerance_frac,
                   "tolerance_image": r.tolerance_image}
            self.scores[key]["best_area_hits"] = selection_ceiling(*args, **tol)
            # ... and a perfect ranking: each candidate tried first (somtorch.tasks.detect.first_place)
            self.scores[key]["first_place_hits"] = sum(bool(m.first_place) for m in members)
            # ... and a perfect choice among each run's maps (PipelineConfig.consensus): a useful one
            # wherever the run has one (with one map a run: the run itself)
            self.scores[key]["best_map_hits"] = sum(
                x.useful_hit if m.maps_useful is None else m.maps_useful > 0 for m, x in zip(members, s))
            self.scores[key]["selection_gap"] = selection_gap(*args, **tol)  # why those runs still missed
            # ... and how far a perfect grouping of the same segments would go
            labels = self.labels  # the defaults' kept maps (members() just ran them)
            self.scores[key]["best_grouping_hits"] = grouping_ceiling(labels, *args[1:], members=members,
                                                                      **tol)
        if saliency:
            from somtorch.saliency_metrics import saliency_scores

            union = self.scene.objects > 0
            per = [saliency_scores(m.reduction.mask, union) for m in members]
            self.scores[key]["saliency"] = {k: sum(p[k] for p in per) / len(per) for k in per[0]}
        return self.scores[key]


class GridCache:
    """One frame read on several pixel grids (``validate``'s ``frame_shifts``): a :class:`SceneCache`
    per grid, and a candidate's scores summed over them (:func:`merge_scores`) — the frame's runs on
    two grids count as twice the seeds would, so the protocol's per-frame rate is the mean over the
    grids and a choice is decided on every grid at once. The gallery's picture and the transforms
    read the first grid's frame (:attr:`scene`); the baselines run on each grid's own."""

    def __init__(self, grids: list[SceneCache]) -> None:
        self.grids = grids
        self.spec, self.base = grids[0].spec, grids[0].base

    @property
    def scene(self) -> Any:
        return self.grids[0].scene

    def fresh_scene(self) -> Any:
        return self.grids[0].fresh_scene()

    def members(self, overrides: dict[str, Any], first_place: bool = False) -> tuple[Any, list]:
        return self.grids[0].members(overrides, first_place)

    @property
    def scores(self) -> dict[str, dict[str, Any]]:
        """The merged scores of every candidate scored on all the grids."""
        keys = [k for k in self.grids[0].scores if all(k in g.scores for g in self.grids[1:])]
        return {k: merge_scores([g.scores[k] for g in self.grids]) for k in keys}

    def score(self, overrides: dict[str, Any], saliency: bool = False) -> dict[str, Any]:
        return merge_scores([g.score(overrides, saliency) for g in self.grids])

    def release(self) -> None:
        """:meth:`SceneCache.release` on every grid."""
        for g in self.grids:
            g.release()


#: per-frame figures that describe the frame, not its runs: not summed over the grids (the first's)
_FRAME_FIGURES = ("n_objects",)


def merge_scores(parts: list[Any]) -> Any:
    """The scores of one frame on several grids as one: counts (ints) summed, rates and means
    (floats) averaged (each grid runs the same seeds), nested dicts merged alike; None where a grid
    has none (a baseline that does not apply). One part: that part itself."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    if first is None or any(p is None for p in parts):
        return None
    if isinstance(first, dict):
        return {k: first[k] if k in _FRAME_FIGURES else merge_scores([p[k] for p in parts]) for k in first}
    if isinstance(first, bool) or not isinstance(first, (int, float)):
        return first
    if isinstance(first, int) and all(isinstance(p, int) and not isinstance(p, bool) for p in parts):
        return sum(parts)
    return float(sum(parts)) / len(parts)


def _score_frame(job: tuple) -> dict[str, dict[str, Any]]:
    """A worker's job: every candidate of ``keys`` (``[(overrides, saliency)]``) on one frame, read
    from ``source`` (:meth:`SceneCache.source`: the same loader the parent's cache would call, so a
    frame loaded transformed — the fresh pass's shifted grid — is scored transformed in a worker
    too); ``ceilings``: :attr:`SceneCache.ceilings`."""
    spec, base, keys, source, threads, ceilings = job
    import torch

    torch.set_num_threads(threads)
    cache = SceneCache(spec, source() if callable(source) else source, base, ceilings=ceilings)
    for ov, sal in keys:
        cache.score(ov, saliency=sal)
    return cache.scores


class Protocol:
    """Per-frame rates of every scored candidate over one set of frame caches, and the choices."""

    def __init__(self, caches: list[SceneCache], cfg: Any, grid: dict[str, list[Any]],
                 defaults: dict[str, Any], runs_log: Path | None = None) -> None:
        from .protocol import FrameTable

        self.caches, self.cfg, self.grid, self.defaults = caches, cfg, grid, defaults
        self.runs_log = runs_log  # where the workers of a candidate scored on demand log (score_missing)
        self.table = FrameTable([c.spec.dataset for c in caches], [c.spec.group for c in caches],
                                [c.spec.real for c in caches], n_boot=cfg.n_boot, seed=cfg.seed)
        self._rates: dict[tuple[str, str], np.ndarray] = {}

    def rates(self, overrides: dict[str, Any], which: str = "useful_hits") -> np.ndarray:
        """One rate (hits / runs) per frame with ``overrides`` (scored on demand; the array is kept,
        as the folds ask for the same candidates again and again)."""
        key = (_key(overrides), which)
        if key not in self._rates:
            # a candidate not scored up front (a greedy join of two knobs): in the workers, as they were
            score_missing(self.caches, overrides, False, self.cfg.workers, self.runs_log)
            rows = [c.score(overrides) for c in self.caches]
            self._rates[key] = np.array([r[which] / r["runs"] for r in rows])
        return self._rates[key]

    def decide(self, cand: dict[str, Any], base: dict[str, Any], table: Any = None) -> Any:
        """:func:`experiments.protocol.decide` of ``cand`` against ``base`` on ``table`` (default: all)."""
        from .protocol import decide

        t = table or self.table
        sel = getattr(t, "index", slice(None))
        cu, bu = self.rates(cand)[sel], self.rates(base)[sel]
        ca, ba = self.rates(cand, "all_objects_hits")[sel], self.rates(base, "all_objects_hits")[sel]
        return decide(t, cu, bu, ca, ba, loss_margin=self.cfg.loss_margin, ni_margin=self.cfg.ni_margin)

    def choose(self, table: Any = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        """The knobs adopted on ``table``'s frames: per knob the adopted value of the largest real macro
        gain; then, greedily by gain, each joins the choice only if it is still adopted against the
        choice so far. Returns ``(overrides, log of the steps)``."""
        best = []
        for k, values in self.grid.items():
            cands = []
            for v in values:
                ov = _overrides(k, v, self.defaults)
                if ov:
                    d = self.decide(ov, {}, table)
                    if d.adopt:
                        cands.append((d.useful[0], k, v, ov))
            if cands:
                best.append(max(cands, key=lambda t: t[0]))
        chosen: dict[str, Any] = {}
        steps = []
        for gain, k, v, ov in sorted(best, key=lambda t: -t[0]):
            trial = {**chosen, **ov}
            d = self.decide(trial, chosen, table) if chosen else self.decide(ov, {}, table)
            steps.append({"knob": k, "value": v, "alone_gain": gain, "joined": d.adopt, **d.as_dict()})
            if d.adopt:
                chosen = trial
        return chosen, steps


def _overrides(key: str, value: Any, defaults: dict[str, Any]) -> dict[str, Any]:
    """The overrides of one grid value; a key ``"a.b+c.d"`` sets several fields at once (``value`` a list)."""
    if value == defaults[key]:
        return {}
    names = key.split("+")
    values = list(value) if len(names) > 1 else [value]
    if len(values) != len(names):
        raise ValueError(f"grid {key!r}: value {value!r} must give {len(names)} values")
    return dict(zip(names, values))


def _default_of(cfg: Any, key: str) -> Any:
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def scorable(scene: Any) -> bool:
    """Whether ``scene`` can be scored: its main object has a valid disparity pixel (an SGBM map may
    have none on a textureless object, a shifted grid may cut it off)."""
    main = scene.main_object_mask
    return main is not None and bool((main & scene.valid).any())


def frames_progress(total: int) -> Any:
    """A progress bar over the frames (off with ``--quiet`` or where stderr is not a terminal)."""
    from .cli import progress_bar

    return progress_bar(total, "frames", "frame")


def score_caches(caches: list[SceneCache], missing: dict[int, list[tuple[dict[str, Any], bool]]],
                 workers: int, runs_log: Path | None, progress: Any) -> None:
    """Score ``missing[i]`` (``[(overrides, saliency)]``) on ``caches[i]``, frame by frame, in
    ``workers`` processes where there are several frames (one thread each: the scores come back, the
    segmentations do not — a combination needed later is segmented again, deterministically)."""
    from somtorch import interrupt

    todo = list(missing)
    if workers > 1 and len(todo) > 1:
        import concurrent.futures as cf

        from somtorch.interrupt import worker_pool

        from .warning_log import worker_start

        start = (worker_start, (str(runs_log),)) if runs_log is not None else (None, ())
        with worker_pool(workers, *start) as pool:  # Ctrl-C / kill: the workers end at once
            jobs = {i: (caches[i].spec, caches[i].base, missing[i], caches[i].source(), 1, caches[i].ceilings)
                    for i in todo}
            futures = {pool.submit(_score_frame, job): i for i, job in jobs.items()}
            for fut in cf.as_completed(futures):
                caches[futures[fut]].scores.update(fut.result())
                progress.update(1)
                interrupt.note(f"after {progress.n} of {len(caches)} frames")
    else:
        for i in todo:
            for ov, sal in missing[i]:
                caches[i].score(ov, saliency=sal)
            caches[i].release()  # as a worker's: only the scores stay
            progress.update(1)
            interrupt.note(f"after {progress.n} of {len(caches)} frames")


def score_missing(caches: list[Any], overrides: dict[str, Any], saliency: bool, workers: int,
                  runs_log: Path | None = None) -> None:
    """Score ``overrides`` (with the saliency metrics where ``saliency``) on every frame of ``caches``
    (:class:`SceneCache` or :class:`GridCache`) that lacks it, by :func:`score_caches`: what the
    protocol asks for after the candidates scored up front (a greedy join of two knobs, the in-sample
    choice's saliency) is scored in ``workers`` processes too, and the parent keeps only the scores.
    Scored frame by frame in the parent, every frame and grid kept a segmentation per upstream
    setting: on 460 frames × 2 grids with a ground candidate that outgrew 24 GiB (session 43)."""
    flat = [g for c in caches for g in (c.grids if isinstance(c, GridCache) else [c])]
    key = _key(overrides)
    todo = {i: [(overrides, saliency)] for i, c in enumerate(flat)
            if key not in c.scores or (saliency and "saliency" not in c.scores[key])}
    if todo:
        progress = frames_progress(len(flat))
        progress.update(len(flat) - len(todo))
        score_caches(flat, todo, workers, runs_log, progress)
        progress.close()
