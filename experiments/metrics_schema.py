"""The ``metrics.json`` schema of a study job: its name and the hash of the config that made it.

Hydra-free, so ``experiments.aggregate`` reads study results without importing the study runner.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

SCHEMA = "somtorch.study/1"
_UNHASHED = ("paths", "output", "skip_complete", "study", "repeats", "resources")


def config_hash(config: dict[str, Any]) -> str:
    """SHA-256 of the result-relevant part of a resolved config (stable key order)."""
    relevant = {k: v for k, v in config.items() if k not in _UNHASHED}
    return hashlib.sha256(json.dumps(relevant, sort_keys=True, default=str).encode()).hexdigest()[:16]
