"""Save and load a trained learned baseline: safetensors weights plus a JSON sidecar (no pickle).

``save(model, "model.safetensors", data_hash=..., meta=...)`` writes the weights with the model's
config, the data hash and ``meta`` (the training config, held-out metrics, timings) as JSON in the
safetensors metadata, and the same JSON beside it as ``model.json``. Both are written atomically;
the same weights and meta give the same bytes.

:func:`load` rebuilds the network and refuses, with a :class:`CheckpointMismatchError` that names
both values, a checkpoint whose model config or data hash differ from the ones the caller expects.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from somtorch.atomic import atomic_path, write_json
from somtorch.baselines.learned.model import UNet
from somtorch.config.learned import LearnedModelConfig
from somtorch.validation import DataFileError, SomtorchError, require_file

__all__ = ["CheckpointMismatchError", "FORMAT", "load", "read_meta", "save"]

FORMAT = "somtorch.learned/1"


class CheckpointMismatchError(SomtorchError, ValueError):
    """A checkpoint's model config or data hash is not the one the caller expects."""


def _paths(path: str | os.PathLike) -> tuple[Path, Path]:
    p = Path(path)
    if p.suffix != ".safetensors":
        p = p.with_name(p.name + ".safetensors")
    return p, p.with_suffix(".json")


def save(model: UNet, path: str | os.PathLike, *, data_hash: str, meta: dict[str, Any] | None = None) -> Path:
    """Write ``model`` to ``path`` (``.safetensors`` appended if missing); returns the weights file."""
    from safetensors.torch import save_file

    wpath, jpath = _paths(path)
    doc = {"format": FORMAT, "model": model.cfg.as_dict(), "data_hash": data_hash, **(meta or {})}
    state = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    with atomic_path(wpath) as tmp:
        save_file(state, str(tmp), metadata={"config": json.dumps(doc, sort_keys=True)})
    write_json(jpath, doc)
    return wpath


def read_meta(path: str | os.PathLike) -> dict[str, Any]:
    """The JSON document stored in the checkpoint's metadata."""
    from safetensors import SafetensorError, safe_open

    wpath, _ = _paths(path)
    require_file(wpath, "learned-baseline checkpoint")
    try:
        with safe_open(str(wpath), framework="pt") as f:
            doc = json.loads((f.metadata() or {}).get("config", "{}"))
    except (SafetensorError, OSError, ValueError) as err:
        raise DataFileError(wpath, f"is not a readable safetensors checkpoint ({err})") from None
    if doc.get("format") != FORMAT:
        raise DataFileError(wpath, f"is not a learned-baseline checkpoint (format {doc.get('format')!r}, "
                                   f"expected {FORMAT!r})")
    return doc


def load(path: str | os.PathLike, *, model_cfg: LearnedModelConfig | None = None,
         data_hash: str | None = None) -> UNet:
    """Rebuild the network of ``path`` (in eval mode).

    Args:
        model_cfg: if given, the checkpoint's model config must equal it.
        data_hash: if given, the checkpoint's data hash must equal it.

    Raises:
        CheckpointMismatchError: the config or the data hash differ (the message names both).
        DataFileError: not a checkpoint of this format.
    """
    from safetensors.torch import load_file

    wpath, _ = _paths(path)
    doc = read_meta(wpath)
    saved = LearnedModelConfig(**doc["model"])
    if model_cfg is not None and saved.as_dict() != model_cfg.as_dict():
        diff = {k: (v, model_cfg.as_dict()[k]) for k, v in saved.as_dict().items() if model_cfg.as_dict()[k] != v}
        raise CheckpointMismatchError(f"{wpath}: its model config differs from the expected one "
                                      f"(field: (saved, expected) {diff}); retrain with somtorch-train-baseline")
    if data_hash is not None and doc.get("data_hash") != data_hash:
        raise CheckpointMismatchError(f"{wpath}: trained on data {doc.get('data_hash')!r}, expected {data_hash!r}; "
                                      f"retrain with somtorch-train-baseline")
    model = UNet(saved)
    try:
        model.load_state_dict(load_file(str(wpath)))
    except RuntimeError as err:
        raise DataFileError(wpath, f"its tensors do not fit its model config ({str(err).splitlines()[0]})") from None
    return model.eval()
