"""Save and load a :class:`~somtorch.SOM` with safetensors (no pickle anywhere).

``save(som, "model.safetensors")`` writes the weights ``(E, K, D)`` with the hyper-parameters as
JSON in the safetensors metadata, and the same JSON beside it as ``model.json`` for people and tools.
Both files are written atomically.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from ..atomic import atomic_path, write_json
from ..validation import DataFileError, require_file

if TYPE_CHECKING:
    from .som import SOM

FORMAT = "somtorch.som/1"


def _paths(path: str | os.PathLike) -> tuple[Path, Path]:
    p = Path(path)
    if p.suffix != ".safetensors":
        p = p.with_name(p.name + ".safetensors")
    return p, p.with_suffix(".json")


def save(som: SOM, path: str | os.PathLike) -> Path:
    """Write ``som`` to ``path`` (``.safetensors`` appended if missing); returns the weights file."""
    from safetensors.torch import save_file

    wpath, jpath = _paths(path)
    meta = {"format": FORMAT, **som.config(), "initialized": som.initialized}
    with atomic_path(wpath) as tmp:
        save_file({"weight": som.weight.detach().contiguous().cpu()}, str(tmp),
                  metadata={"format": FORMAT, "config": json.dumps(meta)})
    write_json(jpath, meta)
    return wpath


def load(cls: type[SOM], path: str | os.PathLike, *, device=None) -> SOM:
    """Rebuild a map from a file written by :func:`save`."""
    from safetensors import SafetensorError
    from safetensors import safe_open

    given = Path(path)
    if given.is_file() and given.suffix != ".safetensors":
        raise DataFileError(given, "is not a SOM checkpoint (expected a .safetensors file written by SOM.save)")
    wpath, _ = _paths(path)
    require_file(wpath, "SOM checkpoint")
    try:
        with safe_open(str(wpath), framework="pt") as f:
            meta = f.metadata() or {}
            weight = f.get_tensor("weight") if "weight" in f.keys() else None
    except (SafetensorError, OSError, ValueError) as err:
        raise DataFileError(wpath, f"not a readable safetensors file ({err})") from err
    if meta.get("format") != FORMAT or "config" not in meta:
        raise DataFileError(wpath, f"not a somtorch SOM checkpoint (metadata format={meta.get('format')!r}, "
                                   f"expected {FORMAT!r})")
    if weight is None:
        raise DataFileError(wpath, "has no tensor named 'weight'")
    try:
        cfg = json.loads(meta["config"])
        som = cls(cfg["rows"], cfg["cols"], cfg["dim"], ensemble=cfg["ensemble"], topology=cfg["topology"],
                  toroidal=cfg["toroidal"], seeds=cfg["seeds"], dtype=getattr(torch, cfg["dtype"]),
                  device=device)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise DataFileError(wpath, f"broken hyper-parameters in the metadata ({err!r})") from err
    som.set_weight(weight)
    som.initialized = bool(cfg.get("initialized", True))
    return som
