"""The eye recorder's clock mapped onto the session clock (the scene camera's, docs/live.md)."""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)


class SessionClock:
    """Maps recorder times onto the session clock: the offset is the smallest arrival-minus-
    recorder time seen so far (the fastest transport path); mapped times are kept strictly
    increasing when the offset estimate improves.

    Args:
        t0: a callable giving the session clock's origin (``time.monotonic()`` of the first
            frame), or None while the camera has not started.
    """

    def __init__(self, t0):
        self.t0 = t0
        self.offset: float | None = None
        self.last_t = -1.0

    def map(self, arrival: float, t_rec: float) -> float:
        """Session time, s, of a record stamped ``t_rec`` (s, recorder clock) that arrived at
        ``arrival`` (``time.monotonic()``)."""
        t0 = self.t0()
        if t0 is None:
            t0 = arrival
        off = arrival - t0 - t_rec
        if self.offset is None or off < self.offset - 0.002:
            self.offset = off
        t_s = max(t_rec + self.offset, self.last_t + 1e-4)
        self.last_t = t_s
        return t_s
