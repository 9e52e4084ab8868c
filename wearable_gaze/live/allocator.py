"""The C allocator between live sessions run one after another in one process (issue 29).

A session's memory is freed when it ends (its threads joined, no Python object of it kept), but
glibc's malloc keeps the freed pages: its heap only shrinks from the top, its mmap threshold
rises to the largest block freed (up to 32 MB), so a session's growing buffers (arrays of the
fixation's samples, frames, encoder buffers) go onto the heap, and each session's heap ends a
few MB higher than the last, in pages it holds but does not use (the Python objects and the
bytes in use stay flat: tracemalloc and ``mallinfo2``). ``bound_heap`` fixes the threshold at
``MMAP_THRESHOLD_BYTES``, so a large block goes back to the system when freed;
``release_free_memory`` hands the free pages back at a session's end (``malloc_trim``). Both do
nothing outside glibc."""

from __future__ import annotations

import ctypes
import logging

log = logging.getLogger(__name__)

MMAP_THRESHOLD_BYTES = 256 * 1024
"""Blocks of at least this many bytes are mapped on their own, not carved from the heap (glibc's
starting value, kept fixed)."""
_M_MMAP_THRESHOLD = -3          # mallopt's parameter number (malloc.h)


def _libc():
    try:
        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, "malloc_trim") and hasattr(libc, "mallopt") else None
    except OSError:             # pragma: no cover  (no C library to load: not Linux)
        return None


def bound_heap() -> bool:
    """Fix glibc's mmap threshold at ``MMAP_THRESHOLD_BYTES`` (for the whole process); False
    where there is no glibc."""
    libc = _libc()
    return bool(libc is not None and libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


def release_free_memory() -> bool:
    """Hand the C allocator's free pages back to the system (glibc ``malloc_trim(0)``: in every
    arena, not only at the heap's top); False where there is no glibc, or nothing was freed."""
    libc = _libc()
    return bool(libc is not None and libc.malloc_trim(0))
