"""``python -m experiments.train_baseline`` / ``somtorch-train-baseline``: the learned baseline.

Renders the missing training frames (every family x camera of ``data.*``, seeds from
``data.first_seed``, GT and SGBM versions) into the generator's cache, trains the U-Net of
``model.*`` with ``fit.*`` and saves it into the model cache with its JSON sidecar (data hash,
configs, held-out metrics); a model already in the cache is reused. ``folds=true`` also trains one
model without each camera (the validation's leave-one-dataset-out folds). The estimated time and
memory are printed first; a run over ``budget_minutes`` or ``max_memory_frac`` is refused in one line.

**Real data are never used for training**: frames come only from :mod:`somtorch.synth`, and every
frame folder is checked to be the generator's and to lie under neither ``paths.data_dir`` nor any
folder of a ``real: true`` dataset of ``conf/datasets.yaml``.

    somtorch-train-baseline                               # the default model (~15 min on 2 idle cores)
    somtorch-train-baseline folds=true                    # + the three leave-one-camera-out models
    somtorch-train-baseline fit.epochs=2 data.frames=4    # a quick look
"""

from __future__ import annotations

if __name__ == "__main__":  # --help before the heavy imports (torch, Hydra)
    from .help import maybe_print_help

    maybe_print_help("train_baseline")

import logging
import time
from pathlib import Path

import hydra
from hydra.core.config_store import ConfigStore
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from . import CONF
from .schema import register
from .train_baseline_config import TrainBaselineConfig

log = logging.getLogger("somtorch.train_baseline")
register()
ConfigStore.instance().store(name="train_baseline_schema", node=TrainBaselineConfig)


def forbidden_roots(cfg: TrainBaselineConfig) -> tuple[Path, ...]:
    """The real data: ``paths.data_dir`` and the folder of every frame of a ``real: true`` dataset."""
    from .datasets import datasets

    data_dir = Path(to_absolute_path(cfg.paths.data_dir))
    real = {data_dir / f.folder for d in datasets(real=True) for f in d.frames}
    return (data_dir, *sorted(real))


def _runs(cfg: TrainBaselineConfig) -> list:
    from somtorch.tasks.baselines.learned import fold_data

    runs = [fold_data(None, cfg.data)]
    if cfg.folds:
        runs += [fold_data(c, cfg.data) for c in cfg.data.cameras]
    return runs


def plan(cfg: TrainBaselineConfig, corpus: str) -> tuple[list, list[tuple[str, str, int]], float, int]:
    """``(data configs, frames to render, estimated seconds, estimated peak bytes)``; refuses a run
    over the budget (:class:`somtorch.resources.ResourceError`, one line)."""
    from somtorch.baselines.learned.data import synthetic_frames
    from somtorch.baselines.learned.store import model_path
    from somtorch.baselines.learned.train import estimate
    from somtorch.resources import ResourceError, available_memory, fmt_bytes, fmt_seconds
    from somtorch.synth.store import dataset_dir, is_current, read_manifest

    runs = _runs(cfg)
    todo, manifests, seconds, peak, n_cached = set(), {}, 0.0, 0, 0
    for data in runs:
        refs = synthetic_frames(data)  # checks the family and camera names
        for r in refs:
            ds = dataset_dir(r.family, r.camera, data.scale, corpus)
            if ds not in manifests:
                manifests[ds] = read_manifest(ds)
            if not is_current(ds, r.seed, manifests[ds]):
                todo.add((r.family, r.camera, r.seed))
        cached = model_path(cfg.model, data, cfg.fit, cfg.cache).is_file() and not cfg.retrain
        n_cached += cached
        n_held = sum(r.held_out for r in refs)
        est = estimate(cfg.model, cfg.fit, train_frames=0 if cached else len(refs) - n_held,
                       held_out_frames=0 if cached else n_held)
        seconds += est.seconds
        peak = max(peak, est.peak_bytes)
    render = estimate(cfg.model, cfg.fit, train_frames=0, held_out_frames=0, frames_to_render=len(todo),
                      workers=cfg.workers).render_s
    seconds += render
    avail, source = available_memory()
    models = f"{len(runs)} model(s)" + (f" ({n_cached} cached)" if n_cached else "")
    what = (f"{models}, {len(todo)} frame(s) to render: ~{fmt_seconds(seconds)} on 2 idle cores "
            f"(rendering {fmt_seconds(render)}), ~{fmt_bytes(peak)} peak")
    if seconds > 60 * cfg.budget_minutes:
        raise ResourceError(f"training the learned baseline would take {what}; over budget_minutes={cfg.budget_minutes:g}: "
                            f"lower data.frames, fit.epochs or model.widths, or raise budget_minutes")
    if avail > 0 and peak > cfg.max_memory_frac * avail:
        raise ResourceError(f"training the learned baseline would need {what}; over max_memory_frac={cfg.max_memory_frac:g} "
                            f"of {fmt_bytes(avail)} available ({source}): lower data.frames or fit.batch_size")
    log.info("estimated: %s", what)
    return runs, sorted(todo), seconds, peak


