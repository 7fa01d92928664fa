"""Declarative validation of the config dataclasses (in the spirit of scikit-learn's
``_parameter_constraints``): rules per field, checked by :class:`Validated` after ``__init__``.

Option names are checked against the name tables of :mod:`somtorch.config.options`, so this
module imports nothing of somtorch and every layer may use it.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Collection
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

__all__ = ["BOOL", "FRACTION", "NON_NEGATIVE", "POSITIVE", "POSITIVE_INT", "Choice", "Flag", "Interval", "OneOf",
           "Validated", "nonfinite"]


@dataclass(frozen=True)
class Interval:
    """A number in ``[lo, hi]`` (``open_lo`` / ``open_hi`` exclude an end; None = unbounded).

    ``integer``: an int (bools rejected); ``optional``: None allowed.
    """

    lo: float | None = None
    hi: float | None = None
    open_lo: bool = False
    open_hi: bool = False
    integer: bool = False
    optional: bool = False

    def describe(self) -> str:
        """The interval in words, e.g. ``a number in (0, inf)``."""
        lo = "-inf" if self.lo is None else f"{self.lo:g}"
        hi = "inf" if self.hi is None else f"{self.hi:g}"
        left = "(" if self.open_lo or self.lo is None else "["
        right = ")" if self.open_hi or self.hi is None else "]"
        kind = "an integer" if self.integer else "a number"
        return f"{kind} in {left}{lo}, {hi}{right}"

    def check(self, name: str, value: Any) -> None:
        """Raise ``TypeError`` / ``ValueError`` naming ``name`` unless ``value`` lies in the interval."""
        if value is None and self.optional:
            return
        if isinstance(value, bool) or not isinstance(value, numbers.Integral if self.integer else numbers.Real):
            raise TypeError(f"{name} must be {self.describe()}; got {type(value).__name__} {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{name} must be finite, {self.describe()}; got {value}")
        if self.lo is not None and (v <= self.lo if self.open_lo else v < self.lo):
            raise ValueError(f"{name} must be {self.describe()}; got {value}")
        if self.hi is not None and (v >= self.hi if self.open_hi else v > self.hi):
            raise ValueError(f"{name} must be {self.describe()}; got {value}")


@dataclass(frozen=True)
class Choice:
    """An option name from ``names`` (a table of :mod:`somtorch.config.options`; read when checked,
    so names registered later by the module that implements them count)."""

    registry: Collection[str]

    def names(self) -> Collection[str]:
        """The valid names, read when asked (a registry may grow after import)."""
        return self.registry

    def check(self, name: str, value: Any) -> None:
        """Raise ``TypeError`` / ``ValueError`` naming ``name`` unless ``value`` is one of :meth:`names`."""
        choices = self.names()
        if not isinstance(value, str):
            raise TypeError(f"{name} must be a string, one of {sorted(choices)}; got {type(value).__name__}")
        if value not in choices:
            raise ValueError(f"{name}={value!r} is not known; valid names: {', '.join(sorted(choices))}")


@dataclass(frozen=True)
class OneOf:
    """One of a few literal values (e.g. a kind of parallelism)."""

    values: tuple

    def check(self, name: str, value: Any) -> None:
        """Raise ``ValueError`` naming ``name`` unless ``value`` is one of ``values``."""
        if isinstance(value, bool) or value not in self.values:
            raise ValueError(f"{name} must be one of {list(self.values)}; got {value!r}")


@dataclass(frozen=True)
class Flag:
    """A bool (``1`` / ``"yes"`` are not)."""

    def check(self, name: str, value: Any) -> None:
        """Raise ``TypeError`` naming ``name`` unless ``value`` is a bool."""
        if not isinstance(value, bool):
            raise TypeError(f"{name} must be true or false; got {type(value).__name__} {value!r}")


POSITIVE = Interval(0, None, open_lo=True)
NON_NEGATIVE = Interval(0, None)
POSITIVE_INT = Interval(1, None, integer=True)
FRACTION = Interval(0, 1)
BOOL = Flag()


class Validated:
    """Base of the config dataclasses: checks ``_constraints`` and ``_relations`` after ``__init__``.

    ``_group`` prefixes the field names in messages (``objects.merge``); ``_relations`` is a list of
    ``(predicate(cfg) -> bool, message)`` for rules that tie fields together.
    """

    _group: ClassVar[str] = ""
    _constraints: ClassVar[dict[str, Any]] = {}
    _relations: ClassVar[list[tuple[Any, str]]] = []

    def __post_init__(self) -> None:
        prefix = f"{self._group}." if self._group else ""
        for name, rule in self._constraints.items():
            rule.check(prefix + name, getattr(self, name))
        for ok, message in self._relations:
            if not ok(self):
                raise ValueError(f"{self._group or type(self).__name__}: {message.format(c=self)}")

    def as_dict(self) -> dict[str, Any]:
        """The config as a plain dict (nested configs included)."""
        return asdict(self)  # type: ignore[call-overload]


def nonfinite(tree: Any, prefix: str = "") -> tuple[str, float] | None:
    """``(dotted key, value)`` of the first NaN or infinite number in a tree of dicts and lists (a
    config as plain containers), or None: no config value is meant to be NaN or infinite.

    >>> nonfinite({"train": {"lr": float("nan")}, "grid": [1, 2]})
    ('train.lr', nan)
    """
    if isinstance(tree, dict):
        items: Any = ((f"{prefix}{k}", v) for k, v in tree.items())
    elif isinstance(tree, (list, tuple)):
        items = ((f"{prefix[:-1]}[{i}]", v) for i, v in enumerate(tree))
    else:
        return (prefix[:-1], tree) if isinstance(tree, float) and not math.isfinite(tree) else None
    for key, value in items:
        found = nonfinite(value, f"{key}.")
        if found is not None:
            return found
    return None
