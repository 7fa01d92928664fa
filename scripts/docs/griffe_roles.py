"""A griffe extension for the site's API reference: the docstrings' Sphinx roles become links.

somtorch's docstrings refer to each other the Sphinx way (``:func:`segment```,
``:class:`~somtorch.config.AreaConfig```, ``:mod:`.segmentation```). This extension rewrites each
role into a mkdocs-autorefs cross-reference (``[`AreaConfig`][somtorch.config.AreaConfig]``) that
mkdocstrings resolves like Python would (``scoped_crossrefs``); a reference to a name that does not
exist stops the strict build with a warning naming the file and the target. References into other
libraries (``torch.Generator``) or to private names (``_verified``) have no page here: they stay
code, unlinked.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj|const):`(~?)([^`]+)`")
PACKAGE = "somtorch"
EXTERNAL = ("torch", "kornia", "numpy", "np", "cv2", "open3d", "ctypes", "experiments", "hydra", "omegaconf",
            "scipy", "skimage", "minisom", "pathlib", "Path", "typing", "safetensors", "logging", "tqdm",
            "matplotlib", "dataclasses")


def _canonical(obj: Any, target: str, base: str) -> str | None:
    """The canonical dotted path of the somtorch object ``target`` names, read the way Python
    would from ``obj``'s scope (``fit`` in ``SOM``, ``segment`` imported in the module, ``.training``
    relative to the package), or None."""
    collection = obj.modules_collection
    if target.startswith("."):
        candidates = [base + target]
    else:
        candidates = [target] if target.split(".")[0] == PACKAGE else []
        try:
            head = obj.resolve(target.split(".")[0])
            candidates.append(head + target[len(target.split(".")[0]):])
        except Exception:  # noqa: BLE001 - griffe's NameResolutionError: not in this scope
            pass
        candidates += [f"{base}.{target}", f"{obj.module.path}.{target}"]
    for path in candidates:
        if path.split(".")[0] != PACKAGE:
            continue
        try:
            found = collection.get_member(path)
            return found.final_target.path if found.is_alias else found.path
        except Exception:  # noqa: BLE001 - KeyError, AliasResolutionError: try the next reading
            continue
    return None


def crossref(obj: Any, tilde: str, target: str, base: str) -> str:
    """The Markdown for one role: a cross-reference to the canonical path, or plain code where there
    is no page to link; a somtorch name that does not exist keeps its written target, so the build
    reports it."""
    shown = target.rsplit(".", 1)[-1] if tilde else target.lstrip(".")
    parts = target.lstrip(".").split(".")
    if (parts[0] in EXTERNAL or any(p.startswith("_") and not p.startswith("__") for p in parts)
            or not re.fullmatch(r"[\w.]+", target)):
        return f"`{shown}`"
    canonical = _canonical(obj, target, base)
    if canonical is None and target.split(".")[0] != PACKAGE and not target.startswith("."):
        return f"`{shown}`"  # not a somtorch name in scope (a parameter, another library's name)
    return f"[`{shown}`][{canonical or (base + target if target.startswith('.') else target)}]"


def fence_doctests(text: str) -> str:
    """Put each run of doctest lines (``>>>`` and the output up to a blank line) into a ``pycon``
    code block: Markdown would read a bare ``>>>`` as nested quotes."""
    lines, out, i, fenced = text.split("\n"), [], 0, False
    while i < len(lines):
        line = lines[i]
        stripped = line.lstrip()
        fenced ^= stripped.startswith("```")
        if stripped.startswith(">>>") and not fenced:
            indent = line[:len(line) - len(stripped)]
            block = []
            while i < len(lines) and lines[i].strip() and lines[i].startswith(indent):
                block.append(lines[i][len(indent):])
                i += 1
            out += [indent + "```pycon", *(indent + b for b in block), indent + "```"]
            continue
        out.append(line)
        i += 1
    return "\n".join(out)


def _objects(obj: Any) -> Any:
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _objects(member)


class SphinxRoles(griffe.Extension):
    """Rewrite the Sphinx roles of every docstring of the package into autorefs links, once the
    whole package is loaded; give its lazily imported public names (``somtorch.SOM``, served by a
    module ``__getattr__`` that static analysis cannot follow) their aliases; leave out the
    undocumented instance attributes a class's ``__init__`` assigns (its docstring's Attributes
    section lists them); fence the doctests."""

    def on_package(self, *, pkg: Any, **kwargs: Any) -> None:  # griffe calls it once the package is loaded
        for name in map(str, pkg.exports or []):
            if name in pkg.members:
                continue
            try:
                origin = getattr(getattr(importlib.import_module(pkg.path), name), "__module__", None)
            except (ImportError, AttributeError):
                continue
            if origin and origin != pkg.path:
                pkg.set_member(name, griffe.Alias(name, f"{origin}.{name}", parent=pkg))
        for obj in list(_objects(pkg)):
            if obj.is_class:  # `self.rows = check(...)` in __init__: the Attributes section documents them
                for name, member in list(obj.members.items()):
                    if (not member.is_alias and member.is_attribute
                            and member.labels == {"instance-attribute"} and member.docstring is None):
                        obj.del_member(name)
            if obj.docstring is None:
                continue
            if ">>>" in obj.docstring.value:
                obj.docstring.value = fence_doctests(obj.docstring.value)
            if ":`" not in obj.docstring.value:
                continue
            mod = obj if obj.is_module else obj.module
            base = mod.path if mod.is_init_module or mod.parent is None else mod.parent.path  # .x: a sibling
            obj.docstring.value = ROLE.sub(lambda m, o=obj, b=base: crossref(o, m.group(1), m.group(2), b),
                                           obj.docstring.value)
