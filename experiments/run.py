"""``python -m experiments.run`` / ``somtorch-run``: the whole pipeline on one scene.

Compose the config (conf/run.yaml), load the scene, run steps 1a–1d, write into the Hydra run
directory: PNG maps, the reduced map (NPZ), PLY point clouds and a PNG view, the SOM checkpoint,
TensorBoard events and ``metrics.json`` (written last, atomically: its presence marks a complete run).

Examples::

    python -m experiments.run                                   # embedded Motorcycle scene
    python -m experiments.run data=kitti2015 ensemble=20         # a shared scene, 20 seeds at once
    python -m experiments.run data.source=/path/disp.pfm objects=paper
    python -m experiments.run data=stereo_pair data.left=l.png data.right=r.png
"""

from __future__ import annotations

if __name__ == "__main__":  # signals and --help answered before the heavy imports (torch, Hydra)
    from .entry import start

    start("run")

import dataclasses
import logging
import shutil
import tempfile
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from . import CONF
from .schema import RunConfig, register

# absolute, so that the console script and python -m find the same configs from any directory
CONF_DIR = str(CONF)
log = logging.getLogger("somtorch.run")
register()


def load_input(cfg: RunConfig):
    """The scene named by ``cfg.data`` (every check on the files happens here, before any work)."""
    from somtorch.disparity.io import read_image
    from somtorch.disparity.camera import read_calibration
    from somtorch.disparity import Camera, load_scene
    from somtorch.disparity.stereo import SGBMParams, load_stereo_pair

    d = cfg.data
    if d.left is not None or d.right is not None:
        if d.left is None or d.right is None:
            raise ValueError("data.left and data.right must both be set for a stereo pair")
        left_path, right_path = to_absolute_path(d.left), to_absolute_path(d.right)
        camera = None
        if d.calibration is not None and d.focal_px is not None:
            raise ValueError("give data.calibration or data.focal_px / data.baseline, not both")
        if d.calibration is not None:
            camera = read_calibration(to_absolute_path(d.calibration), tuple(read_image(left_path).shape[-2:]))
        if (d.focal_px is None) != (d.baseline is None):
            raise ValueError("data.focal_px and data.baseline must be given together (or neither)")
        if d.focal_px is not None:
            h, w = read_image(left_path).shape[-2:]
            camera = Camera(focal_px=d.focal_px, cx=d.cx if d.cx is not None else (w - 1) / 2,
                            cy=d.cy if d.cy is not None else (h - 1) / 2, baseline=d.baseline,
                            baseline_unit=d.baseline_unit, doffs=d.doffs)
        return load_stereo_pair(left_path, right_path, SGBMParams(**dataclasses.asdict(d.sgbm)), camera=camera,
                                name=d.name or Path(d.left).stem)
    if d.family is not None:  # a generated frame (conf/data/synthetic.yaml), from the cache or made now
        from somtorch.synth import load_frame

        given = {"seed": d.seed, "camera": d.camera, "version": d.version}
        scene = load_frame(d.family, **{k: v for k, v in given.items() if v is not None})
        if d.name:
            scene.name = d.name
        return scene
    if d.source is None:
        raise ValueError("data.source is empty: give 'motorcycle', a scene folder or a disparity file")
    spec = d.source if d.source == "motorcycle" else to_absolute_path(d.source)
    disp = to_absolute_path(d.disparity_file) if d.disparity_file else None
    if d.frame is not None:
        from somtorch.disparity.loading import load_kitti_frame

        scene = load_kitti_frame(spec, d.frame, disparity=d.disparity_file or "disp_occ_0")
    else:
        scene = load_scene(spec, disparity_file=disp, disparity_scale=d.disparity_scale)
    if d.calibration is not None:
        scene.camera = read_calibration(to_absolute_path(d.calibration), (scene.height, scene.width))
    if d.name:  # one name in the log, metrics.json and the run folder (kitti2015, not devkit_demo)
        scene.name = d.name
    return scene


def check_resources(jobs, resources, what: str):
    """Refuse (:class:`somtorch.resources.ResourceError`, one line) work that would need more memory or
    time than ``resources`` (a :class:`~somtorch.config.ResourcesConfig`) allows. ``jobs``: ``(scene,
    pipeline config, times)`` run one after another (peak: the largest; time: the sum); an iterable,
    so that a long list of frames is read one at a time. Returns the :class:`~somtorch.resources.Estimate`."""
    from somtorch.pipeline import resource_estimate
    from somtorch.resources import check, combine

    est = combine([resource_estimate(scene, c).times(n) for scene, c, n in jobs])
    log.debug("%s: estimated %s", what, est.describe())
    if resources.check:
        check(est, max_memory_frac=resources.max_memory_frac, max_hours=resources.max_hours, what=what)
    return est


