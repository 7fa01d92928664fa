"""somtorch: batched, ensemble-capable, differentiable self-organising maps for stereo disparity maps.

Importing ``somtorch`` imports neither hydra nor open3d.
"""

from .core import SOM, StepInfo
from .validation import DataFileError, SomtorchError

__version__ = "0.1.0"

__all__ = ["SOM", "DataFileError", "SomtorchError", "StepInfo", "__version__"]
