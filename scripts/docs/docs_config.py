"""The configuration reference (``reference/config.md``): every Hydra config group with its
options, and every key with its default, constraint and description, from the config dataclasses and
their ``_constraints`` tables through ``experiments/help.py`` (the code that renders ``--help``)."""

from __future__ import annotations

import dataclasses
import re
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # the clone's experiments/ (help, cli, schema)
    sys.path.insert(0, str(ROOT))

PACKAGE = "somtorch"


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
        rule_text = _cell(describe(rule)) if rule else ""
        out.append(f"| `{key}` | `{_cell(repr(default))}` | {rule_text} | {_cell(desc)} |")
    return out + [""]


def _folded(title: str, lang: str, text: str) -> list[str]:
    """A collapsed block (pymdownx.details) holding ``text`` as code."""
    return [f"??? {title}", "", f"    ```{lang}", *("    " + ln for ln in text.splitlines()), "    ```", ""]


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
            out += _folded(f'note "`{group}={opt}`"', "yaml", text)
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
        out += _folded(f'info "`{command} --help`"', "text", text)
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


