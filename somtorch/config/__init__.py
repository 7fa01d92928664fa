"""Every configuration of somtorch, declared once (one dataclass per group, in three modules:
:mod:`.segmentation` steps 1a–1b, :mod:`.objects` the ground plane and step 1c, :mod:`.pipeline`
step 1d, outputs, sequences and the whole pipeline).

These dataclasses are the single home of every default: the library reads its defaults from them,
the Hydra schemas *are* them (``experiments/schema.py`` registers them), and ``conf/`` states only
what a preset changes. So ``run_pipeline(scene)`` does exactly what ``somtorch-run`` does with no
overrides.

Validation is declarative: each class lists its ``_constraints`` (field → rule) and, where fields
depend on each other, ``_relations``; :class:`Validated` checks both after ``__init__``, with
messages that name the field (``objects.min_purity must be in [0, 1]; got 2``). Option names are
checked against the registry that implements them, looked up lazily so that this package imports
nothing of somtorch but the error helpers (every layer may import it).

The list of tuned constants of the object step, their values and how each was chosen, is in
``docs/tuned_constants.md``.
"""

from __future__ import annotations

from .constraints import Choice, Flag, Interval, OneOf, Validated
from .objects import AreaConfig, GroundConfig
from .pipeline import OutputConfig, PipelineConfig, ReductionConfig, WarmStartConfig, with_overrides
from .segmentation import BaselineConfig, FeatureConfig, SOMConfig, TrainConfig

__all__ = [
    "AreaConfig", "BaselineConfig", "Choice", "FeatureConfig", "Flag", "GroundConfig", "Interval", "OneOf",
    "OutputConfig", "PipelineConfig", "ReductionConfig", "SOMConfig", "TrainConfig", "Validated", "WarmStartConfig",
    "with_overrides",
]
