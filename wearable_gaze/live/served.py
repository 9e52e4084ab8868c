"""A live session's helper process served over a pipe (``track_process``: head tracking;
``target_process``: targets): a fresh interpreter (spawned, so that no thread of the session's is
copied), its niceness raised above the session's, that sends "ready" once set up."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

START_TIMEOUT_S = 60.0     # the process's imports on a loaded machine
NOT_STARTED = ("the {} process did not start (a script that opens a live session must do so under "
               "'if __name__ == \"__main__\":')")
"""The error of a process that did not start, with its name."""


def renice(nice: int) -> None:
    """In the helper process: its niceness ``nice`` above the session's (kept where refused)."""
    try:
        os.nice(nice)
    except OSError:                                  # pragma: no cover (not allowed: the same priority)
        pass


def start(serve: Callable, args: tuple, name: str) -> tuple[BaseProcess, Connection]:
    """Start ``serve(conn, *args)`` in a process named ``name``; its process and this end of the
    pipe."""
    ctx = multiprocessing.get_context("spawn")
    conn, child = ctx.Pipe()
    proc = ctx.Process(target=serve, args=(child, *args), daemon=True, name=name)
    proc.start()
    child.close()
    return proc, conn


def ready(conn: Connection) -> bool:
    """Whether the process at the other end of ``conn`` said "ready" within ``START_TIMEOUT_S``."""
    try:
        return bool(conn.poll(START_TIMEOUT_S)) and conn.recv() == "ready"
    except EOFError:                   # it ended: e.g. a main module that starts a session unguarded
        return False
