"""``torchrun ... -m experiments.distributed``: the main job with its SOM trained across processes.

Every rank composes the same config (``conf/run.yaml`` + the command-line overrides), loads the
scene and computes the features; training runs on the process group (``train.parallel=data``: each
rank holds a shard of the training pixels and the batch map's sums are all-reduced every epoch;
``train.parallel=members``: the ensemble members are dealt to the ranks and gathered). Rank 0 then
writes the outputs of ``experiments.run`` into ``paths.output_dir/distributed/<time>`` (its own
folder, staged and committed atomically); the other ranks write nothing.

    torchrun --standalone --nproc_per_node=2 -m experiments.distributed train.parallel=data
    torchrun --standalone --nproc_per_node=4 -m experiments.distributed train.parallel=members ensemble=20
    # several nodes (one torchrun per node; SLURM: srun runs it once per node, see docs/scaling.md)
    torchrun --nnodes=2 --nproc_per_node=8 --rdzv_backend=c10d --rdzv_endpoint=$HEAD:29500 \\
        -m experiments.distributed train.parallel=data data=kitti2015

Backend: ``gloo`` (the pipeline's tensors live on the CPU); ``SOMTORCH_DIST_BACKEND=nccl`` for
CUDA tensors.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from pathlib import Path

log = logging.getLogger("somtorch.distributed")


def compose_config(overrides: list[str]):
    """The :class:`~experiments.schema.RunConfig` of ``conf/run.yaml`` with ``overrides``; the
    default ``train.parallel`` here is ``data`` (the point of launching this module)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from .run import CONF_DIR

    if not any(o.startswith("train.parallel=") for o in overrides):
        overrides = [*overrides, "train.parallel=data"]
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        dcfg = compose("run", overrides=overrides)
    return OmegaConf.to_object(dcfg), OmegaConf.to_container(dcfg, resolve=True)


def main(argv: list[str] | None = None) -> int:
    import torch.distributed as dist

    from .schema import one_line_errors

    logging.basicConfig(level=logging.INFO, format="[%(asctime)s][rank %(rank)s][%(levelname)s] %(message)s")
    _from_slurm(os.environ)
    from .cli import configure_threads

    configure_threads()  # the local ranks share the node's cores
    rank_env = os.environ.get("RANK")
    old = logging.getLogRecordFactory()

    def factory(*args, **kwargs):
        rec = old(*args, **kwargs)
        rec.rank = rank_env if rank_env is not None else "-"
        return rec

    logging.setLogRecordFactory(factory)
    with one_line_errors(log):
        cfg, cfg_dict = compose_config(list(sys.argv[1:] if argv is None else argv))
        if rank_env is None or "WORLD_SIZE" not in os.environ:
            raise ValueError("experiments.distributed runs under torchrun (RANK / WORLD_SIZE unset): "
                             "torchrun --standalone --nproc_per_node=2 -m experiments.distributed")
        dist.init_process_group(os.environ.get("SOMTORCH_DIST_BACKEND", "gloo"))
        try:
            return _run(cfg, cfg_dict, dist)
        finally:
            dist.destroy_process_group()
    return 2


def _from_slurm(env) -> None:
    """Under ``srun`` (one task per process, no torchrun): RANK / WORLD_SIZE / LOCAL_RANK from
    SLURM's task ids. MASTER_ADDR / MASTER_PORT must be exported by the batch script
    (``scripts/slurm_distributed.sh``)."""
    if "RANK" in env or "SLURM_PROCID" not in env or int(env.get("SLURM_NTASKS", "1")) < 2:
        return
    env["RANK"], env["WORLD_SIZE"] = env["SLURM_PROCID"], env["SLURM_NTASKS"]
    env.setdefault("LOCAL_RANK", env.get("SLURM_LOCALID", "0"))
    if "MASTER_ADDR" not in env or "MASTER_PORT" not in env:
        raise ValueError("under srun, export MASTER_ADDR (the first node) and MASTER_PORT in the batch script "
                         "(scripts/slurm_distributed.sh)")


def _run(cfg, cfg_dict, dist) -> int:
    from hydra.utils import to_absolute_path

    from .run import execute, load_input
    from somtorch.locks import exclusive_folder
    from somtorch.pipeline import run_pipeline

    rank, world = dist.get_rank(), dist.get_world_size()
    t0 = time.perf_counter()
    if rank != 0:  # same collectives as rank 0's execute(), no outputs
        run_pipeline(load_input(cfg), cfg, metrics=False)
        log.info("rank %d of %d done in %.1f s", rank, world, time.perf_counter() - t0)
        return 0
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
    out_dir = Path(to_absolute_path(cfg.paths.output_dir)) / "distributed" / f"{stamp}_{cfg.train.parallel}_w{world}"
    out_dir.mkdir(parents=True, exist_ok=True)
    with exclusive_folder(out_dir):
        metrics = execute(cfg, out_dir, {**cfg_dict, "world_size": world})
    log.info("rank 0 of %d: %s in %.1f s; outputs in %s", world, cfg.train.parallel, time.perf_counter() - t0,
             out_dir)
    return 0 if metrics else 1


if __name__ == "__main__":
    sys.exit(main())
