"""``--help`` of the experiments in a fraction of a second: no torch, no Hydra composition.

The text is built from what is declared once: the config groups and their options (``conf/``),
the experiment's own YAML (its top-level values), and the dataclasses of ``somtorch.config``
(every key with its default and the first sentence of its description from the class docstring).
"""

from __future__ import annotations

import dataclasses
import re
import sys
from pathlib import Path

from . import CONF  # the clone's conf/, or the one shipped in the wheel

USAGE = {
    "run": "the whole pipeline on one scene (outputs/run/<scene>/<time>/)",
    "study": "paper studies and sweeps (Table 1/2, runtime, stability; -m for sweeps)",
    "validate": "leave-one-dataset-out validation of the object step's constants",
    "real_scenes": "the pipeline (and baselines) scored on named development scenes",
    "video": "a disparity sequence, each frame's SOM warm-started",
    "synth": "generated stereo frames (GT + SGBM) into the cache (docs/synth.md)",
    "ground_report": "the ground step alone under two ground configs, side by side (a Markdown table)",
    "synth_gallery": "one picture per family of the synthetic generator (docs/gallery/)",
    "train_baseline": "the learned baseline: a small U-Net trained on generated frames only (docs/validation.md)",
}


def _descriptions(cls: type | str | None) -> dict[str, str]:
    """``{field: first sentence}`` from the ``Attributes:`` section of a class docstring (or the
    docstring itself), or (a docstring in titled sections, like :class:`~somtorch.config.AreaConfig`'s)
    from every ``name: text`` entry of it."""
    doc = (cls if isinstance(cls, str) else getattr(cls, "__doc__", None)) or ""
    out: dict[str, str] = {}
    body = doc.split("Attributes:", 1)[1] if "Attributes:" in doc else doc
    current: list[str] = []
    text: list[str] = []
    for line in body.splitlines():
        m = re.match(r"^\s{4,8}([a-z_][\w, ]*):\s*(.*)$", line)
        if m and not line.startswith(" " * 12):
            for name in current:
                out[name] = " ".join(text)
            current = [n.strip() for n in m.group(1).split(",")]
            text = [m.group(2)]
        elif current and line.strip():
            text.append(line.strip())
    for name in current:
        out[name] = " ".join(text)
    return {k: re.split(r"(?<=\.)\s", v, maxsplit=1)[0] for k, v in out.items()}


def field_rows(cls: type, prefix: str, instance: object = None) -> list[tuple[str, object, str]]:
    """``[(key, default, description)]`` of a config dataclass's own fields (nested dataclasses
    left out), the description being the first sentence of the field's docstring entry: what
    ``--help`` lists and the site's configuration reference tabulates (``scripts/docs/gen_pages.py``).
    Defaults are read from ``instance`` where given (a field whose default is a configured instance
    of ``cls``)."""
    import typing

    rows = []
    desc = _descriptions(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name.startswith("_") or dataclasses.is_dataclass(hints.get(f.name)):
            continue
        default = getattr(instance, f.name) if instance is not None else f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else "???")
        rows.append((f"{prefix}{f.name}", default, desc.get(f.name, "")))
    return rows


def _fields(cls: type, prefix: str, instance: object = None) -> list[str]:
    return [f"  {k}={v!r}" + (f"  — {d}" if d else "") for k, v, d in field_rows(cls, prefix, instance)]


def prog(module: str, argv0: str | None = None) -> str:
    """The command the user typed: the console script (``somtorch-run``) or ``python -m <package>.<module>``."""
    name = Path(sys.argv[0] if argv0 is None else argv0).name
    if not name or name.endswith(".py") or name in ("-c", "-m", "__main__.py"):
        return f"python -m {__package__}.{module}"
    return name


class _Literal(str):
    """A default as written in the source (its repr is itself)."""

    def __repr__(self) -> str:
        return str(self)


def _yaml_comments(text: str) -> dict[str, str]:
    """``{top-level key: its trailing comment}`` of a YAML file."""
    return {m.group(1): m.group(2).strip() for m in re.finditer(r"^([a-z_]+):[^#\n]*#(.*)$", text, re.M)}


