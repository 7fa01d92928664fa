"""Lazy imports of optional heavy dependencies, with error messages that say how to fix them.

``import somtorch`` never imports Open3D (a ~1 s import that needs system libraries such as
``libusb-1.0.so.0``); the few functions that need it call :func:`import_open3d` at the edge. When an
import fails, the ``ImportError`` raised here says in one paragraph what is missing and the command
that installs it, and chains the original error (``raise ... from err``) so nothing is hidden.

Example:
    >>> import math
    >>> optional_import("math", pip_name="math") is math
    True
"""

from __future__ import annotations

import importlib
import re
from types import ModuleType

__all__ = ["import_error_message", "import_open3d", "optional_import"]

# System libraries that Python wheels commonly dlopen but do not bundle → the Debian/Ubuntu package
# that provides them. Extend this table when another optional dependency needs one.
_SYSTEM_PACKAGES: dict[str, str] = {
    "libusb-1.0.so.0": "libusb-1.0-0",
    "libGL.so.1": "libgl1",
    "libEGL.so.1": "libegl1",
    "libgomp.so.1": "libgomp1",
    "libX11.so.6": "libx11-6",
}

# The dynamic loader's wording: "<lib>: cannot open shared object file: No such file or directory".
_MISSING_SO = re.compile(r"(?P<lib>[\w.+-]+\.so(?:\.[\w.]+)?): cannot open shared object file")


def import_error_message(module: str, pip_name: str, err: BaseException, hint: str | None = None) -> str:
    """Build the one-paragraph explanation for a failed ``import module``.

    Three cases, told apart from the original error:

    * a system shared library is missing (the loader's ``cannot open shared object file``): name the
      library and, where known, the ``apt-get`` command that installs it;
    * the module itself is not installed (``ModuleNotFoundError`` for ``module``): ``pip install``;
    * anything else (a broken install, a missing Python dependency of the module): name the error
      and suggest reinstalling.

    Args:
        module: the module that was imported, e.g. ``"open3d"``.
        pip_name: the name to ``pip install``, e.g. ``"open3d"``.
        err: the error the import raised.
        hint: an extra sentence appended to the message (what the module is needed for).

    Example:
        >>> msg = import_error_message("open3d", "open3d",
        ...     ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory"))
        >>> "apt-get install -y libusb-1.0-0" in msg
        True
    """
    text = str(err)
    missing = _MISSING_SO.search(text)
    root = module.split(".")[0]
    if missing is not None:
        lib = missing.group("lib")
        apt = _SYSTEM_PACKAGES.get(lib)
        fix = (f"install it with `apt-get update && apt-get install -y {apt}` (Debian/Ubuntu; other systems: "
               f"the package that provides {lib})" if apt is not None
               else f"install the system package that provides {lib} "
                    f"(Debian/Ubuntu: `apt-file search {lib}`)")
        msg = (f"{module} is installed but cannot be loaded because the system library {lib} is missing; "
               f"{fix}, then retry. Original error: {text}")
    elif isinstance(err, ModuleNotFoundError) and err.name is not None and (
            err.name == module or err.name == root or module.startswith(err.name + ".")):
        msg = (f"{module} is not installed; install it with `pip install {pip_name}` "
               f"(in the same environment as somtorch), then retry.")
    elif isinstance(err, ModuleNotFoundError) and err.name is not None:
        msg = (f"{module} is installed but its dependency {err.name!r} is missing; reinstall with "
               f"`pip install --force-reinstall {pip_name}` or `pip install {err.name}`, then retry. "
               f"Original error: {text}")
    else:
        msg = (f"{module} could not be imported ({type(err).__name__}: {text}); the installation may be "
               f"broken or built for another platform — try `pip install --force-reinstall {pip_name}`.")
    if hint:
        msg = f"{msg} {hint}"
    return msg


def optional_import(module: str, pip_name: str | None = None, hint: str | None = None) -> ModuleType:
    """Import and return ``module``, or raise ``ImportError`` explaining how to install it.

    Args:
        module: dotted module name.
        pip_name: the distribution to ``pip install`` (defaults to the top-level module name).
        hint: an extra sentence for the message, e.g. which somtorch feature needs the module.

    Returns:
        The imported module (cached by Python in ``sys.modules`` after the first success).

    Raises:
        ImportError: with the message of :func:`import_error_message`, chained to the original error.
    """
    try:
        return importlib.import_module(module)
    except (ImportError, OSError) as err:  # OSError: some packages dlopen with ctypes at import time
        raise ImportError(import_error_message(module, pip_name or module.split(".")[0], err, hint),
                          name=module) from err


def import_open3d() -> ModuleType:
    """Return the ``open3d`` module, importing it on first use.

    Raises:
        ImportError: open3d is not installed (``pip install open3d``) or a system library it needs is
            missing (``libusb-1.0.so.0`` → ``apt-get update && apt-get install -y libusb-1.0-0``).
    """
    return optional_import("open3d", "open3d",
                           hint="Open3D is needed only for PLY files, Open3D conversion and rendering.")
