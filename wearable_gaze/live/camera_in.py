"""Scene-camera input: ``cv2.VideoCapture`` by index, device path, URL or file (a file replays at
its own frame rate), timestamped on arrival; frames the consumer had no room for, frames a device
missed and stalls are counted, each event once."""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2

from calibration.images import to_gray

from .input_thread import InputThread

log = logging.getLogger(__name__)


def put_newest(q: queue.Queue, item) -> int:
    """Put ``item`` on the frame queue ``q``; when it is full the oldest frame goes (the loop
    wants the newest). Returns how many frames were skipped for it (0 or 1). The one producer's
    put cannot fail after the get, as only it puts."""
    skipped = 0
    try:
        q.put_nowait(item)
    except queue.Full:
        try:
            q.get_nowait()
            skipped = 1
        except queue.Empty:
            pass
        q.put_nowait(item)
    return skipped


@dataclass
class CameraStats:
    frames: int = 0
    skipped: int = 0          # frames the consumer had no room for (the oldest waiting one goes; still recorded)
    missed: int = 0           # frames a device did not deliver: gaps of 1.5 to 5 frame periods
    stalls: int = 0           # waits longer than 5 frame periods, or a run of failed reads: one each


class FrameSource(InputThread):
    """Puts ``(t_s, frame_index, grey_frame, colour_frame)`` on a bounded queue; ``t_s`` is
    ``time.monotonic()`` at capture (a file: its start time plus index / fps).

    Args:
        source: a camera index ('0'), a device path, a URL or a video file.
        maxsize: queue length; when full, the oldest frame is dropped (counted as ``skipped``).
    """

    def __init__(self, source: str, maxsize: int = 4, sink=None, loop: bool = False):
        super().__init__("camera")
        self.source = source
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.stats = CameraStats()
        self.error: str | None = None
        self.finished = threading.Event()
        target = int(source) if str(source).isdigit() else str(source)
        self.cap = cv2.VideoCapture(target)
        if not self.cap.isOpened():
            raise OSError(f"camera {source!r} will not open (check the index, path or URL)")
        self.is_file = not str(source).isdigit() and Path(str(source)).is_file()
        self.fps = self.cap.get(cv2.CAP_PROP_FPS) or 30.0
        self.size = (int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        self.t0: float | None = None
        self.sink = sink            # sink(t_rel_s, index, grey) sees every frame (the recorder)
        self.loop = loop            # a file starts again at its end (long-run benchmarks)

    def _run(self):
        period = 1.0 / self.fps
        self.t0 = time.monotonic()
        last = self.t0
        i = 0
        failing = False
        try:
            while not self.stop_event.is_set():
                if self.is_file:
                    due = self.t0 + i * period
                    wait = due - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                ok, frame = self.cap.read()
                now = time.monotonic()
                if not ok:
                    if self.is_file and self.loop and i > 0:
                        self.cap.release()
                        self.cap = cv2.VideoCapture(str(self.source))
                        continue
                    if self.is_file:
                        break
                    if not failing:                  # a run of failed reads is one stall
                        self.stats.stalls += 1
                    failing = True
                    time.sleep(period)
                    continue
                t = self.t0 + i * period if self.is_file else now
                if now - last > 5 * period:
                    if not failing:
                        self.stats.stalls += 1       # a stall, not a run of missed frames
                elif not self.is_file and now - last > 1.5 * period:
                    self.stats.missed += int(round((now - last) / period)) - 1
                failing = False
                last = now
                gray = to_gray(frame)
                if self.sink is not None:
                    self.sink(t - self.t0, i, gray)
                item = (t, i, gray, frame)
                self.stats.skipped += put_newest(self.queue, item)
                self.stats.frames += 1
                i += 1
        finally:
            self.cap.release()
            self.finished.set()