def _own_fields(module: str) -> list[tuple[str, str, str]]:
    """``[(key, default, description)]`` of the fields the experiment's schema class (the class of
    ``experiments/<module>.py`` derived from ``RunConfig``) adds, read from its source without
    importing it (that would import torch and Hydra); a nested dataclass of the same file gives
    ``name.field`` keys. The description: the class docstring's ``Attributes:`` entry, else the
    field's trailing comment."""
    import ast

    path = Path(__file__).with_name(f"{module}.py")
    if not path.is_file():
        return []
    text = path.read_text()
    lines = text.splitlines()
    classes = {n.name: n for n in ast.parse(text).body if isinstance(n, ast.ClassDef)}

    def fields(node: ast.ClassDef, prefix: str) -> list[tuple[str, str, str]]:
        desc = _descriptions(ast.get_docstring(node))
        out = []
        for st in node.body:
            if not (isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name)):
                continue
            name, ann = st.target.id, ast.unparse(st.annotation)
            if ann in classes:
                out += fields(classes[ann], f"{prefix}{name}.")
                continue
            default = "???" if st.value is None else ast.unparse(st.value)
            if default.startswith("field(default_factory="):
                default = {"list": "[]", "dict": "{}"}.get(default[len("field(default_factory="):-1], default)
                factory = next((k.value for k in getattr(st.value, "keywords", [])
                                if k.arg == "default_factory"), None)
                if isinstance(factory, ast.Lambda):  # `lambda: [0, 5]`: the value it makes
                    default = ast.unparse(factory.body)
            comment = lines[st.lineno - 1].split("#", 1)[1].strip() if "#" in lines[st.lineno - 1] else ""
            out.append((prefix + name, default, desc.get(name) or comment))
        return out

    own = [c for c in classes.values() if any(ast.unparse(b) == "RunConfig" for b in c.bases)]
    return fields(own[0], "") if own else []


def top_keys(module: str) -> tuple[dict[str, object], dict[str, str], list[tuple[str, str, str]]]:
    """``(defaults, descriptions, nested)`` of an experiment's top-level keys: the pipeline's own
    (method, ensemble, seed, object_id, device), label, and what the experiment's schema class and
    YAML add (a value the YAML sets replaces the dataclass default); ``nested``: the experiment's
    own ``group.key`` fields as ``(key, default, description)``."""
    from somtorch import config as C

    own = CONF / f"{module}.yaml"
    doc, comments = {}, {}
    if own.is_file():
        import yaml

        text = own.read_text()
        doc = {k: v for k, v in (yaml.safe_load(text) or {}).items()
               if k not in ("defaults", "hydra") and not isinstance(v, dict)}
        comments = _yaml_comments(text)
    desc = {**_descriptions(C.PipelineConfig), "label": "a name for the configuration (set by presets; shown in tables)."}
    top = {f.name: f.default for f in dataclasses.fields(C.PipelineConfig)
           if not f.name.startswith("_") and f.default is not dataclasses.MISSING}
    top["label"] = "robust"
    own_fields = _own_fields(module)
    nested = [f for f in own_fields if "." in f[0]]
    for key, default, d in own_fields:
        if "." not in key:
            top[key] = _Literal(default)
            desc[key] = d
    top.update(doc)
    return top, {k: desc.get(k) or comments.get(k, "") for k in top}, nested


def sections(module: str) -> list[tuple[str, type]]:
    """``[(prefix, dataclass)]``: the key groups of an experiment's config after its top-level keys."""
    from somtorch import config as C

    out = [("features", C.FeatureConfig), ("som", C.SOMConfig), ("train", C.TrainConfig),
           ("ground", C.GroundConfig), ("objects", C.AreaConfig), ("reduction", C.ReductionConfig),
           ("output", C.OutputConfig), ("baseline", C.BaselineConfig), ("resources", C.ResourcesConfig)]
    if module == "video":
        out.append(("sequence", C.WarmStartConfig))
    return out


