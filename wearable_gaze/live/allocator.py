"""The C allocator between live sessions run one after another in one process (issue 29).

A session's memory is freed when it ends (its threads joined, no Python object of it kept), but
glibc's malloc keeps the freed pages: its heap only shrinks from the top, its mmap threshold
rises to the largest block freed (up to 32 MB), so a session's growing buffers (arrays of the
fixation's samples, frames, encoder buffers) go onto the heap, and each session's heap ends a
few MB higher than the last, in pages it holds but does not use (the Python objects and the
bytes in use stay flat: tracemalloc and ``mallinfo2``); and each of a session's threads may get
an arena of its own, which the next session's threads fragment further. ``bound_heap`` fixes the
threshold at ``MMAP_THRESHOLD_BYTES``, so a large block goes back to the system when freed, and
keeps every thread on one arena (``ARENAS``); ``release_free_memory`` hands the free pages back at
a session's start and end (``malloc_trim``). Both do nothing outside glibc."""

from __future__ import annotations

import ctypes
import logging

log = logging.getLogger(__name__)

MMAP_THRESHOLD_BYTES = 64 * 1024
"""Blocks of at least this many bytes are mapped on their own, not carved from the heap."""
ARENAS = 1
"""The most malloc arenas (the session's threads hold the GIL for their Python work anyway)."""
_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8          # mallopt's parameter numbers (malloc.h)


def _libc():
    try:
        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, "malloc_trim") and hasattr(libc, "mallopt") else None
    except OSError:             # pragma: no cover  (no C library to load: not Linux)
        return None


def bound_heap() -> bool:
    """Fix glibc's mmap threshold at ``MMAP_THRESHOLD_BYTES`` and its arenas at ``ARENAS`` (for
    the whole process: call it before the session's threads start); False where there is no glibc."""
    libc = _libc()
    return bool(libc is not None and libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and libc.mallopt(_M_ARENA_MAX, ARENAS))


def release_free_memory() -> bool:
    """Hand the C allocator's free pages back to the system (glibc ``malloc_trim(0)``: in every
    arena, not only at the heap's top); False where there is no glibc, or nothing was freed."""
    libc = _libc()
    return bool(libc is not None and libc.malloc_trim(0))
