"""The ``metrics.json`` schema of a study job: its name and the hash of the config that made it.

Hydra-free, so ``experiments.aggregate`` reads study results without importing the study runner.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

SCHEMA = "somtorch.study/1"
_UNHASHED = ("paths", "output", "skip_complete", "study", "repeats", "resources")


def config_hash(config: dict[str, Any]) -> str:
    """SHA-256 of the result-relevant part of a resolved config (stable key order)."""
    relevant = {k: v for k, v in config.items() if k not in _UNHASHED}
    return hashlib.sha256(json.dumps(relevant, sort_keys=True, default=str).encode()).hexdigest()[:16]


def files_digest(root: Path, files: Iterable[Path], read: Callable[[Path], bytes] = Path.read_bytes) -> str:
    """16 hex digits of SHA-256 over ``files`` (each ``relative path\\0bytes\\0``, in path order; ``read``
    gives a file's bytes): the identity of a frame's files (``experiments.synth.frame_digest``) or of a
    package's sources (``experiments.study.source_digest``)."""
    h = hashlib.sha256()
    for f in sorted(files):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + read(f) + b"\0")
    return h.hexdigest()[:16]
