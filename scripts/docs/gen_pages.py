"""The generated pages of the documentation site, built from the code at every ``mkdocs build``.

Run by mkdocs-gen-files (``mkdocs.yml``); nothing it writes is committed. It writes:

* ``reference/`` — one page per public module of ``somtorch`` (rendered by mkdocstrings from the
  docstrings), a package page listing the package's public names, the configuration reference, and
  ``reference/SUMMARY.md``, the navigation of that section (mkdocs-literate-nav);
* ``reference/config.md`` — every Hydra config group with its options, and every key with its
  default, constraint and description, from the config dataclasses and their ``_constraints``
  tables through ``experiments/help.py`` (the code that renders ``--help``);
* ``notebooks/*.ipynb`` — the stored notebooks (mkdocs-jupyter renders their stored outputs);
* ``pictures.md`` — the summary figure and every image of ``docs/gallery/`` with its caption.

The same functions serve ``tests/test_docs.py``: :func:`public_api` is what "public" means for the
docstring test, :func:`config_keys` what the configuration reference must hold.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # the clone's experiments/ (help, cli, schema)
    sys.path.insert(0, str(ROOT))

PACKAGE = "somtorch"


# ------------------------------------------------------------------------------------- public API
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
        elif not member.is_alias and member.is_attribute and "property" in member.labels and not name.startswith("_"):
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
                    rows.append(f"| [`{name.path.rsplit('.', 1)[1]}`][{target.path}] | {_summary(target)} |")
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
            text = [f"# `{module.path}`\n", f"::: {module.path}\n    options:\n      show_root_heading: false\n"
                    f"      members: {members}\n"]
            if others:  # an __all__ that re-exports names documented on their own module's page
                text += ["## Also exported here\n", "| name | what it is |", "|---|---|",
                         *(f"| [`{n.path.rsplit('.', 1)[1]}`][{n.target.path}] | {_summary(n.target)} |" for n in others), ""]
            pages[_page(module.path)] = "\n".join(text)
            nav.append("    " * depth + f"* [{label}]({_page(module.path)})")
    pages["SUMMARY.md"] = "\n".join(nav) + "\n"
    return pages


# --------------------------------------------------------------------------- configuration reference
COMMANDS = {"run": "somtorch-run", "study": "somtorch-study", "validate": "somtorch-validate",
            "real_scenes": "somtorch-scenes", "video": "somtorch-video", "synth": "somtorch-synth"}


def describe(rule: Any) -> str:
    """A constraint of a ``_constraints`` table in words."""
    from somtorch.config.constraints import Choice, Flag, Interval, OneOf

    if isinstance(rule, Interval):
        return rule.describe() + (" or null" if rule.optional else "")
    if isinstance(rule, Choice):
        return "one of " + ", ".join(f"`{n}`" for n in sorted(rule.names()))
    if isinstance(rule, OneOf):
        return "one of " + ", ".join(f"`{v}`" for v in rule.values)
    if isinstance(rule, Flag):
        return "true or false"
    return type(rule).__name__


def _md(text: object) -> str:
    """Docstring text for a Markdown page: one line; a Sphinx role to a somtorch name becomes a link
    into the reference (checked by the strict build), any other its name as code."""
    def role(m: re.Match) -> str:
        tilde, target = m.group(1), m.group(2)
        shown = target.rsplit(".", 1)[-1] if tilde else target
        return f"[`{shown}`][{target}]" if target.startswith(PACKAGE + ".") else f"`{shown}`"

    return re.sub(r":\w+:`(~?)([^`]+)`", role, re.sub(r"\s+", " ", str(text)).strip())


def _cell(text: object) -> str:
    return _md(text).replace("|", "\\|")


def _key_table(rows: list[tuple[str, object, str]], constraints: dict[str, Any], prefix: str) -> list[str]:
    out = ["| key | default | constraint | description |", "|---|---|---|---|"]
    for key, default, desc in rows:
        rule = constraints.get(key[len(prefix):])
        out.append(f"| `{key}` | `{_cell(repr(default))}` | {_cell(describe(rule)) if rule else ''} | {_cell(desc)} |")
    return out + [""]


def _relations(cls: type) -> list[str]:
    import inspect

    out = []
    for predicate, message in getattr(cls, "_relations", []):
        try:
            src = inspect.getsource(predicate).strip()
            rule = src[src.index("lambda"):].split(",\n")[0].split(":", 1)[1].strip().rstrip(",")
        except (OSError, TypeError, ValueError):
            rule = ""
        msg = re.sub(r"\{c\.(\w+)!r\}|\{c\.(\w+)\}", lambda m: f"<{m.group(1) or m.group(2)}>", message)
        out.append(f"- `{rule}` — otherwise: *{_cell(msg)}*" if rule else f"- *{_cell(msg)}*")
    return out


def config_page() -> str:
    """The configuration reference: groups, options, and every key with default and constraint."""
    from somtorch.config import PipelineConfig

    from experiments import CONF
    from experiments import help as H
    from experiments.cli import config_groups
    from experiments.data_schema import DataSource, PathsConfig
    from experiments.synth_config import SynthConfig

    out = ["# Configuration reference (Hydra)", "",
           "Generated at build time from the config dataclasses of `somtorch.config` (their docstrings and "
           "`_constraints` tables) and the groups of `conf/`, through the code that renders `--help` "
           "(`experiments/help.py`): one source, so this page cannot drift from the CLI. Every key below "
           "is set on the command line as `key=value`; a group as `group=option`.", ""]
    out += ["## Config groups", "",
            "Each option is a file `conf/<group>/<option>.yaml`, shown as it is: it states only what the "
            "option changes; everything else keeps the dataclass defaults below.", ""]
    for group, options in config_groups().items():
        out += [f"### `{group}`", "", "Options: " + ", ".join(f"`{o}`" for o in options), ""]
        for opt in options:
            text = (CONF / group / f"{opt}.yaml").read_text().rstrip()
            out += [f'??? note "`{group}={opt}`"', "", "    ```yaml", *("    " + ln for ln in text.splitlines()),
                    "    ```", ""]
    out += ["## Top-level keys", ""]
    top, desc, _ = H.top_keys("run")
    pipe_constraints = getattr(PipelineConfig, "_constraints", {})
    out += _key_table([(k, v, desc[k]) for k, v in top.items()], pipe_constraints, "")
    out += _relations(PipelineConfig) + [""]
    out += ["## `data.*` (DataSource)", "", _cell(_summary_of(DataSource)), ""]
    out += _key_table(H.field_rows(DataSource, "data."), {}, "data.")
    from somtorch.disparity.stereo import SGBMParams

    sgbm = [(f"data.sgbm.{f.name}", f.default, "StereoSGBM setting under OpenCV's name "
             "(`somtorch.disparity.stereo.SGBMParams`)") for f in dataclasses.fields(SGBMParams)]
    out += ["### `data.sgbm.*` (SGBMParams)", ""] + _key_table(sgbm, {}, "data.sgbm.")
    out += ["## `paths.*` (PathsConfig)", ""] + _key_table(H.field_rows(PathsConfig, "paths."), {}, "paths.")
    for prefix, cls in H.sections("video"):
        out += [f"## `{prefix}.*` ({cls.__name__})", "", _cell(_summary_of(cls)), ""]
        out += _key_table(H.field_rows(cls, prefix + "."), getattr(cls, "_constraints", {}), prefix + ".")
        rel = _relations(cls)
        if rel:
            out += ["Rules that tie these keys together:", "", *rel, ""]
    out += ["## Keys of each command", "",
            "The keys a command adds to the ones above (its schema class in `experiments/<command>.py` and "
            "`conf/<command>.yaml`), and its whole `--help`.", ""]
    for module, command in COMMANDS.items():
        out += [f"### `{command}`", ""]
        if module == "synth":
            out += _key_table(H.field_rows(SynthConfig, ""), {}, "")
        else:
            top_m, desc_m, nested = H.top_keys(module)
            extra = [(k, v, desc_m[k]) for k, v in top_m.items() if k not in top or top[k] != v]
            extra += nested
            out += _key_table(extra, {}, "") if extra else ["No keys of its own.", ""]
        text = H.help_text("scenes" if module == "real_scenes" else module, command)
        out += [f'??? info "`{command} --help`"', "", "    ```text", *("    " + ln for ln in text.splitlines()),
                "    ```", ""]
    return "\n".join(out)


def _summary_of(cls: type) -> str:
    doc = (cls.__doc__ or "").strip()
    return doc.split("\n\n", 1)[0].replace("\n", " ")


def config_keys() -> dict[str, list[str]]:
    """``{command: every dotted key its Hydra schema accepts}`` (``experiments.cli.schema_keys``),
    what the configuration reference must name."""
    import importlib as il

    from experiments.cli import schema_keys
    from experiments.schema import RunConfig
    from experiments.synth_config import SynthConfig

    def leaves(schema: type) -> list[str]:  # a group of keys (data.sgbm) is named by its keys
        keys = schema_keys(schema)[0]
        return sorted(k for k in keys if not any(other.startswith(k + ".") for other in keys))

    out = {"run": leaves(RunConfig), "synth": leaves(SynthConfig)}
    for module in ("study", "validate", "real_scenes", "video"):
        mod = il.import_module(f"experiments.{module}")
        schemas = [v for v in vars(mod).values() if isinstance(v, type) and dataclasses.is_dataclass(v)
                   and issubclass(v, RunConfig) and v is not RunConfig and v.__module__ == mod.__name__]
        out[module] = sorted(set().union(*(leaves(s) for s in schemas))) if schemas else []
    return out


# ------------------------------------------------------------------------------------------ pictures
def _headings(text: str) -> list[tuple[int, str]]:
    return [(m.start(), m.group(2)) for m in re.finditer(r"^(#{1,4}) (.+)$", text, re.M)]


def _slug(heading: str) -> str:
    from markdown.extensions.toc import slugify

    return slugify(re.sub(r"[`*]", "", heading), "-")


def pictures_page() -> str:
    """The summary figure (caption from the README) and every gallery image, each with the section
    of the page that shows it (and that section's legend), or the script that draws it."""
    readme = (ROOT / "README.md").read_text()
    m = re.search(r"!\[[^\]]*\]\(docs/img/(\S+?)\)\n\n\*(.+?)\*\n", readme, re.S)
    out = ["# Pictures", "", "Every picture the documentation shows, with its caption; generated from the "
           "files in `docs/img/` and `docs/gallery/` and the pages that embed them.", ""]
    out += ["## One run of the pipeline", ""]
    if m:
        out += [f"![summary of one run](img/{m.group(1)})", "", "*" + m.group(2).replace("\n", " ") + "*", ""]
    used: dict[str, tuple[str, str, str]] = {}
    notes: dict[str, str] = {}  # an image's own words where a page gives them: the rest of its table cell
    for page in sorted((ROOT / "docs").glob("*.md")):
        text = page.read_text()
        heads = _headings(text)
        for hit in re.finditer(r"\(gallery/([^)\s]+\.png)\)", text):
            before = [h for pos, h in heads if pos < hit.start()]
            head = before[-1] if before else page.stem
            pos = next(p for p, h in heads if h == head) if before else 0
            rest = text[pos:].split("\n\n")
            legend = rest[1].replace("\n", " ") if len(rest) > 1 and not rest[1].lstrip().startswith(("|", "!", "`")) else ""
            used.setdefault(hit.group(1), (page.name, head, legend))
        for img in re.finditer(r"!\[[^\]]*\]\(gallery/([^)\s]+\.png)\)([^|\n]*)", text):
            if img.group(2).strip():
                notes.setdefault(img.group(1), img.group(2).strip())
    synth_doc = importlib.import_module("experiments.synth_gallery").__doc__ or ""
    synth_legend = synth_doc.split("\n\n")[1].replace("\n", " ") if "\n\n" in synth_doc else ""
    groups: dict[tuple[str, str, str], list[str]] = {}
    for png in sorted((ROOT / "docs" / "gallery").glob("*.png")):
        if png.name in used:
            key = used[png.name]
        elif png.name.startswith("synth_"):
            key = ("synth.md", "The generator's families (`python -m experiments.synth_gallery`)", synth_legend)
        else:
            key = ("", "Other pictures", "")
        groups.setdefault(key, []).append(png.name)
    for (page, head, legend), names in groups.items():
        out += [f"## {re.sub(r'[`]', '', head)}", ""]
        if page:
            anchor = "" if head.startswith("The generator") else f"#{_slug(head)}"
            out += [f"From [{page}]({page}{anchor}). {legend}".strip(), ""]
        for name in names:
            note = f" — {notes[name]}" if name in notes else ""
            out += [f"![{Path(name).stem}](gallery/{name})", "", f"*`{Path(name).stem}`*{note}", ""]
    return "\n".join(out)


# ---------------------------------------------------------------------------------------- the build
def write_all() -> None:
    """Write every generated page into the build (mkdocs-gen-files' virtual files). A public name
    without a docstring, or a config key the configuration reference does not name, is a warning,
    so the strict build stops with the name and the file."""
    import logging

    import mkdocs_gen_files

    log = logging.getLogger("mkdocs.plugins.somtorch_docs")
    for missing in undocumented():
        log.warning("gen_pages.py: public name without a docstring: %s", missing)
    config = config_page()
    for command, keys in config_keys().items():
        for key in keys:
            if f"`{key}`" not in config:
                log.warning("gen_pages.py: config key %s of %s is missing from reference/config.md", key,
                            COMMANDS[command])
    for page, text in api_pages().items():
        with mkdocs_gen_files.open(f"reference/{page}", "w") as f:
            f.write(text)
    with mkdocs_gen_files.open("reference/config.md", "w") as f:
        f.write(config)
    with mkdocs_gen_files.open("pictures.md", "w") as f:
        f.write(pictures_page())
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        with mkdocs_gen_files.open(f"notebooks/{nb.name}", "wb") as f:
            f.write(nb.read_bytes())


if __name__ in ("__main__", "<run_path>"):
    write_all()
