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

CONF = Path(__file__).resolve().parents[1] / "conf"

USAGE = {
    "run": "the whole pipeline on one scene (outputs/run/<scene>/<time>/)",
    "study": "paper studies and sweeps (Table 1/2, runtime, stability; -m for sweeps)",
    "validate": "leave-one-scene-out validation of the object step's constants",
    "real_scenes": "the pipeline (and baselines) scored on named development scenes",
    "video": "a disparity sequence, each frame's SOM warm-started",
    "synth": "generated stereo frames (GT + SGBM) into the cache (docs/synth.md)",
}


def _descriptions(cls: type) -> dict[str, str]:
    """``{field: first sentence}`` from the ``Attributes:`` section of a class docstring, or (a
    docstring in titled sections, like :class:`~somtorch.config.AreaConfig`'s) from every
    ``name: text`` entry of it."""
    doc = cls.__doc__ or ""
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


def _fields(cls: type, prefix: str) -> list[str]:
    import typing

    lines = []
    desc = _descriptions(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if f.name.startswith("_") or dataclasses.is_dataclass(hints.get(f.name)):
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else "???")
        d = desc.get(f.name, "")
        lines.append(f"  {prefix}{f.name}={default!r}" + (f"  — {d}" if d else ""))
    return lines


def help_text(name: str) -> str:
    from somtorch import config as C

    from experiments.cli import config_groups

    groups = config_groups()
    module = "real_scenes" if name == "scenes" else name
    if module == "synth":  # not a pipeline run: its own keys only
        from experiments.synth_config import SynthConfig

        return "\n".join([f"python -m experiments.synth [key=value ...]", f"  {USAGE['synth']}", "",
                          "Keys (SynthConfig):"] + _fields(SynthConfig, ""))
    lines = [f"python -m experiments.{module} [group=option ...] [key=value ...]",
             f"  {USAGE.get(module, '')}", "",
             "Config groups (group=option; '+preset=paper' and '+experiment=...' add one):"]
    for g, opts in groups.items():
        lines.append(f"  {g}: {', '.join(opts)}")
    own = CONF / f"{module}.yaml"
    if own.is_file():
        import yaml

        doc = yaml.safe_load(own.read_text()) or {}
        top = {k: v for k, v in doc.items() if k not in ("defaults", "hydra")}
        if top:
            lines += ["", f"Top-level keys of conf/{module}.yaml:"]
            lines += [f"  {k}={v!r}" for k, v in top.items()]
    sections = [("features", C.FeatureConfig), ("som", C.SOMConfig), ("train", C.TrainConfig),
                ("ground", C.GroundConfig), ("objects", C.AreaConfig), ("reduction", C.ReductionConfig),
                ("output", C.OutputConfig)]
    if module == "video":
        sections.append(("sequence", C.WarmStartConfig))
    for prefix, cls in sections:
        lines += ["", f"{prefix}.* ({cls.__name__}):"] + _fields(cls, prefix + ".")
    lines += ["", "Every key, resolved: --cfg job.  Hydra's own help: --hydra-help.",
              "Docs: README.md, docs/ (validation, scaling, tuned_constants, reliability, results)."]
    return "\n".join(lines)


def maybe_print_help(name: str, argv: list[str] | None = None) -> None:
    """Print the help and exit 0 when ``-h`` / ``--help`` is among the arguments."""
    args = sys.argv[1:] if argv is None else argv
    if "--help" in args or "-h" in args:
        print(help_text(name))
        raise SystemExit(0)
