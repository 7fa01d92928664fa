"""The option names the configs accept, declared at the bottom layer.

Each table lists the names that the module implementing them serves (that module reads its names
from here, or a test checks that its registry matches), so validating a config imports nothing above
:mod:`somtorch.config`. Segmenters are the one open registry: :func:`register_method` is called by
:func:`somtorch.segmenters.register`, so a segmenter registered by user code is a valid ``method``.
"""

from __future__ import annotations

__all__ = ["D_MODES", "DECAYS", "GROUND_RULES", "INITS", "METHODS", "MODES", "NEIGHBORHOODS", "NORMALIZATIONS",
           "OBJECT_RULES", "ORDERS", "SYNTH_FAMILIES", "TOPOLOGIES", "register_method"]

# somtorch.core
MODES = ("online", "batch", "minibatch")  # SOM.fit's update rules
ORDERS = ("sequential", "random")  # sample orders of SOM.fit
INITS = ("random", "sample", "pca")  # somtorch.core.init
TOPOLOGIES = ("rectangular", "hexagonal")  # somtorch.core.grid
DECAYS = ("asymptotic", "linear", "exponential", "inverse_time", "constant")  # keys of core.decay.DECAYS
NEIGHBORHOODS = ("gaussian", "bubble", "mexican_hat", "triangle")  # keys of core.neighborhood.NEIGHBORHOODS
# somtorch.disparity.features
NORMALIZATIONS = ("image", "minmax", "none")
D_MODES = ("raw", "plane_residual")  # FeatureConfig.d_mode (applied by somtorch.pipeline)
# somtorch.tasks.ground
GROUND_RULES = ("none", "position", "support", "either")
# somtorch.tasks.objects
OBJECT_RULES = ("salient", "paper")
# somtorch.synth: the generator's scene families (keys of somtorch.synth.FAMILIES, in that order)
SYNTH_FAMILIES = ("stairs", "garden", "road", "room", "tabletop", "hands", "fence", "clutter", "floor",
                  "floor_near")
# somtorch.segmenters: name -> deterministic (one run whatever ``ensemble`` says)
METHODS: dict[str, bool] = {"som": False, "minisom": False, "kmeans": False, "slic": True, "felzenszwalb": True}


def register_method(name: str, deterministic: bool) -> None:
    """Declare the segmenter ``name``; a built-in name must keep its declared determinism."""
    if METHODS.get(name, deterministic) != deterministic:
        raise ValueError(f"segmenter {name!r} is declared deterministic={METHODS[name]} in "
                         f"somtorch.config.options; got deterministic={deterministic}")
    METHODS[name] = deterministic