def train(cfg: TrainBaselineConfig, progress: bool = True) -> list[dict]:
    """Plan, render, train (or reuse) every model of ``cfg``; their sidecar documents."""
    from torch.utils.tensorboard import SummaryWriter

    from somtorch.baselines.learned.data import RealDataError
    from somtorch.baselines.learned.store import model_path, train_or_load
    from somtorch.synth.store import cache_root

    from .synth import generate
    from .synth_config import SynthConfig

    if cfg.workers < 1 or not cfg.budget_minutes > 0 or not 0 < cfg.max_memory_frac <= 1:
        raise ValueError(f"need workers >= 1, budget_minutes > 0 and 0 < max_memory_frac <= 1; got workers={cfg.workers}, "
                         f"budget_minutes={cfg.budget_minutes}, max_memory_frac={cfg.max_memory_frac}")
    corpus = str(Path(to_absolute_path(cfg.corpus)) if cfg.corpus else cache_root())
    forbidden = forbidden_roots(cfg)
    for root in forbidden:
        r = root.resolve()
        if Path(corpus).resolve() == r or r in Path(corpus).resolve().parents:
            raise RealDataError(f"corpus={corpus} lies under the real data {r}; the learned baseline trains on "
                                f"generated frames only")
    runs, todo, _, _ = plan(cfg, corpus)
    if todo:
        t0 = time.perf_counter()
        for fam, cam in sorted({(f, c) for f, c, _ in todo}):
            seeds = sorted(s for f, c, s in todo if (f, c) == (fam, cam))
            generate(SynthConfig(families=[fam], cameras=[cam], n=seeds[-1] - seeds[0] + 1, start=seeds[0],
                                 scale=cfg.data.scale, workers=cfg.workers, cache=corpus), progress=progress)
        log.info("rendered %d frame(s) in %.0f s", len(todo), time.perf_counter() - t0)
    out = []
    for data in runs:
        tb = model_path(cfg.model, data, cfg.fit, cfg.cache).parent / "tb"
        writer = SummaryWriter(str(tb))
        try:
            model, meta, path = train_or_load(cfg.model, data, cfg.fit, root=cfg.cache, corpus=corpus,
                                              forbidden=forbidden, progress=progress, log=writer.add_scalar,
                                              retrain=cfg.retrain)
            for k, v in meta["held_out_metrics"].items():
                writer.add_scalar(f"held_out/{k}", v, 0)
        finally:
            writer.close()
        m = meta["held_out_metrics"]
        log.info("%s (cameras %s): %d parameters, trained in %s s; held out: mask IoU %.3f, box IoU %.3f, "
                 "identified %.1f %% of %d frames", path, ",".join(data.cameras), meta["parameters"],
                 meta["train_s"], m["mask_iou"], m["box_iou"], 100 * m["identified_95"], m["frames"])
        out.append(meta)
    return out


@hydra.main(version_base="1.3", config_path=str(CONF), config_name="train_baseline")
def main(dcfg: DictConfig) -> list[dict]:
    from .cli import configure_threads, show_progress
    from .schema import one_line_errors

    with one_line_errors(log):
        cfg: TrainBaselineConfig = OmegaConf.to_object(dcfg)
        configure_threads()
        return train(cfg, progress=show_progress())


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, TrainBaselineConfig)


if __name__ == "__main__":
    cli()