def execute(cfg: RunConfig, out_dir: Path, config_dict: dict | None = None) -> dict:
    """Run the pipeline described by ``cfg`` and write every output into ``out_dir``.

    Everything is written into a staging folder first and moved into ``out_dir`` only when the
    whole run succeeded (``metrics.json`` last), so a failed or killed run leaves no partial results.
    """
    import torch

    from somtorch import interrupt
    from somtorch.atomic import commit_staged, write_json
    from somtorch.outputs import summarize, write_maps, write_point_clouds
    from somtorch.pipeline import run_pipeline, unscorable

    t_start = time.perf_counter()
    out_t: dict[str, float] = {}  # seconds spent writing each kind of output

    def timed(kind: str):
        t0 = time.perf_counter()
        return lambda: out_t.__setitem__(kind, out_t.get(kind, 0.0) + time.perf_counter() - t0)

    if not 0 <= cfg.output.member < cfg.runs:  # checked before any file is read
        raise ValueError(f"output.member={cfg.output.member} must be in [0, runs={cfg.runs}) (ensemble="
                         f"{cfg.ensemble}, method={cfg.method!r})")
    scene = load_input(cfg)
    t_load = time.perf_counter() - t_start
    if cfg.object_id is not None and scene.objects is None:
        raise ValueError(f"object_id={cfg.object_id} but scene {scene.name!r} has no object mask")
    why = unscorable(scene, cfg.object_id)
    if why is not None:  # the reduction needs no labels: reduce it, unscored
        log.warning("%s; the runs are not scored", why)
        scene = dataclasses.replace(scene, objects=None, object_info=[])
    what = f"scene {scene.name} ({scene.width}x{scene.height}, ensemble={cfg.runs})"
    log.info("%s: estimated %s", what, check_resources([(scene, cfg, 1)], cfg.resources, what).describe())
    out_dir.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=out_dir))
    writer = None
    try:
        if cfg.output.tensorboard:
            done = timed("tensorboard")
            from torch.utils.tensorboard import SummaryWriter
            writer = SummaryWriter(str(stage / "tb"))
            done()
        from tqdm.auto import tqdm

        from .cli import show_progress

        steps = ["pipeline"] + (["maps"] if cfg.output.maps else []) + (["point clouds"] if cfg.output.pointcloud else [])
        bar = tqdm(total=len(steps), desc=f"{scene.name}", unit="stage", disable=not show_progress(), leave=False)
        bar.set_postfix_str(steps[0])
        result = run_pipeline(scene, cfg, progress=show_progress(), log_training=writer.add_scalar if writer else None)
        bar.update()
        metrics = summarize(scene, result, config_dict)
        if result.ground is not None:
            metrics["ground_plane"] = result.ground.as_dict()
        if cfg.output.pointcloud and cfg.output.render and cfg.output.render_backend != "matplotlib" \
                and scene.camera is not None:  # whether Open3D renders: asked while the pictures are drawn
            from somtorch.geometry import start_open3d_probe  # (a core each, not beside the pipeline)
            start_open3d_probe()
        if cfg.output.maps:
            interrupt.note("while writing the pictures")
            bar.set_postfix_str("maps")
            done = timed("maps")
            pics = write_maps(scene, result, stage, member=cfg.output.member)
            done()
            bar.update()
            if writer is not None:
                done = timed("tensorboard")
                for name, img in pics.items():
                    writer.add_image(f"maps/{name}", torch.from_numpy(img).permute(2, 0, 1), 0)
                done()
        if cfg.output.pointcloud:
            interrupt.note("while writing the point clouds")
            bar.set_postfix_str("point clouds")
            done = timed("point_clouds")
            metrics["pointcloud"] = write_point_clouds(
                scene, result, stage, member=cfg.output.member, voxel_size=cfg.output.voxel_size,
                render=cfg.output.render, render_backend=cfg.output.render_backend)
            done()
        bar.close()
        if cfg.output.checkpoint and result.som is not None:
            done = timed("checkpoint")
            result.som.save(stage / "som.safetensors")
            done()
        if writer is not None:
            done = timed("tensorboard")
            _log_hparams(writer, cfg, metrics)
            writer.close()
            writer = None
            done()
        # the stages of the pipeline (compute) apart from writing pictures and files (output)
        metrics["timings_s"] = {"load": t_load, **metrics["timings_s"]}
        metrics["output_timings_s"] = out_t
        total = time.perf_counter() - t_start
        compute, output = sum(metrics["timings_s"].values()), sum(out_t.values())
        metrics["wall_s"] = {"compute": compute, "output": output, "other": max(0.0, total - compute - output),
                             "total": total}
        write_json(stage / "metrics.json", metrics)
        commit_staged(stage, out_dir)  # metrics.json last: its presence marks a complete run
    finally:
        if writer is not None:
            writer.close()
        shutil.rmtree(stage, ignore_errors=True)
    s = metrics.get("summary")
    w = metrics["wall_s"]
    log.info("scene %s: %d valid px, %d train px; %.1f s: compute %.1f s %s, output %.1f s %s", scene.name,
             scene.n_valid, metrics["pixels"]["train"], w["total"], w["compute"],
             {k: round(v, 3) for k, v in metrics["timings_s"].items()}, w["output"],
             {k: round(v, 2) for k, v in out_t.items()})
    m0 = metrics["members"][cfg.output.member]
    log.info("member %d: %d areas, kept %d, reduction %.1f %% (union), %.1f %% (crops)", cfg.output.member,
             m0["n_areas"], len(m0["kept_areas"]), m0["reduction_union"], m0["reduction_crops"])
    if metrics.get("object_step"):
        log.info("object step: %s — %s", metrics["object_step"]["mode"], metrics["object_step"]["reason"])
    if s:
        log.info("object: identified_100 %d/%d, identified_95 %d/%d, useful hits %d, x_opt %.1f %%",
                 s["identified_100"], s["runs"], s["identified_95"], s["runs"], s["useful_hits"], s["x_opt"])
    from .schema import log_to_file

    log_to_file(log, logging.INFO, "outputs in %s", out_dir)
    print(f"outputs in {out_dir}", flush=True)  # always, --quiet too: where the results are
    return metrics


