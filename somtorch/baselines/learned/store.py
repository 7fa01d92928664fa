"""Trained learned baselines in a cache, keyed by what made them.

Layout (root: ``$SOMTORCH_CACHE/learned``, else ``~/.cache/somtorch/learned``)::

    <root>/<key>/model.safetensors   weights + config JSON (somtorch.baselines.learned.checkpoint)
    <root>/<key>/model.json          the same JSON: model, data and fit configs, data hash,
                                     held-out metrics, training seconds, thread count
    <root>/<key>/tb/                 TensorBoard events of the training

``key`` = 16 hex digits of SHA-256 over the three configs, the generator's version (its source
hash) and the preparation's version: a change to any of them is another model, trained afresh. The
cache is never committed; ``somtorch-train-baseline`` rebuilds it.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from somtorch.baselines.learned import checkpoint
from somtorch.baselines.learned.data import PREP_VERSION, build_tensors
from somtorch.baselines.learned.model import UNet, parameter_count
from somtorch.baselines.learned.train import check_alive, evaluate, fit
from somtorch.config.learned import LearnedDataConfig, LearnedFitConfig, LearnedModelConfig

__all__ = ["cache_root", "model_key", "model_path", "train_or_load", "trained_model"]


def cache_root() -> Path:
    """``$SOMTORCH_CACHE/learned``, else ``~/.cache/somtorch/learned``."""
    base = os.environ.get("SOMTORCH_CACHE")
    return (Path(base).expanduser() if base else Path.home() / ".cache" / "somtorch") / "learned"


def model_key(model_cfg: LearnedModelConfig, data_cfg: LearnedDataConfig, fit_cfg: LearnedFitConfig) -> str:
    """16 hex digits naming the model these configs train (see the module docstring)."""
    from somtorch.synth.store import generator_version

    doc = {"model": model_cfg.as_dict(), "data": data_cfg.as_dict(), "fit": fit_cfg.as_dict(),
           "generator": generator_version(), "prep": PREP_VERSION}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def model_path(model_cfg: LearnedModelConfig, data_cfg: LearnedDataConfig, fit_cfg: LearnedFitConfig,
               root: str | Path | None = None) -> Path:
    """Where the model of these configs is (or will be) stored."""
    base = cache_root() if root is None else Path(root)
    return base / model_key(model_cfg, data_cfg, fit_cfg) / "model.safetensors"


def trained_model(model_cfg: LearnedModelConfig, data_cfg: LearnedDataConfig, fit_cfg: LearnedFitConfig,
                  root: str | Path | None = None) -> UNet:
    """The cached model of these configs.

    Raises:
        FileNotFoundError: it was never trained; the message gives the command that trains it.
    """
    path = model_path(model_cfg, data_cfg, fit_cfg, root)
    if not path.is_file():
        raise FileNotFoundError(f"no trained learned baseline for data.cameras={list(data_cfg.cameras)} in {path.parent}; "
                                f"train it first: somtorch-train-baseline 'data.cameras=[{','.join(data_cfg.cameras)}]'")
    return checkpoint.load(path, model_cfg=model_cfg)


def train_or_load(model_cfg: LearnedModelConfig, data_cfg: LearnedDataConfig, fit_cfg: LearnedFitConfig, *,
                  root: str | Path | None = None, corpus: str | Path | None = None,
                  forbidden: tuple[str | Path, ...] = (), progress: bool = False,
                  log: Callable[[str, float, int], None] | None = None,
                  retrain: bool = False) -> tuple[UNet, dict[str, Any], Path]:
    """The model of these configs: from the cache, else trained on generated frames and saved.

    Args:
        root: the model cache (None: :func:`cache_root`).
        corpus: the generator's frame cache (None: :func:`somtorch.synth.cache_root`).
        forbidden: roots no training frame may lie under (the real data).
        progress: tqdm bars; log: ``log(tag, value, step)`` per training step (TensorBoard).
        retrain: train again even if the cache holds the model.

    Returns:
        ``(model, sidecar document, checkpoint path)``.
    """
    path = model_path(model_cfg, data_cfg, fit_cfg, root)
    if path.is_file() and not retrain:
        return checkpoint.load(path, model_cfg=model_cfg), checkpoint.read_meta(path), path
    t0 = time.perf_counter()
    data = build_tensors(data_cfg, model_cfg, root=corpus, forbidden=forbidden, progress=progress)
    t_data = time.perf_counter() - t0
    train = ~data.held_out
    t1 = time.perf_counter()
    model = fit(data.inputs[train], data.targets[train], model_cfg, fit_cfg, progress=progress, log=log)
    t_fit = time.perf_counter() - t1
    check_alive(model, data.inputs[data.held_out])  # a collapsed network is never cached
    held = evaluate(model, data.inputs[data.held_out], data.targets[data.held_out])
    meta = {"data": data_cfg.as_dict(), "fit": fit_cfg.as_dict(), "parameters": parameter_count(model),
            "train_frames": int(train.sum()), "held_out_metrics": held, "prepare_s": round(t_data, 1),
            "train_s": round(t_fit, 1), "threads": torch.get_num_threads(), "torch": torch.__version__,
            "key": path.parent.name}
    checkpoint.save(model, path, data_hash=data.data_hash, meta=meta)
    return model, checkpoint.read_meta(path), path
