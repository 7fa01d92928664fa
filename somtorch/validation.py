"""Error classes and input checks shared by every layer of somtorch.

Public functions validate their inputs once, at the boundary, with these helpers; private helpers
trust their callers. Every message names the argument, what was expected, what arrived and, where
there is one, the fix.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import torch

T = TypeVar("T")

__all__ = [
    "DataFileError",
    "SomtorchError",
    "check_choice",
    "check_finite",
    "check_positive",
    "check_positive_int",
    "check_tensor",
    "require_file",
    "resolve",
]


class SomtorchError(Exception):
    """Base class of the errors somtorch raises on its own (besides plain ValueError/TypeError)."""


class DataFileError(SomtorchError, ValueError):
    """A data file exists but cannot be used: unreadable, truncated, wrong header, wrong size.

    The message always starts with the file's path.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def require_file(path: str | Path, what: str = "file") -> Path:
    """Return ``path`` as a :class:`Path`, raising ``FileNotFoundError`` that names it if absent."""
    p = Path(path).expanduser()
    if not p.exists():
        raise FileNotFoundError(f"{what} not found: {p} (check the path; relative paths resolve "
                                f"against {Path.cwd()})")
    if not p.is_file():
        raise DataFileError(p, f"{what} is not a regular file")
    return p


def check_choice(name: str, value: str, choices: Sequence[str] | Mapping[str, Any]) -> str:
    """Check that option string ``value`` is one of ``choices`` and return it."""
    if not isinstance(value, str):
        raise TypeError(f"{name} must be a string, one of {sorted(choices)}; got {type(value).__name__}")
    if value not in choices:
        raise ValueError(f"{name}={value!r} is not known; valid names: {', '.join(sorted(choices))}")
    return value


def resolve(name: str, value: str | Callable[..., T], registry: Mapping[str, Callable[..., T]]) -> Callable[..., T]:
    """Resolve an option that is either a registry name or a callable."""
    if callable(value):
        return value
    return registry[check_choice(name, value, registry)]


def check_positive_int(name: str, value: Any) -> int:
    """Check that ``value`` is an int ≥ 1 (bools rejected) and return it."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be a positive integer; got {type(value).__name__} {value!r}")
    value = int(value)
    if value < 1:
        raise ValueError(f"{name} must be a positive integer (>= 1); got {value}")
    return value


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> None:
    """Check that a scalar or tensor hyper-parameter is finite and > 0 (or ≥ 0)."""
    if isinstance(value, torch.Tensor):
        if value.numel() == 0:
            raise ValueError(f"{name} is an empty tensor")
        bad = ~torch.isfinite(value) | ((value < 0) if allow_zero else (value <= 0))
        if bool(bad.any()):
            raise ValueError(f"{name} must be finite and {'>= 0' if allow_zero else '> 0'}; "
                             f"got {value.flatten()[bad.flatten()][:5].tolist()}")
        return
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{name} must be a number or a tensor; got {type(value).__name__}")
    if not math.isfinite(value) or (value < 0 if allow_zero else value <= 0):
        raise ValueError(f"{name} must be finite and {'>= 0' if allow_zero else '> 0'}; got {value}")


def check_finite(name: str, x: torch.Tensor) -> None:
    """Raise ``ValueError`` if ``x`` holds NaN or ±inf, saying how many and where the first is."""
    if x.is_floating_point() or x.is_complex():
        bad = ~torch.isfinite(x)
        if bool(bad.any()):
            n = int(bad.sum())
            first = tuple(int(i) for i in bad.nonzero()[0])
            raise ValueError(f"{name} contains {n} non-finite value(s) (NaN or inf), first at index {first}; "
                             "remove or mask them first")


def check_tensor(
    name: str,
    x: Any,
    *,
    ndim: int | Sequence[int] | None = None,
    last_dim: int | None = None,
    floating: bool = False,
    finite: bool = False,
    nonempty: bool = True,
    device: torch.device | None = None,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """Validate a tensor argument and return it.

    Args:
        name: argument name used in messages.
        x: the value to check; must already be a ``torch.Tensor``.
        ndim: allowed number(s) of dimensions.
        last_dim: required size of the last dimension.
        floating: require a floating-point dtype.
        finite: reject NaN / inf.
        nonempty: reject tensors whose first dimension (or any dimension) is 0.
        device: required device.
        dtype: required dtype.
    """
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor; got {type(x).__name__} "
                        "(convert with torch.as_tensor(...))")
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if x.ndim not in allowed:
            raise ValueError(f"{name} must have {' or '.join(map(str, allowed))} dimensions; "
                             f"got shape {tuple(x.shape)}")
    if last_dim is not None and (x.ndim == 0 or x.shape[-1] != last_dim):
        raise ValueError(f"{name} must have last dimension {last_dim} (features); got shape {tuple(x.shape)}")
    if nonempty and x.numel() == 0:
        raise ValueError(f"{name} is empty (shape {tuple(x.shape)}); at least one row is needed")
    if floating and not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor; got dtype {x.dtype}")
    if dtype is not None and x.dtype != dtype:
        raise TypeError(f"{name} has dtype {x.dtype} but {dtype} is expected (convert with .to({dtype}))")
    if device is not None and x.device != torch.device(device):
        raise ValueError(f"{name} is on device {x.device} but {device} is expected (move it with .to(...))")
    if finite:
        check_finite(name, x)
    return x
