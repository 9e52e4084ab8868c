"""The status files of ``wearable-gaze batch`` (docs/batch.md, docs/formats.md): each session's
status in its output folder (``OUT/NAME/batch_status.json``: name, session, state, reason,
fingerprint, times, the worker and its memory) and the batch's index (``OUT/batch.json``:
settings, counts per state, every status). One reader (``read_status``, ``earlier_statuses``)
and one writer (``write_status``, ``write_index``), atomic.
"""

from __future__ import annotations

import json
import logging
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
