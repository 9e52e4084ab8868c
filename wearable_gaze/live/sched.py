"""The gaze path's threads asked for short time slices (docs/live.md, Latency).

Linux's scheduler (EEVDF, 6.6 and later) gives each task a time slice (1.4 ms by default on the
2-core development machine) and, since 6.12, lets a task ask for a shorter one
(``sched_setattr``'s ``sched_runtime`` for a normal task): a waking task whose slice is shorter
than the running one's preempts it (``PREEMPT_SHORT``) instead of waiting for it to use up its
own. The eye reader and the loop sleep between samples and then need well under a millisecond:
with short slices a sample that arrives while the tracking process, the video encoder or another
program computes on the same core is taken at once. Their share of the CPU is unchanged (the
slice is not a priority: the weight stays that of the thread's niceness).

Where the call does not exist (another system, an older kernel) or is refused, nothing changes.
"""

from __future__ import annotations

import ctypes
import logging
import os
import struct
import sys

log = logging.getLogger(__name__)

GAZE_SLICE_S = 0.0003
"""The slice the gaze path's threads ask for, s (the kernel takes 0.1-100 ms)."""
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}
_SYS_SCHED_GETATTR = {"x86_64": 315, "aarch64": 275}
_ATTR = struct.Struct("IIQiIQQQII")        # struct sched_attr (its first version's 56 bytes)


def _syscall(table: dict, *args) -> bool:
    if not sys.platform.startswith("linux") or os.uname().machine not in table:
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    return libc.syscall(table[os.uname().machine], *args) == 0


def thread_slice_s() -> float | None:
    """The calling thread's time slice, s (None where it cannot be read)."""
    buf = ctypes.create_string_buffer(_ATTR.size)
    if not _syscall(_SYS_SCHED_GETATTR, 0, buf, _ATTR.size, 0):
        return None
    fields = _ATTR.unpack(buf.raw)
    return fields[5] / 1e9 if fields[1] == 0 else None          # a normal task's slice (0: the default)


def set_thread_slice(slice_s: float | None) -> bool:
    """Ask for a time slice of ``slice_s`` (s; None or 0: the kernel's default) for the calling
    thread, a normal (``SCHED_OTHER``) one; its niceness is kept. True when the kernel took it."""
    buf = ctypes.create_string_buffer(_ATTR.size)
    if not _syscall(_SYS_SCHED_GETATTR, 0, buf, _ATTR.size, 0):
        return False
    fields = _ATTR.unpack(buf.raw)
    if fields[1] != 0:                     # not a normal task (real-time, batch, idle): leave it
        return False
    attr = _ATTR.pack(_ATTR.size, 0, 0, fields[3], 0, int((slice_s or 0.0) * 1e9), 0, 0, 0, 0)
    ok = _syscall(_SYS_SCHED_SETATTR, 0, ctypes.c_char_p(attr), 0)
    if not ok:
        log.debug("sched_setattr refused a %.2f ms slice (errno %d)", (slice_s or 0) * 1e3, ctypes.get_errno())
    return ok
