"""Pupil Neon input for the live session (``live --device neon://HOST[:PORT]``, docs/live.md, "Neon"):
the Companion app's real-time API read with Pupil Labs' own client, ``pupil-labs-realtime-api``
(the optional extra ``wearable-gaze[neon]``), unmodified.

The client calls made: ``Device(host, port)`` + ``get_status()`` (the phone, its ``time_echo_port``
and the DIRECT gaze and world sensors' RTSP URLs: ``Status.direct_gaze_sensor().url``,
``direct_world_sensor().url``); ``TimeOffsetEstimator(host, time_echo_port).estimate()`` (the
clock offset); ``receive_gaze_data(url)`` (``EyestateGazeData`` and the kinds with eyelids: eye
states; ``GazeData``: the 2D point only) and ``receive_video_frames(url)`` (decoded H.264 frames),
each in its own thread with its own asyncio loop, with the serial reader's and the camera's
interfaces (``GazeReader``, ``WorldFrames``), so that the live loop runs unchanged.

Clock: a datum's ``timestamp_unix_seconds`` is the phone's sample time (its RTP time mapped by the
RTCP sender reports onto the phone's clock). The Time Echo estimate ``offset_ms`` (client minus
phone, the mean of ``SYNC_ECHOES`` round trips) maps it to the local Unix clock, and
``time.monotonic() - time.time()`` (taken at the sync) onto the monotonic clock the loop uses.
Latency is measured from that mapped sample time, not from arrival.

Faults: a stream silent for ``STALL_S``, or one whose connection ends or fails (the phone went away,
the app restarted, a payload the client cannot parse), gives one log line, then the status and the
clock are asked again every ``RETRY_S`` until the phone answers, and the stream is opened again
(``reconnects``); everything received before and after is kept.
"""

from __future__ import annotations

import asyncio
import logging
import queue
import threading
import time
from urllib.parse import urlparse

import numpy as np

from ..errors import UserError
from ..formats.devices.neon_rtp import DEFAULT_PORT, cyclopean_sample, eye_state_sample, has_eye_states
from .camera_in import CameraStats, put_newest
from .input_thread import InputThread, hand_on_gaze
from .serial_in import SerialStats
from .stats import LatencyHistogram

log = logging.getLogger(__name__)

STALL_S = 1.0             # a stream silent this long is opened again
RETRY_S = 0.25            # then the phone is asked again this often until it answers
REQUEST_TIMEOUT_S = 2.0   # the status and the clock sync must answer within this
SYNC_ECHOES = 20
DRAIN_QUIET_S = 0.1       # at the session's end, a stream behind is read on until it reaches the end's time,
DRAIN_MAX_S = 1.0         # is quiet this long, or this long has passed (everything sent before the end recorded)
TEARDOWN_S = 0.1          # a closed stream's RTSP TEARDOWN gets this long to be answered
CLIENT_LOG_LEVEL = logging.WARNING   # the client's RTSP reader (aiortsp) logs each connection step at INFO
EXTRA = "the [neon] extra (pip install 'wearable-gaze[neon]': Pupil Labs' pupil-labs-realtime-api) is not installed"


def client():
    """Pupil Labs' client modules (the extra), or a UserError saying how to install them."""
    try:
        from pupil_labs.realtime_api import Device, receive_gaze_data, receive_video_frames
        from pupil_labs.realtime_api.time_echo import TimeOffsetEstimator
    except ImportError:
        raise UserError(f"--device neon://: {EXTRA}") from None
    return Device, TimeOffsetEstimator, receive_gaze_data, receive_video_frames


def parse_neon_url(url: str) -> tuple[str, int]:
    """``neon://HOST[:PORT]`` -> (host, port); the port defaults to the Companion app's 8080.

    Raises:
        UserError: another scheme, no host, a bad port, a path or query.
    """
    u = urlparse(url)
    try:
        port = u.port or DEFAULT_PORT
    except ValueError:
        port = None
    if u.scheme != "neon" or not u.hostname or port is None or u.path not in ("", "/") or u.query:
        raise UserError(f"--device {url}: expected neon://HOST[:PORT] (the address the Companion app shows under "
                        f"Streaming; port {DEFAULT_PORT} by default)")
    return u.hostname, port


