"""The public API of ``somtorch`` as the site's reference shows it (griffe: static analysis).

What "public" means for the docstring test (``tests/test_docs.py``) and the pages it generates
(``reference/<module>.md`` and ``reference/SUMMARY.md``, the section's navigation).
"""

from __future__ import annotations

import dataclasses
import importlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "somtorch"


@dataclasses.dataclass
class Name:
    """One public name: where it is exported (``path``), the object it is (``target``, griffe)."""

    path: str
    target: Any

    @property
    def where(self) -> str:
        """``file:line`` of the object's definition, relative to the repository."""
        file = Path(str(self.target.filepath)).resolve()
        return f"{file.relative_to(ROOT) if file.is_relative_to(ROOT) else file}:{self.target.lineno or 1}"


def load() -> Any:
    """The ``somtorch`` package as griffe reads it (static analysis, nothing imported)."""
    import griffe

    return griffe.load(PACKAGE, search_paths=[str(ROOT)], docstring_parser="google")


def public_modules(pkg: Any) -> list[Any]:
    """Every module of the package whose dotted path has no ``_``-prefixed part, package first."""

    def walk(module: Any) -> Iterator[Any]:
        yield module
        for name, sub in sorted(module.members.items()):
            if not sub.is_alias and sub.is_module and not name.startswith("_"):
                yield from walk(sub)

    return list(walk(pkg))


def _resolve(pkg: Any, module: Any, name: str) -> Any:
    member = module.members.get(name)
    if member is not None:
        return member.final_target if member.is_alias else member
    # a name served lazily by the module's __getattr__ (somtorch.SOM): ask the imported module
    value = getattr(importlib.import_module(module.path), name)
    origin = getattr(value, "__module__", module.path)
    return pkg.modules_collection.get_member(f"{origin}.{name}")


def _is_logger(obj: Any) -> bool:
    return obj.is_attribute and str(obj.value or "").startswith(("logging.getLogger", "getLogger"))


def public_names(pkg: Any, module: Any) -> list[Name]:
    """The module's public names: its ``__all__``, else what it defines without a leading ``_``
    (imports, submodules and loggers left out)."""
    if module.exports is not None:
        names = [str(n) for n in module.exports if str(n) != "__version__"]
    else:
        names = [n for n, o in module.members.items()
                 if not n.startswith("_") and not o.is_alias and not o.is_module and not _is_logger(o)]
    return [Name(f"{module.path}.{n}", _resolve(pkg, module, n)) for n in names]


def rendered_names(module: Any) -> list[str]:
    """What a module's reference page renders: every name it defines without a leading ``_``
    (loggers left out; in source order), whether or not its ``__all__`` lists it, so that the
    docstrings may refer to a module's constants."""
    return [n for n, o in module.members.items()
            if not n.startswith("_") and not o.is_alias and not o.is_module and not _is_logger(o)]


def public_api(pkg: Any | None = None) -> dict[str, list[Name]]:
    """``{module path: its public names}`` for every public module."""
    pkg = pkg or load()
    return {m.path: public_names(pkg, m) for m in public_modules(pkg)}


def _methods(cls: Any) -> Iterator[Any]:
    for name, member in cls.members.items():
        if not member.is_alias and member.is_function and not name.startswith("_"):
            yield member
        elif (not member.is_alias and member.is_attribute and "property" in member.labels
              and not name.startswith("_")):
            yield member


def _has_doc(obj: Any) -> bool:
    return obj.docstring is not None and obj.docstring.value.strip() != ""