def _tool_help(module: str, argv0: str | None) -> str:
    """The help of a command that is not a pipeline run: its schema's keys, nested ones by prefix."""
    import typing

    from .synth_config import SynthConfig
    from .tool_configs import GroundReportConfig, SynthGalleryConfig
    from .train_baseline_config import TrainBaselineConfig

    cls = {"synth": SynthConfig, "ground_report": GroundReportConfig, "synth_gallery": SynthGalleryConfig,
           "train_baseline": TrainBaselineConfig}[module]
    lines = [f"{prog(module, argv0)} [key=value ...]", f"  {USAGE[module]}", "", f"Keys ({cls.__name__}):"]
    lines += _fields(cls, "")
    hints, desc = typing.get_type_hints(cls), _descriptions(cls)
    for f in dataclasses.fields(cls):
        sub = hints.get(f.name)
        if dataclasses.is_dataclass(sub):
            lines += ["", f"{f.name}.* ({sub.__name__}): {desc.get(f.name, '')}"]
            lines += _fields(sub, f.name + ".", f.default_factory())  # type: ignore[misc]
    return "\n".join(lines)


def help_text(name: str, argv0: str | None = None) -> str:
    from .cli import config_groups
    from .data_schema import DataSource, PathsConfig

    groups = config_groups()
    module = "real_scenes" if name == "scenes" else name
    if module in ("synth", "ground_report", "synth_gallery", "train_baseline"):  # not a pipeline run: its own keys only
        return _tool_help(module, argv0)
    lines = [f"{prog(module, argv0)} [group=option ...] [key=value ...]",
             f"  {USAGE.get(module, '')}", "",
             "Config groups (group=option; '+preset=paper' and '+experiment=...' add one):"]
    for g, opts in groups.items():
        lines.append(f"  {g}: {', '.join(opts)}")
    top, desc, nested = top_keys(module)
    lines += ["", "Top-level keys:"]
    for k, v in top.items():
        d = desc[k]
        lines.append(f"  {k}={v!r}" + (f"  — {d}" if d else ""))
    lines += ["", "data.* (where the disparity comes from; conf/data/<option>.yaml sets them):"]
    lines += _fields(DataSource, "data.")
    lines.append("  data.sgbm.<name>  — StereoSGBM setting under OpenCV's name (somtorch.disparity.stereo.SGBMParams:"
                 " minDisparity, numDisparities, blockSize, P1, P2, disp12MaxDiff, uniquenessRatio,"
                 " speckleWindowSize, speckleRange, mode), e.g. data.sgbm.numDisparities=64")
    lines += ["", "paths.* (PathsConfig):"] + _fields(PathsConfig, "paths.")
    for prefix, cls in sections(module):
        lines += ["", f"{prefix}.* ({cls.__name__}):"] + _fields(cls, prefix + ".")
        lines += [f"  {k}={v}" + (f"  — {d}" if d else "") for k, v, d in nested if k.startswith(prefix + ".")]
    if module == "study":
        lines += ["", "Sweeps (-m or +experiment=...):",
                  "  hydra.launcher.n_jobs=None  — jobs side by side (None: as many as cores are free and memory"
                  " holds; 1: one after another in this process); the default launcher, hydra/launcher=somtorch"
                  " (docs/scaling.md §11)",
                  "  hydra/launcher=basic|joblib|ray|slurm  — Hydra's launchers instead (slurm: conf/hydra/launcher/)"]
    lines += ["", "Every key, resolved: --cfg job.  Hydra's own help: --hydra-help.",
              "Docs: README.md, docs/ (validation, scaling, tuned_constants, reliability, results)."]
    return "\n".join(lines)


def maybe_print_help(name: str, argv: list[str] | None = None) -> None:
    """Print the help and exit 0 when ``-h`` / ``--help`` is among the arguments."""
    args = sys.argv[1:] if argv is None else argv
    if "--help" in args or "-h" in args:
        try:
            print(help_text(name, sys.argv[0] if argv is None else None), flush=True)
        except BrokenPipeError:  # `--help | head`: the reader has seen enough
            import os

            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise SystemExit(0)
