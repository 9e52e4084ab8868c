"""Errors a user can fix. The CLI prints their message as one line and exits with status 2."""

from __future__ import annotations

import os
from pathlib import Path


class UserError(Exception):
    """Bad input at a boundary (a file, an option, a device): the message says what is wrong and
    how to fix it."""


def one_line(text: object, limit: int | None = None) -> str:
    """``text`` (any object, as ``str``) as one printable line: whitespace runs become one space,
    control characters (a terminal escape in a file name or a header) are shown escaped; cut to
    ``limit`` characters, the last three ``...``, when given. The one home of the one-line
    messages: the CLI's errors and batch's status reasons."""
    text = " ".join(str(text).split())
    text = "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)
    return text if limit is None or len(text) <= limit else text[:limit - 3] + "..."


def same_file(a, b) -> bool:
    """Whether two paths name one file: ``os.path.samefile`` when both exist, else their resolved
    paths compared."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):
        return False


def check_output(out, inputs=(), option: str = "-o", folder: bool = False) -> Path:
    """Refuse an output path before any work is done: one of the inputs, a folder where a file is
    wanted (or a file where a folder is wanted, ``folder=True``), a parent that is a file, or a
    folder that cannot be written.

    Raises:
        UserError: naming the path and the fix.
    """
    out = Path(out)
    for src in inputs:
        if src is not None and same_file(out, src):
            raise UserError(f"{option} {out} is also an input ({src}); writing it would destroy the input: "
                            "choose another output name")
    if folder:
        if out.exists() and not out.is_dir():
            raise UserError(f"{option} {out}: is a file, but a folder is wanted; choose a new folder name")
    elif out.is_dir():
        raise UserError(f"{option} {out}: is a folder; give a file name, e.g. {out / 'out'}{out.suffix or ''}")
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise UserError(f"{option} {out}: {parent} is a file, not a folder; choose an output path in a folder")
    if parent.is_dir() and not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{option} {out}: the folder {parent} is not writable; choose a writable place or "
                        "change its permissions")
    return out
