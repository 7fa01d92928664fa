"""Crash-safe file output: write to a temporary file beside the target, then rename.

A reader never sees a half-written file: either the old file (or none) or the complete new one.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder (same suffix); move it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is left untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_UMASK)  # mkstemp creates 0600; give the file the usual mode
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_UMASK)  # again: a writer may have replaced the file (safetensors does)
        os.replace(tmp_path, target)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Atomically write ``data`` to ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Atomically write ``obj`` as indented JSON (NaN/inf rejected, so the file is valid JSON)."""
    return write_bytes(path, (json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n").encode())


def commit_staged(stage: str | os.PathLike, out_dir: str | os.PathLike, last: str = "metrics.json") -> None:
    """Move every entry of the staging folder ``stage`` into ``out_dir``, ``last`` last: its presence
    marks a complete result, so a run killed half-way never looks complete. Existing entries of the
    same name are replaced."""
    import shutil

    out = Path(out_dir)
    for entry in sorted(Path(stage).iterdir(), key=lambda p: p.name == last):
        target = out / entry.name
        if target.is_dir():
            shutil.rmtree(target)
        os.replace(entry, target)


def write_staged(out_dir: str | os.PathLike, files: dict[str, bytes | Any], last: str | None = None) -> None:
    """Write ``{name: bytes or JSON-ready object}`` into ``out_dir`` through a staging folder, the
    last entry of ``files`` (or ``last``) moved in last: a killed writer leaves no partial result."""
    import shutil

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=out))
    try:
        for name, content in files.items():
            if isinstance(content, bytes):
                write_bytes(stage / name, content)
            else:
                write_json(stage / name, content)
        commit_staged(stage, out, last=last or list(files)[-1])
    finally:
        shutil.rmtree(stage, ignore_errors=True)