"""The status files of ``wearable-gaze batch`` (docs/batch.md, docs/formats.md): each session's
status in its output folder (``OUT/NAME/batch_status.json``: name, session, state, reason,
fingerprint, times, the worker and its memory) and the batch's index (``OUT/batch.json``:
settings, counts per state, every status). One reader (``read_status``, ``earlier_statuses``)
and one writer (``write_status``, ``write_index``), atomic. And the lock a worker holds on a
session's output folder while it processes it (``LOCK_FILE``: ``take_lock``, ``release_lock``,
``lock_owner``), stale when its owner process is dead.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import time
from collections import Counter
from pathlib import Path

from .jsonio import write_json

log = logging.getLogger(__name__)

STATUS_FILE = "batch_status.json"
"""Each session's status, in its output folder."""
INDEX_FILE = "batch.json"
"""The batch's index: every session's status."""
STATES = ("pending", "running", "done", "partial", "failed")
"""A session's states: ``partial``: targets estimated but a step failed (``process`` exits 3)."""


def read_status(folder: Path) -> dict | None:
    """The status in ``folder/STATUS_FILE``, or None (no file, or one that is not a status)."""
    p = Path(folder) / STATUS_FILE
    try:
        st = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        log.warning("%s is unreadable (%s); its session is done again", p, exc)
        return None
    ok = isinstance(st, dict) and st.get("state") in STATES and isinstance(st.get("session"), str)
    return st if ok else None


def write_status(folder: Path, status: dict) -> None:
    """Write a session's status (a dict with ``name``, ``session``, ``state``, ``reason``,
    ``fingerprint``, ...) into its output folder, atomically."""
    write_json(Path(folder) / STATUS_FILE, status)


def earlier_statuses(out: Path) -> dict:
    """{resolved session path: status} of the sessions an earlier batch wrote into ``out``."""
    found = {}
    if out.is_dir():
        for d in sorted(out.iterdir()):
            st = read_status(d) if d.is_dir() else None
            if st is not None and st.get("name") == d.name:
                found[Path(st["session"])] = st
    return found


def write_index(out: Path, statuses: dict, settings: dict) -> None:
    """``OUT/batch.json``: the settings, the counts per state and every session's status."""
    counts = Counter(s["state"] for s in statuses.values())
    write_json(Path(out) / INDEX_FILE, {"version": 1, "updated": time.time(), "settings": settings,
                                        "counts": {k: counts.get(k, 0) for k in STATES},
                                        "sessions": list(statuses.values())})


# --- the per-session lock ------------------------------------------------------------------------

LOCK_FILE = ".batch_lock"
"""In a session's output folder while a worker processes it: ``HOST:PID:START`` of that worker
(START: the process's start time, so that a pid used again is not taken for the owner)."""


def process_start(pid: int) -> str | None:
    """A running process's start time (clock ticks since boot, Linux /proc; elsewhere "?" while
    it exists), or None: no such process (or a zombie)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return None if fields[0] == "Z" else fields[19]
    except FileNotFoundError:
        return None
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass
        return "?"


def this_process() -> str:
    """``HOST:PID:START`` of this process."""
    return f"{socket.gethostname()}:{os.getpid()}:{process_start(os.getpid())}"


def is_alive(owner: str) -> bool:
    """The process ``HOST:PID:START`` runs: on this host, that pid with that start time. A lock
    of another host (a Dask worker) cannot be checked from here and is not honoured: the
    scheduler runs a session once, and reassigns it only when its worker is lost."""
    host, _, rest = owner.partition(":")
    pid, _, start = rest.partition(":")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    now = process_start(int(pid))
    return now is not None and (now == start or "?" in (now, start))


def lock_owner(folder: Path) -> str | None:
    """The live owner of ``folder``'s lock, or None (no lock, or a stale one: its owner is dead)."""
    try:
        owner = (Path(folder) / LOCK_FILE).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return owner if is_alive(owner) else None


def take_lock(folder: Path) -> str | None:
    """Take ``folder``'s lock for this process: None when taken (a stale lock is replaced), else
    the live owner's ``HOST:PID:START``."""
    path = Path(folder) / LOCK_FILE
    me = this_process()
    for _ in range(3):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = lock_owner(folder)
            if owner is not None:
                return owner
            with contextlib.suppress(FileNotFoundError):
                path.unlink()                            # stale: its owner is dead
            continue
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(me)
        return None
    return lock_owner(folder) or "another process"


def release_lock(folder: Path) -> None:
    """Remove ``folder``'s lock if this process holds it."""
    path = Path(folder) / LOCK_FILE
    with contextlib.suppress(OSError, UnicodeDecodeError):
        if path.read_text(encoding="utf-8").strip() == this_process():
            path.unlink()
