"""somtorch: batched, ensemble-capable, differentiable self-organising maps for stereo disparity maps.

Importing ``somtorch`` imports neither hydra nor open3d.
"""

from typing import Any

__version__ = "0.1.0"

__all__ = ["SOM", "DataFileError", "SomtorchError", "StepInfo", "__version__"]

_LAZY = {"SOM": "core", "StepInfo": "core", "DataFileError": "validation", "SomtorchError": "validation"}


def __getattr__(name: str) -> Any:
    """The public names, imported on first use: ``import somtorch.config`` (the CLI's help, the
    config schema) does not pay for torch."""
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'somtorch' has no attribute {name!r}")