class NeonLink:
    """The phone's status and clock, shared by the two readers; ``connect`` runs again after a
    stall (``reconnect``), at most once per stall (``generation`` counts the connections).

    Attributes:
        urls: the gaze and world streams' RTSP URLs. offset_s: ``time.monotonic()`` minus phone
            time, s. rtt_ms: the Time Echo round trips' mean. t0: the session clock's origin.
        camera: the scene camera (the cyclopean ray of a datum without eye states).
    """

    def __init__(self, host: str, port: int, camera=None):
        self.host, self.port, self.camera = host, port, camera
        self.lock = threading.RLock()
        self.urls: dict[str, str] = {}
        self.offset_s: float | None = None
        self.rtt_ms: float | None = None
        self.generation = 0
        self.t0 = time.monotonic()

    @property
    def where(self) -> str:
        return f"neon://{self.host}:{self.port}"

    async def _connect(self):
        Device, TimeOffsetEstimator, _, _ = client()
        async with Device(self.host, self.port) as dev:
            status = await dev.get_status()
        urls = {"gaze": status.direct_gaze_sensor().url, "world": status.direct_world_sensor().url}
        if None in urls.values() or status.phone.time_echo_port is None:
            raise ConnectionError("the phone reports no connected gaze or scene stream, or no Time Echo port "
                                  "(is the Neon module plugged in?)")
        est = await TimeOffsetEstimator(self.host, status.phone.time_echo_port).estimate(SYNC_ECHOES)
        if est is None:
            raise ConnectionError("the Time Echo clock sync failed")
        mono_minus_wall = time.monotonic() - time.time()
        return urls, est.time_offset_ms.mean / 1000.0 + mono_minus_wall, est.roundtrip_duration_ms.mean

    def connect(self) -> None:
        """Ask for the status and sync the clock.

        Raises:
            ConnectionError: the phone did not answer in time, or lacks a stream.
        """
        with self.lock:
            try:
                urls, offset, rtt = asyncio.run(asyncio.wait_for(self._connect(), REQUEST_TIMEOUT_S))
            except (OSError, asyncio.TimeoutError) as exc:
                raise ConnectionError(f"{self.where} did not answer ({type(exc).__name__}: {exc})") from None
            except Exception as exc:
                raise ConnectionError(f"{self.where}: {type(exc).__name__}: {exc}") from None
            self.urls, self.offset_s, self.rtt_ms = urls, offset, rtt
            self.generation += 1

    def reconnect(self, generation: int) -> bool:
        """A new connection unless one has been made since ``generation``; False while the phone
        does not answer."""
        with self.lock:
            if self.generation != generation:
                return True
            try:
                self.connect()
                return True
            except ConnectionError:
                return False

    def local_time(self, t_phone: float) -> float:
        """``time.monotonic()`` at phone time ``t_phone`` (Unix s)."""
        return t_phone + self.offset_s

    def close(self) -> None:
        """Nothing held open between calls (the readers close their own streams)."""


class _Stream(InputThread):
    """A thread reading one of the client's streams in its own asyncio loop: opened again after
    ``STALL_S`` of silence or when it ends, with one log line per outage."""

    kind = ""

    def __init__(self, link: NeonLink, name: str, maxsize: int):
        super().__init__(name)
        self.link = link
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.connected = threading.Event()
        self.error: str | None = None
        self.port = link.where
        self.last_t = -np.inf
        self._last = time.monotonic()
        self._last_local = -np.inf             # the newest datum's local time

    def _run(self) -> None:
        asyncio.run(self._main())

    async def _main(self) -> None:
        loop = asyncio.get_running_loop()
        while not self.stop_event.is_set():
            gen = self.link.generation
            task = asyncio.create_task(self._consume(self.link.urls[self.kind]))
            self._last = time.monotonic()
            self.connected.set()
            while not (self.stop_event.is_set() or task.done() or time.monotonic() - self._last > STALL_S):
                await asyncio.sleep(0.02)
            stopped = time.monotonic()
            while (self.stop_event.is_set() and not task.done() and self._last_local < stopped
                   and time.monotonic() - stopped < DRAIN_MAX_S and time.monotonic() - self._last < DRAIN_QUIET_S):
                await asyncio.sleep(0.01)            # a reader behind takes what was sent before the end
            task.cancel()
            why = (await asyncio.gather(task, return_exceptions=True))[0]
            await asyncio.sleep(TEARDOWN_S)          # the client's RTSP TEARDOWN answered before its loop ends
            if self.stop_event.is_set():
                return
            what = f"ended ({type(why).__name__}: {why})" if isinstance(why, Exception) else (
                "ended" if task.done() and not task.cancelled() else f"silent for {STALL_S:g} s")
            log.warning("%s: the %s stream %s; reconnecting", self.port, self.kind, what)
            while not self.stop_event.is_set():
                if await loop.run_in_executor(None, self.link.reconnect, gen):
                    self._reconnected()
                    break
                await asyncio.sleep(RETRY_S)

    async def _consume(self, url: str) -> None:
        raise NotImplementedError

    def _session_time(self, t_phone: float) -> tuple[float, float]:
        """(local time, session time) of a datum stamped ``t_phone``; session times kept increasing
        (a new clock sync may step back by its error)."""
        local = self._last_local = self.link.local_time(t_phone)
        t_s = max(local - self.link.t0, self.last_t + 1e-6)
        self.last_t = t_s
        return local, t_s


