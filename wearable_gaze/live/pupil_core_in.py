"""Pupil Core input for the live session (``live --device pupil-core://HOST:PORT``, docs/live.md,
"Pupil Core"): Pupil Capture's network API read with pyzmq.

``PupilCoreLink`` talks to Pupil Remote (REQ): the backbone's ``SUB_PORT``, the clock (``t``
round trips: the offset of the one with the least round-trip delay) and the Frame Publisher's
start (a ``start_plugin`` notification, BGR frames). Two threads then subscribe: ``GazeReader``
(``gaze.3d.``: per-eye rays, the serial ``EyeReader``'s interface) and ``WorldFrames``
(``frame.world``: the camera ``FrameSource``'s interface), so that the live loop runs unchanged.

Clock: a message's Pupil time ``t`` is the device's sample time; ``t + offset`` is that moment on
``time.monotonic()``; the session time is that minus ``t0``, the local time the session opened.
Latency is measured from ``t + offset`` (the device's own sample time), not from arrival.

Faults: a message that does not parse is counted (``corrupt``) and skipped, one log line per run
of them; a device silent for ``STALL_S`` (stopped, disconnected, restarted on new ports) makes
the reader ask Pupil Remote again (a new handshake, counted in ``reconnects``) until it answers;
everything received before and after is kept.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlparse

import numpy as np
import zmq

from calibration.images import to_gray

from ..errors import UserError
from ..formats.devices.pupil_net import (
    DEFAULT_PORT,
    FRAME_TOPIC,
    GAZE_TOPIC,
    BadMessage,
    parse_frame,
    parse_gaze,
    start_frame_publisher,
)
from .camera_in import CameraStats, put_newest
from .input_thread import InputThread, hand_on_gaze
from .serial_in import SerialStats
from .stats import LatencyHistogram

log = logging.getLogger(__name__)

STALL_S = 1.0            # a device silent this long is reconnected
RETRY_S = 0.25           # then Pupil Remote is asked again this often until it answers
REQUEST_TIMEOUT_S = 0.5  # a Pupil Remote request unanswered this long has failed
SYNC_ROUND_TRIPS = 20
CLOCK_AHEAD_S = 0.05     # a message stamped this far in the local future, or ...
CLOCK_BEHIND_S = 5.0     # ... this far in the past (beyond any transport delay): the device's clock was set
RESYNC_EVERY_S = 1.0     # at most one clock sync a second for that


class DeviceUnreachable(ConnectionError):
    """Pupil Remote did not answer (the message says what was asked)."""


def parse_device_url(url: str) -> tuple[str, int, str]:
    """``pupil-core://HOST[:PORT][?frames=bgr|jpeg]`` -> (host, port, frame format); the port
    defaults to Capture's 50020, the frames to raw BGR (JPEG: a tenth of the bytes, for a slow
    network, at the cost of decoding them here).

    Raises:
        UserError: another scheme, no host, a bad port, another query.
    """
    u = urlparse(url)
    try:
        port = u.port or DEFAULT_PORT
    except ValueError:
        port = None
    query = dict(parse_qsl(u.query, keep_blank_values=True))
    fmt = query.pop("frames", "bgr")
    if u.scheme != "pupil-core" or not u.hostname or port is None or query or fmt not in ("bgr", "jpeg"):
        raise UserError(f"--device {url}: expected pupil-core://HOST:PORT (Pupil Remote's address, shown in "
                        f"Capture's Pupil Remote menu; port {DEFAULT_PORT} by default), optionally ?frames=jpeg")
    return u.hostname, port, fmt


@dataclass
class ClockSync:
    """``local = pupil + offset_s``, from the round trip of least delay ``rtt_s``."""

    offset_s: float
    rtt_s: float


class PupilCoreLink:
    """Pupil Remote and what it gives: the SUB address, the clock offset, the Frame Publisher
    started; shared by the two readers. ``handshake`` runs again after a stall (``reconnect``),
    at most once per stall (``generation`` counts the handshakes done).

    Args:
        host, port: Pupil Remote's address; frame_format: the Frame Publisher's ('bgr', 'jpeg').
    """

    def __init__(self, host: str, port: int, frame_format: str = "bgr"):
        self.host, self.port, self.frame_format = host, port, frame_format
        self.ctx = zmq.Context()
        self.lock = threading.RLock()
        self.req = None
        self.sub_url: str | None = None
        self.sync: ClockSync | None = None
        self.generation = 0
        self.t0 = time.monotonic()        # the session clock's origin
        self.resyncs = 0                  # clock syncs after a jump of the device's clock
        self._last_resync = -np.inf

    @property
    def where(self) -> str:
        return f"pupil-core://{self.host}:{self.port}"

    def request(self, parts: list[bytes]) -> str:
        """One request, its answer (a REQ socket that timed out is replaced: ZMQ's lazy pirate).

        Raises:
            DeviceUnreachable: no answer within ``REQUEST_TIMEOUT_S``.
        """
        if self.req is None:
            self.req = self.ctx.socket(zmq.REQ)
            self.req.setsockopt(zmq.LINGER, 0)
            self.req.connect(f"tcp://{self.host}:{self.port}")
        self.req.send_multipart(parts)
        if self.req.poll(int(REQUEST_TIMEOUT_S * 1000)):
            return self.req.recv_string()
        self.req.close()
        self.req = None
        raise DeviceUnreachable(f"Pupil Remote at {self.host}:{self.port} did not answer {parts[0][:20]!r}")

    def time_sync(self, n: int = SYNC_ROUND_TRIPS) -> ClockSync:
        """``n`` ``t`` round trips; the offset of the fastest (its error is at most half its delay)."""
        best = None
        for _ in range(n):
            a = time.monotonic()
            answer = self.request([b"t"])
            b = time.monotonic()
            try:
                t_pupil = float(answer)
            except ValueError:
                raise DeviceUnreachable(f"Pupil Remote answered 't' with {answer[:40]!r}, not a time") from None
            if best is None or b - a < best.rtt_s:
                best = ClockSync(0.5 * (a + b) - t_pupil, b - a)
        return best

    def handshake(self) -> None:
        """Ask for the SUB port, sync the clock, start the Frame Publisher (``frame_format``).

        Raises:
            DeviceUnreachable: Pupil Remote did not answer, or answered nonsense.
        """
        with self.lock:
            sub_port = self.request([b"SUB_PORT"])
            if not sub_port.isdigit():
                raise DeviceUnreachable(f"Pupil Remote answered SUB_PORT with {sub_port[:40]!r}, not a port")
            sync = self.time_sync()
            self.request(start_frame_publisher(self.frame_format))
            self.sub_url, self.sync = f"tcp://{self.host}:{sub_port}", sync
            self.generation += 1

    def reconnect(self, generation: int) -> bool:
        """A new handshake unless one has been done since ``generation``; False while Pupil
        Remote does not answer."""
        with self.lock:
            if self.generation != generation:
                return True
            try:
                self.handshake()
                return True
            except DeviceUnreachable:
                return False

    def resync(self) -> bool:
        """Sync the clock again (the device's clock was set: Pupil Remote's ``T``, or another
        program's time sync), at most once every ``RESYNC_EVERY_S``; False if not done."""
        with self.lock:
            if time.monotonic() - self._last_resync < RESYNC_EVERY_S:
                return False
            self._last_resync = time.monotonic()
            try:
                sync = self.time_sync()
            except DeviceUnreachable:
                return False
            jump = self.sync.offset_s - sync.offset_s
            self.sync = sync
            if abs(jump) < CLOCK_AHEAD_S:          # no jump: the messages were late (a reader behind)
                return False
            log.warning("%s: Pupil time jumped by %+.3f s (the device's clock was set); clock synced again",
                        self.where, jump)
            self.resyncs += 1
            return True

    def local_time(self, t_pupil: float) -> float:
        """``time.monotonic()`` at Pupil time ``t_pupil``, s."""
        return t_pupil + self.sync.offset_s

    def close(self) -> None:
        with self.lock:
            if self.req is not None:
                self.req.close()
                self.req = None
        self.ctx.destroy(linger=0)          # the readers' sockets too, should one not have ended


class _Subscriber(InputThread):
    """A thread reading one topic from the link's SUB port: a new subscription after each
    handshake, a reconnect after ``STALL_S`` without a message, one log line per run of bad
    messages."""

    topic = ""

    def __init__(self, link: PupilCoreLink, name: str, maxsize: int):
        super().__init__(name)
        self.link = link
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.connected = threading.Event()
        self.error: str | None = None
        self.port = link.where
        self._bad_run = False
        self.last_t = -np.inf

    def _run(self) -> None:
        sub, gen, last = None, -1, time.monotonic()
        outage_said = False
        try:
            while not self.stop_event.is_set():
                if gen != self.link.generation:
                    if sub is not None:              # a new handshake (this reader's or the other's)
                        sub.close()
                        self._reconnected()
                    sub, gen = self._subscribe(), self.link.generation
                    last = time.monotonic()
                    self.connected.set()
                if sub.poll(50):
                    parts = sub.recv_multipart()
                    last = time.monotonic()
                    outage_said = False
                    self._message(parts)
                elif time.monotonic() - last > STALL_S:
                    if not outage_said:
                        log.warning("%s: no %s for %.1f s; reconnecting", self.port, self.topic, STALL_S)
                        outage_said = True
                    if self.link.reconnect(gen):
                        last = time.monotonic()
                    else:
                        last = time.monotonic() - STALL_S + RETRY_S
            while sub is not None and sub.poll(0):   # the session ends: what has arrived is taken (recorded)
                self._message(sub.recv_multipart())
        finally:
            if sub is not None:
                sub.close()

    def _subscribe(self):
        sub = self.link.ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.LINGER, 0)
        sub.setsockopt(zmq.RCVHWM, 10000)
        sub.connect(self.link.sub_url)
        sub.setsockopt(zmq.SUBSCRIBE, self.topic.encode())
        return sub

    def _reconnected(self) -> None:
        self.stats.reconnects += 1

    def _message(self, parts: list[bytes]) -> None:
        try:
            self._handle(parts)
            self._bad_run = False
        except BadMessage as exc:
            self._corrupt()
            if not self._bad_run:
                topic = parts[0][:40].decode("ascii", "replace") if parts else ""
                log.warning("%s: a bad %s message skipped (%s); the following bad ones are counted only",
                            self.port, topic, exc)
                self._bad_run = True

    def _session_time(self, t_pupil: float) -> tuple[float, float]:
        """(local time, session time) of a message stamped ``t_pupil``; a stamp in the local
        future or far in the past means the device's clock was set: the clock is synced again
        (``PupilCoreLink.resync``). Session times are kept increasing (a re-synced clock may step
        back by its error; messages in flight across a jump are stamped just after the last)."""
        local = self.link.local_time(t_pupil)
        now = time.monotonic()
        if not now - CLOCK_BEHIND_S <= local <= now + CLOCK_AHEAD_S and self.link.resync():
            local = self.link.local_time(t_pupil)
        t_s = max(local - self.link.t0, self.last_t + 1e-6)
        self.last_t = t_s
        return local, t_s


class GazeReader(_Subscriber):
    """Pupil Core's 3D gaze as the live loop's eye reader: ``(sample_local_s, t_s, RaySample)``
    on ``queue``; ``on_record(t_s, record)`` sees every intact sample first, in
    this thread (the recorder)."""

    topic = GAZE_TOPIC

    def __init__(self, link: PupilCoreLink, on_record=None, maxsize: int = 2000):
        super().__init__(link, "pupil-core-gaze", maxsize)
        self.stats = SerialStats()
        self.on_record = on_record
        self.transport = LatencyHistogram()   # device sample time -> received here, ms

    def _corrupt(self) -> None:
        self.stats.corrupt += 1

    def _handle(self, parts: list[bytes]) -> None:
        if len(parts) < 2:
            raise BadMessage(f"{len(parts)} part(s), not topic and payload")
        rec = parse_gaze(parts[0].decode("ascii", "replace"), parts[1], self.stats.records)
        local, t_s = self._session_time(rec.t)
        hand_on_gaze(self, local, t_s, rec)


class WorldFrames(_Subscriber):
    """The Frame Publisher's scene frames as the live loop's camera: ``(local_s, index, grey,
    colour)`` on ``queue`` (the oldest goes when it is full: ``skipped``); ``sink(t_s, index,
    grey)`` sees every frame (the recorder). ``size``, ``fps`` are the stream's, measured by
    ``probe`` before the session starts."""

    topic = FRAME_TOPIC

    def __init__(self, link: PupilCoreLink, size, fps: float, maxsize: int = 4):
        super().__init__(link, "pupil-core-frames", maxsize)
        self.stats = CameraStats()
        self.size, self.fps = tuple(size), fps
        self.t0 = link.t0
        self.finished = threading.Event()     # a device does not end; the session does
        self.sink = None
        self.n = 0
        self.last_index: int | None = None

    def _corrupt(self) -> None:
        self.stats.missed += 1                # a frame that came malformed is one not delivered

    def _reconnected(self) -> None:
        self.stats.stalls += 1

    def _handle(self, parts: list[bytes]) -> None:
        fr = parse_frame(parts)
        if (fr.image.shape[1], fr.image.shape[0]) != self.size:
            raise BadMessage(f"a {fr.image.shape[1]}x{fr.image.shape[0]} frame in a {self.size[0]}x{self.size[1]} "
                             "stream")
        if self.last_index is not None and 1 < fr.index - self.last_index < 1000:
            self.stats.missed += fr.index - self.last_index - 1
        self.last_index = fr.index
        local, t_s = self._session_time(fr.t)
        color = fr.image if fr.image.ndim == 3 else None
        gray = to_gray(fr.image) if color is not None else fr.image
        if self.sink is not None:
            self.sink(t_s, self.n, gray)
        item = (local, self.n, gray, color)
        self.n += 1
        self.stats.frames += 1
        self.stats.skipped += put_newest(self.queue, item)


def probe_frames(link: PupilCoreLink, n: int = 6, timeout_s: float = 3.0) -> tuple[tuple[int, int], float]:
    """The scene stream's (width, height) px and rate, Hz, from its first ``n`` frames.

    Raises:
        UserError: no frame within ``timeout_s`` (the Frame Publisher is not running), or only
            malformed ones.
    """
    sub = link.ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(link.sub_url)
    sub.setsockopt(zmq.SUBSCRIBE, FRAME_TOPIC.encode())
    times, size, why = [], None, "none arrived"
    end = time.monotonic() + timeout_s
    try:
        while len(times) < n and (left := end - time.monotonic()) > 0:
            if not sub.poll(int(left * 1000) + 1):
                break
            try:
                fr = parse_frame(sub.recv_multipart())
            except BadMessage as exc:
                why = str(exc)
                continue
            size = (fr.image.shape[1], fr.image.shape[0])
            times.append(fr.t)
    finally:
        sub.close()
    if size is None:
        raise UserError(f"--device {link.where}: no scene frame within {timeout_s:g} s ({why}); enable the Frame "
                        "Publisher plugin in Pupil Capture (format BGR or JPEG) and check the world camera")
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 30.0
    return size, float(fps)


def open_link(url: str) -> PupilCoreLink:
    """Connect to Pupil Remote at ``url`` (the first handshake).

    Raises:
        UserError: a bad URL, or Pupil Remote does not answer.
    """
    link = PupilCoreLink(*parse_device_url(url))
    try:
        link.handshake()
    except DeviceUnreachable as exc:
        link.close()
        raise UserError(f"--device {url}: {exc}; check that Pupil Capture runs with the Pupil Remote plugin on "
                        f"that address and that the network lets you reach it") from None
    return link
