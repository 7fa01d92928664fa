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
    with atomic_path(wpath) as tmp:  # one metadata key, sorted JSON: identical maps give identical bytes
        save_file({"weight": som.weight.detach().contiguous().cpu()}, str(tmp),
                  metadata={"config": json.dumps(meta, sort_keys=True)})
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
    try:
        cfg = json.loads(meta["config"]) if "config" in meta else {}
    except (ValueError, RecursionError) as err:
        raise DataFileError(wpath, f"broken hyper-parameters in the metadata ({type(err).__name__})") from None
    fmt = meta.get("format", cfg.get("format") if isinstance(cfg, dict) else None)
    if fmt != FORMAT or not isinstance(cfg, dict):
        raise DataFileError(wpath, f"not a somtorch SOM checkpoint (metadata format={fmt!r}, expected {FORMAT!r})")
    if weight is None:
        raise DataFileError(wpath, "has no tensor named 'weight'")
    _check_against_weight(wpath, cfg, weight)
    try:
        som = cls(cfg["rows"], cfg["cols"], cfg["dim"], ensemble=cfg["ensemble"], topology=cfg["topology"],
                  toroidal=cfg["toroidal"], seeds=cfg["seeds"], dtype=getattr(torch, cfg["dtype"]),
                  device=device)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise DataFileError(wpath, f"broken hyper-parameters in the metadata ({err!r})") from err
    try:
        som.set_weight(weight)
    except (TypeError, ValueError) as err:  # NaN / inf weights, a non-float tensor
        raise DataFileError(wpath, f"unusable weights: {err}") from None
    som.initialized = bool(cfg.get("initialized", True))
    return som


def _check_against_weight(path: Path, cfg: dict, weight: torch.Tensor) -> None:
    """The metadata must describe the stored tensor before anything is built from it (a 1 kB file
    claiming ``rows=2000`` would otherwise allocate gigabytes of grid distances)."""
    for key in ("rows", "cols", "dim", "ensemble"):
        v = cfg.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise DataFileError(path, f"metadata field {key!r} must be a positive integer; got {v!r}")
    expected = (cfg["ensemble"], cfg["rows"] * cfg["cols"], cfg["dim"])
    if tuple(weight.shape) != expected:
        raise DataFileError(path, f"metadata (ensemble={cfg['ensemble']}, rows={cfg['rows']}, cols={cfg['cols']}, "
                                  f"dim={cfg['dim']}) describes weights {expected} but the file stores "
                                  f"{tuple(weight.shape)}")
    seeds = cfg.get("seeds")
    if not isinstance(seeds, list) or len(seeds) != cfg["ensemble"] or \
            not all(isinstance(x, int) and not isinstance(x, bool) for x in seeds):
        raise DataFileError(path, f"metadata field 'seeds' must list {cfg['ensemble']} integers")
    if cfg.get("dtype") not in ("float32", "float64", "float16", "bfloat16"):
        raise DataFileError(path, f"metadata field 'dtype' must be a floating dtype name; got {cfg.get('dtype')!r}")