class GazeReader(_Stream):
    """Neon's gaze as the live loop's eye reader: ``(sample_local_s, t_s, RaySample)`` on
    ``queue``; ``on_record(t_s, record)`` sees every sample first, in this thread (the recorder).
    Eye states give per-eye lines (``neon_rtp.eye_state_sample``); a datum without them the
    cyclopean ray from the scene camera (``neon_rtp.cyclopean_sample``)."""

    kind = "gaze"

    def __init__(self, link: NeonLink, on_record=None, maxsize: int = 2000):
        super().__init__(link, "neon-gaze", maxsize)
        self.stats = SerialStats()
        self.on_record = on_record
        self.without_eye_states = 0
        self.transport = LatencyHistogram()   # phone sample time -> received here, ms

    def _reconnected(self) -> None:
        self.stats.reconnects += 1

    async def _consume(self, url: str) -> None:
        receive_gaze_data = client()[2]
        async for datum in receive_gaze_data(url, log_level=CLIENT_LOG_LEVEL):
            self._last = time.monotonic()
            self._datum(datum)

    def _datum(self, datum) -> None:
        t = float(datum.timestamp_unix_seconds)
        if has_eye_states(datum):
            rec = eye_state_sample(self.stats.records, t, datum)
        elif self.link.camera is not None:
            rec = cyclopean_sample(self.stats.records, t, datum, self.link.camera)
            self.without_eye_states += 1
        else:
            self.stats.corrupt += 1
            return
        local, t_s = self._session_time(t)
        hand_on_gaze(self, local, t_s, rec)


class WorldFrames(_Stream):
    """Neon's scene video as the live loop's camera: ``(local_s, index, grey, None)`` on ``queue``
    (the oldest goes when it is full: ``skipped``); ``sink(t_s, index, grey)`` sees every frame
    (the recorder). ``size``, ``fps`` are the stream's (``probe_frames``)."""

    kind = "world"

    def __init__(self, link: NeonLink, size, fps: float, maxsize: int = 4):
        super().__init__(link, "neon-frames", maxsize)
        self.stats = CameraStats()
        self.size, self.fps = tuple(size), fps
        self.t0 = link.t0
        self.finished = threading.Event()     # a device does not end; the session does
        self.sink = None
        self.n = 0
        self._prev_t: float | None = None

    def _reconnected(self) -> None:
        self.stats.stalls += 1
        self._prev_t = None

    async def _consume(self, url: str) -> None:
        receive_video_frames = client()[3]
        async for frame in receive_video_frames(url, log_level=CLIENT_LOG_LEVEL):
            self._last = time.monotonic()
            self._frame(frame.av_frame, float(frame.timestamp_unix_seconds))

    def _frame(self, av_frame, t: float) -> None:
        if (av_frame.width, av_frame.height) != self.size:
            self.stats.missed += 1
            return
        if self._prev_t is not None and self.fps > 0:
            gap = (t - self._prev_t) * self.fps
            if 1.5 <= gap <= 5.0:
                self.stats.missed += int(round(gap)) - 1
        self._prev_t = t
        gray = av_frame.to_ndarray(format="gray")
        local, t_s = self._session_time(t)
        if self.sink is not None:
            self.sink(t_s, self.n, gray)
        item = (local, self.n, gray, None)
        self.n += 1
        self.stats.frames += 1
        self.stats.skipped += put_newest(self.queue, item)


async def _probe(url: str, n: int) -> list:
    receive_video_frames = client()[3]
    out = []
    frames = receive_video_frames(url, log_level=CLIENT_LOG_LEVEL)
    try:
        async for frame in frames:
            out.append(((frame.av_frame.width, frame.av_frame.height), frame.timestamp_unix_seconds))
            if len(out) >= n:
                break
    finally:
        await frames.aclose()
        await asyncio.sleep(TEARDOWN_S)              # the client's RTSP TEARDOWN answered before the loop ends
    return out


def probe_frames(link: NeonLink, n: int = 6, timeout_s: float = 5.0) -> tuple[tuple[int, int], float]:
    """The scene stream's (width, height) px and rate, Hz, from its first ``n`` frames.

    Raises:
        UserError: no frame within ``timeout_s``.
    """
    try:
        got = asyncio.run(asyncio.wait_for(_probe(link.urls["world"], n), timeout_s))
    except (asyncio.TimeoutError, OSError, ValueError) as exc:
        got, why = [], f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    else:
        why = "the stream ended"
    if not got:
        raise UserError(f"--device {link.where}: no scene frame within {timeout_s:g} s ({why}); check that the "
                        "Neon module is connected and the scene camera streams in the Companion app")
    size = got[-1][0]
    times = [t for _, t in got]
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 30.0
    return size, float(fps)


def open_link(url: str, camera=None) -> NeonLink:
    """Connect to the Companion app at ``url`` (status and clock).

    Raises:
        UserError: a bad URL, the extra missing, or the phone does not answer.
    """
    client()
    link = NeonLink(*parse_neon_url(url), camera=camera)
    try:
        link.connect()
    except ConnectionError as exc:
        raise UserError(f"--device {url}: {exc}; check that the Companion app runs on that address (Streaming "
                        "shows it) and that this computer and the phone are on the same network") from None
    return link