def _log_hparams(writer, cfg: RunConfig, metrics: dict) -> None:
    hp = {"rows": cfg.som.rows, "cols": cfg.som.cols, "mode": cfg.train.mode, "epochs": cfg.train.epochs,
          "lr": cfg.train.lr, "sigma": cfg.train.sigma if cfg.train.sigma is not None else -1.0,
          "d_weight": cfg.features.d_weight, "train_stride": cfg.features.train_stride,
          "objects_rule": cfg.objects.rule, "similarity": cfg.objects.similarity,
          "tolerance_frac": cfg.reduction.tolerance_frac,
          "tolerance_image": cfg.reduction.tolerance_image, "ensemble": cfg.ensemble, "seed": cfg.seed}
    m0 = metrics["members"][cfg.output.member]
    res = {"hparam/reduction_union": m0["reduction_union"],
           "hparam/quantization_error": m0["quantization_error"] or float("nan")}
    if metrics.get("summary"):
        s = metrics["summary"]
        res["hparam/identified_95_rate"] = s["identified_95"] / s["runs"]
        res["hparam/useful_hit_rate"] = s["useful_hits"] / s["runs"]
    writer.add_hparams(hp, res, run_name=".")


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="run")
def main(dcfg: DictConfig) -> dict:
    """Hydra entry point."""
    from .cli import configure_threads

    configure_threads()
    from .cli import interruptible, marked_if_failed, quiet
    from .schema import one_line_errors, to_config
    from somtorch.locks import exclusive_folder

    out_dir = Path(HydraConfig.get().runtime.output_dir)

    if quiet():  # the console shows warnings and errors only; run.log keeps everything
        for h in logging.getLogger().handlers:
            if isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler):
                h.setLevel(logging.WARNING)
    # an error or a refusal: one line, FAILED; Ctrl-C / kill: one line, FAILED, 130 / 143
    with marked_if_failed(out_dir), interruptible(out_dir), one_line_errors(log):
        cfg: RunConfig = to_config(dcfg)  # validates types and dataclass rules
        out_dir.mkdir(parents=True, exist_ok=True)
        with exclusive_folder(out_dir):  # two runs never write into one folder
            return execute(cfg, out_dir, OmegaConf.to_container(dcfg, resolve=True))


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, RunConfig)


if __name__ == "__main__":
    cli()
