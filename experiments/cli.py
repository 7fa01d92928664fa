"""Command-line overrides checked before Hydra sees them: an unknown key gets a "did you mean".

Hydra answers ``objects.simlarity=0.1`` with "Key 'simlarity' not in 'AreaConfig'" and the advice
to *append* it with ``+``, which would silently add a key nothing reads. :func:`check_overrides`
looks every plain ``key=value`` override up in the experiment's schema (the dataclass tree of its
config) and in the config groups of ``conf/``, and stops with one line naming the closest known
key or option. Overrides with a ``+`` / ``++`` / ``~`` prefix, ``hydra.*`` and Hydra's own flags are
left to Hydra.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import sys
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from . import CONF  # the clone's conf/, or the one shipped in the wheel


def field_types(schema: type, prefix: str = "") -> dict[str, Any]:
    """``{dotted key: annotation}`` of every leaf field of a dataclass tree."""
    out: dict[str, Any] = {}
    hints = typing.get_type_hints(schema)
    for f in dataclasses.fields(schema):
        t = hints.get(f.name, Any)
        if dataclasses.is_dataclass(t):
            out.update(field_types(t, f"{prefix}{f.name}."))
        else:
            out[f"{prefix}{f.name}"] = t
    return out


FINITE_HINT = "NaN and infinities are not config values, in any spelling"


def _finite(v: Any, text: str) -> bool:
    """False for a NaN or infinity, as YAML reads it (``.nan``, ``-.inf``) or as Hydra and
    OmegaConf would (``nan``, ``inf``, ``1e999``, ``Infinity``)."""
    import math

    if isinstance(v, float):
        return math.isfinite(v)
    if isinstance(v, str):
        try:
            return math.isfinite(float(v.strip()))
        except ValueError:
            return True  # not a number at all: the type check says so
    return True


def _list_error(key: str, value: str, t: Any, optional: bool) -> str | None:
    """A one-line complaint when ``value`` cannot be a ``t`` (``list[...]``): not a list at all
    (``frame_shifts=5``), or not whole numbers in a ``list[int]``; Hydra's own message is several
    lines. Interpolations, sweeps and what YAML cannot read are left to Hydra."""
    import yaml

    text = value.strip()
    if text.startswith(("${", "choice(", "range(", "glob(", "interval(")) or (optional and text == "null"):
        return None
    try:
        v = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    if not isinstance(v, list):
        return f"{key}={value}: expected a list, e.g. {key}=[{value}]" + (" or null" if optional else "")
    item = (typing.get_args(t) or (Any,))[0]
    if item is int and not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
        return f"{key}={value}: expected a list of whole numbers"
    return None


def _value_error(key: str, value: str, t: Any) -> str | None:
    """A one-line complaint when ``value`` cannot be a ``t`` (int / float / bool, optionally None;
    a list, :func:`_list_error`)."""
    import yaml

    if typing.get_origin(t) is list:  # (its args are the item type's)
        return _list_error(key, value, t, False)
    args = typing.get_args(t)
    optional = type(None) in args
    base = next((a for a in args if a is not type(None)), t) if args else t
    if typing.get_origin(base) is list:  # Optional[list[...]]
        return _list_error(key, value, base, optional)
    if base not in (int, float, bool) or "(" in value or "[" in value:  # sweep functions, lists: Hydra's
        return None
    for part in value.split(","):  # a sweep lists several values
        part = part.strip()
        if not part or part.startswith(("range(", "choice(", "interval(", "${", "glob(")):
            continue
        try:
            v = yaml.safe_load(part)
        except yaml.YAMLError:
            v = part
        if isinstance(v, str) and base is float:  # 1e3: a string to YAML 1.1, a float to Hydra
            with contextlib.suppress(ValueError):
                v = float(part)
        if v is None and optional:
            continue
        if base is not bool and not _finite(v, part):
            return f"{key}={part}: expected a finite number ({FINITE_HINT})"
        ok = (isinstance(v, bool) if base is bool else
              isinstance(v, int) and not isinstance(v, bool) if base is int else
              isinstance(v, (int, float)) and not isinstance(v, bool))
        if not ok:
            return f"{key}={part}: expected {'a' if base is not int else 'an'} {base.__name__}" + (
                " or null" if optional else "")
    return None


def schema_keys(schema: type, prefix: str = "") -> tuple[set[str], set[str]]:
    """``(keys, open_keys)``: every dotted field path of a dataclass tree, and the paths of fields
    that take free sub-keys (dicts, ``Any``)."""
    keys, open_keys = set(), set()
    hints = typing.get_type_hints(schema)
    for f in dataclasses.fields(schema):
        if f.name.startswith("_"):
            continue
        path = f"{prefix}{f.name}"
        keys.add(path)
        t = hints.get(f.name, Any)
        if dataclasses.is_dataclass(t):
            sub, sub_open = schema_keys(t, path + ".")
            keys |= sub
            open_keys |= sub_open
        elif t is Any or typing.get_origin(t) is dict or t is dict:
            open_keys.add(path)
    return keys, open_keys


NOT_GROUPS = ("labels",)  # folders of conf/ that hold data, not Hydra options


def config_groups() -> dict[str, list[str]]:
    """``{group: [options]}`` of the Hydra config groups in ``conf/``."""
    return {d.name: sorted(p.stem for p in d.glob("*.yaml")) for d in sorted(CONF.iterdir())
            if d.is_dir() and d.name not in NOT_GROUPS and any(d.glob("*.yaml"))}


def _hint(word: str, known: list[str]) -> str:
    near = difflib.get_close_matches(word, known, n=1, cutoff=0.6)
    return f"did you mean {near[0]!r}?" if near else f"known: {', '.join(sorted(known)[:12])}" + (
        ", ..." if len(known) > 12 else "")


def check_overrides(argv: list[str], schema: type) -> str | None:
    """The error line for the first unknown key or group option in ``argv``, or None."""
    keys, open_keys = schema_keys(schema)
    types = field_types(schema)
    groups = config_groups()
    for arg in argv:
        if arg.startswith("-") or "=" not in arg or arg[0] == "~":
            continue
        if arg[0] == "+":  # appended or forced keys are Hydra's to place; their values are checked here
            key, value = arg.lstrip("+").split("=", 1)
            bad = _value_error(key, value, types[key]) if key in types else None
            if bad:
                return bad
            continue
        key, value = arg.split("=", 1)
        if key.startswith("hydra") or "@" in key or "/" in key:
            continue
        if key in groups and key not in keys - set(groups):
            options = [v.strip() for v in value.split(",")]  # a sweep lists several
            for opt in options:
                if opt and opt not in groups[key] and not opt.startswith(("range(", "choice(", "glob(")):
                    return f"{key}={opt}: no option {opt!r} in conf/{key}/; {_hint(opt, groups[key])}"
            continue
        if key in keys or any(key.startswith(o + ".") for o in open_keys):
            bad = _value_error(key, value, types.get(key, Any))
            if bad:
                return bad
            continue
        return (f"unknown config key {key!r}: {_hint(key, sorted(keys | set(groups)))} "
                "(--cfg job prints every key)")
    return None


@contextlib.contextmanager
def marked_if_failed(out_dir: Path) -> Iterator[None]:
    """A job that exits with an error leaves ``FAILED`` in the folder Hydra made for it (beside
    ``run.log`` and ``.hydra``), so that nobody, and no aggregate, takes the folder for a result."""
    try:
        yield
    except SystemExit as e:
        if e.code and out_dir.is_dir() and not (out_dir / "FAILED").exists() and not (
                out_dir / "metrics.json").exists():
            (out_dir / "FAILED").write_text(f"this run failed (exit status {e.code}); the error is in the log\n")
        raise


@contextlib.contextmanager
def interruptible(out_dir: Path | None) -> Iterator[None]:
    """SIGINT / SIGTERM stop the job between epochs, chunks and members (:mod:`somtorch.interrupt`):
    one line on stderr, ``FAILED`` in ``out_dir`` (staging folders and the lock are removed by the
    ``finally`` blocks the exception runs through), exit status 130 / 143."""
    import shutil

    from somtorch import interrupt

    interrupt.reset()
    interrupt.install()
    try:
        yield
        interrupt.note("")  # a signal between the jobs of a multirun is not "after epoch 9/10"
    except interrupt.Interrupted as e:
        import signal

        for s in (signal.SIGINT, signal.SIGTERM):  # a second signal (a launcher passing it on) must not
            signal.signal(s, signal.SIG_IGN)       # cut the clean-up short: the process exits below
        where = f" {e.where}" if e.where else ""
        tail = "partial results not written"
        if out_dir is not None and out_dir.is_dir():
            for stale in out_dir.glob(".partial-*"):
                shutil.rmtree(stale, ignore_errors=True)
            (out_dir / "FAILED").write_text(f"interrupted ({e.signal_name}){where}; {tail}\n")
            tail += f"; {out_dir / 'FAILED'}"
        msg = f"interrupted ({e.signal_name}){where}; {tail}"
        import logging

        from .schema import log_to_file

        log_to_file(logging.getLogger("somtorch"), logging.WARNING, "%s", msg)
        print(msg, file=sys.stderr)
        raise SystemExit(e.exit_code) from None


def run_checked(main: Any, schema: type, argv: list[str] | None = None) -> Any:
    """Check ``sys.argv`` against ``schema``, then call the Hydra ``main``; a bad key exits with
    status 2 and one line on stderr."""
    if argv is None and any(a in ("--quiet", "-q") for a in sys.argv[1:]):
        # --quiet: no progress bars, warnings and errors only (Hydra does not know the flag: drop it)
        import os

        sys.argv = [sys.argv[0]] + [a for a in sys.argv[1:] if a not in ("--quiet", "-q")]
        os.environ["SOMTORCH_QUIET"] = "1"
    err = check_overrides(list(sys.argv[1:] if argv is None else argv), schema)
    if err is not None:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2)
    from somtorch import interrupt

    from .entry import STARTUP

    interrupt.install()  # takes over from the start-up handler (experiments.entry): Interrupted, below
    interrupt.note(STARTUP)  # until a job resets it
    try:
        return main()
    except interrupt.Interrupted as e:  # outside a job (start-up, between the jobs of a multirun): no folder to mark
        print(f"interrupted ({e.signal_name}) {e.where or 'between jobs'}".rstrip(), file=sys.stderr)
        raise SystemExit(e.exit_code) from None
    except KeyboardInterrupt:  # a handler of a library replaced ours
        print(f"interrupted (SIGINT) {STARTUP}", file=sys.stderr)
        raise SystemExit(130) from None


def quiet() -> bool:
    """``--quiet`` was given (or ``SOMTORCH_QUIET=1``)."""
    import os

    return os.environ.get("SOMTORCH_QUIET") == "1"


def show_progress() -> bool:
    """Progress bars only for a person watching: a terminal on stderr, no ``--quiet``, and not in a
    worker of the somtorch launcher (``SOMTORCH_PROGRESS=0``: side by side, bars overwrite each other)."""
    import os

    return not quiet() and os.environ.get("SOMTORCH_PROGRESS") != "0" and sys.stderr.isatty()


def announce(command: str, jobs: str, seconds: float | None) -> None:
    """One line on stderr before a long command starts (unless ``--quiet``): what it will do and
    the estimated time (``somtorch.resources``), e.g. ``validate: 9 frames x 14 candidates, estimated ~3.2 min``."""
    from somtorch.resources import fmt_seconds

    est = "no time estimate" if seconds is None else f"estimated ~{fmt_seconds(seconds)} (rough: from the sizes)"
    if not quiet():
        print(f"{command}: {jobs}, {est}", file=sys.stderr, flush=True)


def progress_bar(total: int, desc: str, unit: str) -> Any:
    """A tqdm bar over the ``total`` units of a command, shown where :func:`show_progress` says."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=not show_progress(), dynamic_ncols=True)


def launcher_jobs() -> int:
    """Jobs a Hydra launcher runs side by side on this machine (1 outside a multirun).

    The joblib launcher's ``n_jobs`` (negative counts as joblib does: -1 = every core); other
    launchers start one job per task with its own CPUs (SLURM, Ray set the affinity or
    ``OMP_NUM_THREADS``), so they count as 1. Under ``torchrun`` the local ranks share the node.
    """
    import os

    from somtorch.core.threads import available_cores

    local = os.environ.get("LOCAL_WORLD_SIZE")
    if local and local.isdigit() and int(local) > 0:
        return int(local)
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return 1
    if hc.mode != RunMode.MULTIRUN:
        return 1
    n = hc.launcher.get("n_jobs") if hc.launcher is not None else None
    if n is None:
        return 1
    n = int(n)
    return max(1, available_cores() + 1 + n if n < 0 else n)


def configure_threads() -> int:
    """Set torch's threads for this job from the cores free to it (``somtorch.core.threads``)."""
    import logging

    from somtorch.core.threads import configure

    jobs = launcher_jobs()
    n = configure(jobs=jobs)
    logging.getLogger("somtorch").debug("CPU threads: %d (launcher jobs side by side: %d)", n, jobs)
    return n
