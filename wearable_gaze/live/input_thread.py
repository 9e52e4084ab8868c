"""The base of the live session's input threads (the eye reader, the camera): an unexpected error
ends the thread and is kept in ``failure`` for the loop to report and end the session with."""

from __future__ import annotations

import logging
import queue
import threading
import time

from .sched import GAZE_SLICE_S, set_thread_slice

log = logging.getLogger(__name__)


class InputThread(threading.Thread):
    """A daemon thread running ``_run`` until ``stop``; an exception ends it with ``failure`` set to
    ``"ExceptionType: message"`` (the traceback is logged at debug level).

    Args:
        name: the thread's name, also used in the log line.
    """

    def __init__(self, name: str):
        super().__init__(daemon=True, name=name)
        self.failure: str | None = None          # an unexpected error that ended the thread
        self.stop_event = threading.Event()      # set by ``stop``; ``_run`` returns soon after

    def stop(self) -> None:
        self.stop_event.set()

    def run(self):
        set_thread_slice(GAZE_SLICE_S)           # taken as soon as data arrive (sched.py)
        try:
            self._run()
        except Exception as exc:  # the live loop reports it and ends the session
            self.failure = f"{type(exc).__name__}: {exc}"
            log.debug("%s failed", self.name, exc_info=True)

    def _run(self) -> None:
        raise NotImplementedError


def hand_on_gaze(reader, local: float, t_s: float, rec) -> None:
    """A network device's gaze sample ``rec`` (sample time ``local``, ``time.monotonic()`` s;
    session time ``t_s``, s) handed on by its reader (Pupil Core's, Neon's): its transport delay
    into ``reader.transport`` (ms), counted, recorded first (``reader.on_record``), then queued
    for the loop; a full queue drops it (counted), the recording keeps it."""
    reader.transport.add(max(time.monotonic() - local, 0.0) * 1000)
    reader.stats.records += 1
    if reader.on_record is not None:
        reader.on_record(t_s, rec)
    try:
        reader.queue.put_nowait((local, t_s, rec))
    except queue.Full:
        reader.stats.dropped += 1