def undocumented(pkg: Any | None = None) -> list[str]:
    """``"name (file:line)"`` for every public module, class, function, method or property
    without a docstring. Data (tables, constants) is listed in the reference with its value."""
    pkg = pkg or load()
    missing: dict[str, str] = {}  # canonical path -> message (a re-exported name counts once)
    for module in public_modules(pkg):
        if not _has_doc(module):
            missing[module.path] = f"{module.path} ({Path(str(module.filepath)).relative_to(ROOT)}:1)"
        for name in public_names(pkg, module):
            obj = name.target
            if (obj.is_class or obj.is_function) and not _has_doc(obj):
                missing[obj.path] = f"{obj.path} ({name.where})"
            if obj.is_class and obj.path.startswith(PACKAGE + "."):
                for meth in _methods(obj):
                    if not _has_doc(meth):
                        missing[meth.path] = f"{meth.path} ({Name(meth.path, meth).where})"
    return sorted(missing.values())


def _page(path: str) -> str:
    return f"{path}.md"


def _summary(obj: Any) -> str:
    if obj.is_attribute and not _has_doc(obj):  # a table or constant: its value
        value = str(obj.value or "")
        return f"`{value if len(value) <= 60 else value[:57] + '...'}`".replace("|", "\\|")
    doc = obj.docstring.value.strip() if _has_doc(obj) else ""
    first = doc.split("\n\n", 1)[0].replace("\n", " ")
    first = re.sub(r":\w+:`~?(?:[\w]+\.)*([^`]+)`", r"`\1`", first)  # a Sphinx role: its name as code
    return re.split(r"(?<=\.)\s", first, maxsplit=1)[0].replace("|", "\\|")


def _row(name: Name) -> str:
    return f"| [`{name.path.rsplit('.', 1)[1]}`][{name.target.path}] | {_summary(name.target)} |"


def api_pages(pkg: Any | None = None) -> dict[str, str]:
    """``{page: markdown}`` of the API reference under ``reference/``, SUMMARY.md included.

    A package's page shows its docstring and a table of its public names, each linked to the page of
    the module that defines it; a module's page renders the module (mkdocstrings). A name defined in a
    private module is rendered on the page of the package that exports it."""
    pkg = pkg or load()
    api = public_api(pkg)
    pages: dict[str, str] = {}
    nav = ["* [Configuration (Hydra)](config.md)"]
    for module in public_modules(pkg):
        depth = module.path.count(".")
        label = module.path if depth == 0 else module.name
        if module.is_init_module:
            rows, rendered = [], []
            for name in api[module.path]:
                target = name.target
                home = target.path.rsplit(".", 1)[0]
                if not target.is_module and any(part.startswith("_") for part in home.split(".")):
                    rendered.append(f"::: {target.path}\n    options:\n      heading_level: 3\n")
                    continue
                if target.path != name.path:  # defined in a submodule (the package's own: rendered above)
                    rows.append(_row(name))
            own = rendered_names(module)  # what the package's __init__ itself defines
            text = [f"# `{module.path}`\n", f"::: {module.path}\n    options:\n      members: "
                    f"{'[' + ', '.join(own) + ']' if own else 'false'}\n      show_root_heading: false\n"]
            if rows:
                text += ["## Public names\n", "| name | what it is |", "|---|---|", *rows, ""]
            text += rendered
            pages[_page(module.path)] = "\n".join(text)
            nav.append("    " * depth + f"* {label}")
            nav.append("    " * (depth + 1) + f"* [{module.path}]({_page(module.path)})")
        else:
            others = [n for n in api[module.path] if n.target.path != n.path]
            members = "[" + ", ".join(rendered_names(module)) + "]"
            text = [f"# `{module.path}`\n", f"::: {module.path}\n    options:\n"
                    f"      show_root_heading: false\n      members: {members}\n"]
            if others:  # an __all__ that re-exports names documented on their own module's page
                text += ["## Also exported here\n", "| name | what it is |", "|---|---|",
                         *(_row(n) for n in others), ""]
            pages[_page(module.path)] = "\n".join(text)
            nav.append("    " * depth + f"* [{label}]({_page(module.path)})")
    pages["SUMMARY.md"] = "\n".join(nav) + "\n"
    return pages


