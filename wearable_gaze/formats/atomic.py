"""Write files so that a reader never sees half a file: write a temporary sibling, then rename.

A writer that fails (an exception, ``KeyboardInterrupt``) leaves no temporary file and does not
touch the file under the final name. A writer that is killed (SIGKILL, power loss) cannot clean
up: its temporary sibling is named ``.NAME.XXXXXXXX.SUFFIX`` and ``remove_temporaries`` removes
such leftovers at the next run.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import UserError, check_output

log = logging.getLogger(__name__)


def _umask() -> int:
    """The process's umask, read without setting it where the system allows (setting it to read
    it, as ``os.umask`` does, would briefly change it for every thread, e.g. the live recorder's)."""
    try:
        for line in Path("/proc/self/status").read_text(encoding="ascii").splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    umask = os.umask(0)
    os.umask(umask)
    return umask


def _temp_prefix(path: Path) -> str:
    return f".{path.name}."


@contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it goes.

    ``suffix`` defaults to ``path``'s own (writers such as Open3D pick the format from it).
    Use it only in a ``with`` block: driving ``__exit__(None, None, None)`` by hand after an
    error would commit a partial file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path), suffix=suffix or path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())   # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def remove_temporaries(folder, names) -> list[Path]:
    """Remove the temporary siblings ``atomic_path`` made for ``folder/NAME`` (each of ``names``)
    and left behind when its writer was killed. Returns the removed paths.

    Only names of the exact pattern ``.NAME.<8 random characters>SUFFIX`` are removed, so a
    user's own file that merely starts with a dot is never touched.
    """
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    for name in names:
        p = Path(name)
        pattern = re.compile(re.escape(_temp_prefix(p)) + r"[a-z0-9_]{8}" + re.escape(p.suffix) + r"\Z")
        for q in folder.glob(glob_escape(_temp_prefix(p)) + "*"):
            if pattern.match(q.name) and q.is_file():
                with contextlib.suppress(FileNotFoundError):
                    q.unlink()
                removed.append(q)
                log.info("removed %s, left by a writer that was killed", q)
    return removed


def glob_escape(text: str) -> str:
    """``text`` with the glob metacharacters ``*?[`` taken literally."""
    return re.sub(r"([*?\[])", r"[\1]", text)


def check_new_folder(out_dir, option: str = "-o") -> Path:
    """Refuse an output folder that exists and is not empty (or any path ``check_output``
    refuses), before any work is done.

    Raises:
        UserError: naming the folder and the fix.
    """
    out_dir = check_output(out_dir, (), option, folder=True)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise UserError(f"{out_dir}: already exists and is not empty; choose a new {option} folder")
    return out_dir


@contextmanager
def atomic_folder(out_dir, option: str = "-o"):
    """Yield a temporary folder beside ``out_dir`` to build a folder in; on success it becomes
    ``out_dir``, on error it goes, so a failure leaves nothing half-written and nothing of the
    user's is touched.

    Raises:
        UserError: ``out_dir`` exists and is not an empty folder.
    """
    out_dir = check_new_folder(out_dir, option)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        yield tmp
        if out_dir.exists():
            out_dir.rmdir()
        os.chmod(tmp, 0o777 & ~_umask())                  # mkdtemp makes 0700
        tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise

