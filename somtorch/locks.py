"""A lock file that heals: it names its owner, and a lock whose owner is gone is taken over.

:func:`exclusive_folder` holds ``folder/.lock`` while a block runs. The file is created complete
(written beside it, then hard-linked into place, so nobody ever reads a half-written lock) and
holds one JSON line: the owner's PID, its start time (field 22 of ``/proc/PID/stat``, clock ticks
since boot) and the host name. A second writer of the same folder

* is refused at once, with one line naming the owner, when that owner is alive;
* takes the lock over, with one warning line saying so, when the owner is gone: no process of
  that PID, or a process of that PID that started at another time (the PID was reused after the
  owner died, ``kill -9`` or a power cut). A lock of another host is never taken over (its owner
  cannot be checked from here).

Two writers that find the same stale lock at once both move it aside (``rename`` is atomic: one
of them gets it), check that what they moved is the stale lock they read, and then race for the
exclusive creation; exactly one wins.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["FolderLocked", "exclusive_folder", "owner_alive", "process_start"]

log = logging.getLogger(__name__)
_ATTEMPTS = 5  # stale locks moved aside before giving up (each attempt loses only to a live writer)


class FolderLocked(RuntimeError):
    """The folder is held by another live process (a ``RuntimeError``: one line at the CLI).

    Attributes:
        owner: what the lock file says of its owner ({"pid", "start", "host"}; None if unreadable).
    """

    def __init__(self, message: str, owner: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.owner = owner

    @property
    def local(self) -> bool:
        """The owner is a process of this host (so its end can be waited for)."""
        return self.owner is not None and self.owner.get("host", socket.gethostname()) == socket.gethostname()


def process_start(pid: int) -> int | None:
    """Start time of process ``pid`` (clock ticks since boot, ``/proc/PID/stat`` field 22), or None
    when there is no such process or no ``/proc`` (then only the PID is compared)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) is in parentheses and may hold spaces or ")": split after the last
    fields = stat[stat.rindex(")") + 2:].split()
    return int(fields[19])  # field 22 of the whole line = the 20th after the name


def _pid_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def owner_alive(owner: dict[str, Any]) -> bool:
    """Whether the process a lock names still runs (True when that cannot be told from here)."""
    if owner.get("host", socket.gethostname()) != socket.gethostname():
        return True
    pid = owner.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return True
    if not _pid_exists(pid):
        return False
    start, now = owner.get("start"), process_start(pid)
    return start is None or now is None or start == now  # another start: the PID was reused


def _read(path: Path) -> dict[str, Any] | None:
    """The owner a lock file names ({"pid", "start", "host"}), or None if it says nothing usable."""
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        return {}
    except OSError:
        return None
    if text.isdigit():  # a lock of somtorch before 2026-12 held the bare PID
        return {"pid": int(text)}
    try:
        owner = json.loads(text)
    except ValueError:
        return None
    return owner if isinstance(owner, dict) else None


def _describe(owner: dict[str, Any]) -> str:
    host = owner.get("host")
    return f"PID {owner.get('pid')}" + (f" on {host}" if host and host != socket.gethostname() else "")


def _create(path: Path, content: str) -> bool:
    """Create ``path`` holding ``content`` if it does not exist (complete at once); False if it does."""
    fd, tmp = tempfile.mkstemp(prefix=".lock-", dir=path.parent)
    try:
        os.write(fd, content.encode())
        os.close(fd)
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        except OSError:  # a file system without hard links: exclusive creation, then the content
            try:
                fd2 = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                return False
            os.write(fd2, content.encode())
            os.close(fd2)
        return True
    finally:
        Path(tmp).unlink(missing_ok=True)


def _take_over(path: Path, seen: dict[str, Any]) -> None:
    """Move the stale lock ``path`` (whose owner ``seen`` is gone) aside and delete it; if what was
    moved is not that lock (another writer took it over meanwhile), put it back."""
    aside = path.with_name(f"{path.name}.stale-{os.getpid()}")
    try:
        os.rename(path, aside)
    except FileNotFoundError:  # another writer moved it first
        return
    if _read(aside) == seen:
        aside.unlink(missing_ok=True)
        return
    with contextlib.suppress(OSError):  # a live writer's fresh lock: give it back
        os.link(aside, path)
    aside.unlink(missing_ok=True)


def acquire(path: Path) -> dict[str, Any]:
    """Create the lock file ``path`` for this process, taking over a stale one; the owner written.

    Raises:
        FolderLocked: a live process (or one of another host) holds it.
    """
    me = {"pid": os.getpid(), "start": process_start(os.getpid()), "host": socket.gethostname()}
    content = json.dumps(me) + "\n"
    for _ in range(_ATTEMPTS):
        if _create(path, content):
            return me
        owner = _read(path)
        if owner == {}:  # removed since: try again
            continue
        if owner is None or owner_alive(owner):
            who = "an unreadable lock" if owner is None else f"the run of {_describe(owner)}"
            raise FolderLocked(f"{path.parent} is being written by {who} (lock file {path}); give this run its "
                               "own folder (hydra.run.dir=...), or remove the lock if no run is alive", owner)
        log.warning("%s: took over the lock of %s, which is no longer running", path.parent, _describe(owner))
        _take_over(path, owner)
    raise FolderLocked(f"{path.parent}: could not take the lock {path} ({_ATTEMPTS} attempts; other runs "
                       "keep taking it)")


@contextlib.contextmanager
def exclusive_folder(folder: str | os.PathLike, name: str = ".lock", *, wait: bool = False,
                     poll_s: float = 0.5) -> Iterator[Path]:
    """Hold ``folder/name`` while the block runs (see the module docstring): a second writer of the
    same folder fails at once with one line instead of overwriting the first one's results, and a
    lock left by a killed run is taken over with a warning.

    Args:
        folder: the folder to hold (created if missing).
        name: the lock file's name in it.
        wait: instead of failing, wait (one log line, then a check every ``poll_s`` seconds) until
            a live owner of this host lets go; a lock of another host still fails at once.
        poll_s: seconds between two checks while waiting.

    Raises:
        FolderLocked: a live process holds the folder (and ``wait`` is False, or it is on another host).
    """
    import time

    path = Path(folder) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    said = False
    while True:
        try:
            me = acquire(path)
            break
        except FolderLocked as e:
            if not (wait and e.local):
                raise
            if not said:
                log.info("%s is being written by %s: waiting for it", path.parent, _describe(e.owner or {}))
                said = True
            time.sleep(poll_s)
    try:
        yield path
    finally:
        if _read(path) == me:  # never remove a lock that is not ours
            path.unlink(missing_ok=True)
