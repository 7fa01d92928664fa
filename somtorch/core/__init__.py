"""Core SOM maths and the ``SOM`` module; knows nothing of disparity maps."""

from .decay import DECAYS
from .neighborhood import NEIGHBORHOODS
from .som import MODES, SOM
from .training import StepInfo

__all__ = ["DECAYS", "MODES", "NEIGHBORHOODS", "SOM", "StepInfo"]
