"""Pupil Core in software: Pupil Capture's network API (Pupil Remote, the IPC backbone's 3D gaze
and the Frame Publisher's scene frames) serving a session's eye rays and scene video at their
own pace, for ``live --device pupil-core://`` without the hardware (docs/live.md, "Pupil Core").

The message layouts are ``formats.devices.pupil_net``'s (Pupil's own, cited there). As Capture:
Pupil Remote is a REP socket on the given port; ``SUB_PORT`` names the PUB socket the gaze and
frames go out on, ``PUB_PORT`` a SUB socket taking notifications; ``t`` gives Pupil time (its
own clock: ``time.monotonic()`` plus ``clock_s``), ``T <time>`` sets it; the scene frames go out
only once a ``start_plugin`` notification has started the Frame Publisher (its format: 'bgr',
'jpeg' or 'gray'). The stream starts when a first subscriber subscribes (the PUB socket is an
XPUB, which sees subscriptions) and then waits for no one: messages sent while nobody subscribes
are lost, as on a real network.
"""

from __future__ import annotations

import heapq
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import zmq

from ..errors import UserError
from ..formats.devices.common import read_simulated_recording
from ..formats.devices.pupil_net import (
    FRAME_PUBLISHER,
    BadMessage,
    frame_message,
    gaze_message,
    unpack,
)
from ..formats.eye_rays import read_eye_rays
from ..formats.session import load_session
from ..formats.video import read_frame_times

DEFAULT_CLOCK_S = 5000.0
"""Pupil time minus ``time.monotonic()`` of an emulator not yet set by ``T``: far from the
local clock, so that a client that does not map the device's clock fails its tests."""


@dataclass(frozen=True)
class DeviceStream:
    """What a device emulator plays: the eye rays and the scene video on one clock.

    Attributes:
        t: (N,) eye-sample times, s. left, right: (N, 6) each eye's centre (mm) and unit
            direction, head frame (= the scene camera's, OpenCV axes); left_valid, right_valid:
            (N,) bool. video: the scene video; frame_times: (M,) its frames' times, s.
    """

    t: np.ndarray
    left: np.ndarray
    right: np.ndarray
    left_valid: np.ndarray
    right_valid: np.ndarray
    video: Path
    frame_times: np.ndarray


def device_stream(session) -> DeviceStream:
    """The eye rays and scene video of ``session``: a session with ``eye_rays.csv`` (imported, or
    recorded by ``live --device``) or one written by ``wearable-gaze simulate`` (its measured
    lines, from ``truth/``).

    Raises:
        UserError: neither, or no scene video.
    """
    sess = load_session(session)
    video, stamps = sess.path("scene_video"), sess.path("scene_timestamps")
    if video is None or stamps is None or not video.is_file():
        raise UserError(f"{session}: no scene video with its timestamps; a device emulator sends both")
    if sess.path("eye_rays") is not None:
        rays = read_eye_rays(sess.path("eye_rays"))
    elif sess.path("truth_gaze") is not None:
        rays = read_simulated_recording(session).rays
    else:
        raise UserError(f"{session}: no eye rays (eye_rays.csv) and not a simulated session; give a session from "
                        "'wearable-gaze simulate', 'import' or 'live --device --record'")
    lv, rv = np.asarray(rays.left_valid, bool), np.asarray(rays.right_valid, bool)
    left = np.hstack([rays.left_origin_mm, rays.left_direction])
    right = np.hstack([rays.right_origin_mm, rays.right_direction])
    return DeviceStream(np.asarray(rays.t_s, float), left, right, lv, rv, video, read_frame_times(stamps)[1])


class PupilCoreEmulator:
    """Pupil Capture's network API playing a ``DeviceStream``.

    Args:
        stream: what to play. duration_s: stop after this much stream time (default: its end).
        clock_s: Pupil time minus ``time.monotonic()`` until a ``T`` request sets it.
        inject: fault injection, ``{k: [multipart messages]}`` published right after the k-th
            gaze message. log_sent: keep ``sent_log``, ``(time.monotonic(), k)`` as the k-th
            gaze message goes out.

    Attributes:
        sent, frames_sent: messages published; ``finished`` is set when the stream ends.
        frame_format: the Frame Publisher's format, None until it is started.
    """

    def __init__(self, stream: DeviceStream, duration_s: float | None = None, clock_s: float = DEFAULT_CLOCK_S,
                 inject: dict | None = None, log_sent: bool = False):
        self.stream = stream
        self.duration_s = duration_s
        self.clock_s = clock_s
        self.inject = dict(inject or {})
        self.sent = self.frames_sent = 0
        self.sent_log: list | None = [] if log_sent else None
        self.frame_format: str | None = None
        self.finished = threading.Event()
        self.started = threading.Event()            # the first subscription: the stream's start
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.ctx = zmq.Context()

    def pupil_time(self) -> float:
        """Pupil time now, s."""
        return time.monotonic() + self.clock_s

    # --- Pupil Remote ---------------------------------------------------------------------------

    def listen(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Bind Pupil Remote to ``host:port`` (0: any free port) and start; returns the
        ``pupil-core://HOST:PORT`` address ``live --device`` takes.

        Raises:
            UserError: the address cannot be bound.
        """
        rep, pub, sub = (self.ctx.socket(k) for k in (zmq.REP, zmq.XPUB, zmq.SUB))
        for s in (rep, pub, sub):
            s.setsockopt(zmq.LINGER, 0)
        try:
            rep.bind(f"tcp://{host}:{port}")
        except zmq.ZMQError as exc:
            for s in (rep, pub, sub):
                s.close()
            raise UserError(f"cannot listen on {host}:{port} ({exc}); pick a free port, e.g. --listen 127.0.0.1:0 "
                            "for any") from None
        pub.setsockopt(zmq.SNDHWM, 1000)
        self.sub_port = pub.bind_to_random_port(f"tcp://{host}")
        self.pub_port = sub.bind_to_random_port(f"tcp://{host}")
        sub.setsockopt(zmq.SUBSCRIBE, b"notify.")
        self.port = int(rep.getsockopt(zmq.LAST_ENDPOINT).decode().rsplit(":", 1)[1])
        self._start(self._serve, rep, sub)
        self._start(self._play, pub)
        return f"pupil-core://{host}:{self.port}"

    def _start(self, fn, *args) -> None:
        th = threading.Thread(target=fn, args=args, daemon=True, name="pupil-core-emulator")
        th.start()
        self._threads.append(th)

    def _serve(self, rep, sub) -> None:
        poller = zmq.Poller()
        poller.register(rep, zmq.POLLIN)
        poller.register(sub, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                ready = dict(poller.poll(50))
                if rep in ready:
                    parts = rep.recv_multipart()
                    rep.send_string(self.answer(parts))
                if sub in ready:
                    self.answer(sub.recv_multipart())
        finally:
            rep.close()
            sub.close()

    def answer(self, parts: list[bytes]) -> str:
        """Pupil Remote's answer to one request (``pupil_remote.py``, ``on_recv``)."""
        if len(parts) > 1:
            try:
                self._notify(unpack(parts[1]))
            except BadMessage:
                pass
            return "Message forwarded."
        msg = parts[0].decode("utf-8", "replace")
        if msg == "SUB_PORT":
            return str(self.sub_port)
        if msg == "PUB_PORT":
            return str(self.pub_port)
        if msg.startswith("T"):
            try:
                target = float(msg[2:])
            except ValueError:
                return f"'{msg[2:]}' cannot be converted to float."
            self.clock_s = target - time.monotonic()
            return "Timesync successful."
        if msg.startswith("t"):
            return repr(self.pupil_time())
        if msg.startswith("v"):
            return "3.5.0-emulated"
        return "Unknown command."

    def _notify(self, note: dict) -> None:
        subject = note.get("subject")
        args = note.get("args") or {}
        if subject == "start_plugin" and note.get("name") == FRAME_PUBLISHER:
            self.frame_format = str(args.get("format", "jpeg"))
        elif subject == "stop_plugin" and note.get("name") == FRAME_PUBLISHER:
            self.frame_format = None
        elif subject == "frame_publishing.set_format" and self.frame_format is not None:
            self.frame_format = str(note.get("format", self.frame_format))

    # --- the stream -----------------------------------------------------------------------------

    def _schedule(self):
        """(stream time from the start, kind, index) of every message in time order."""
        s = self.stream
        t0 = min(s.t[0], s.frame_times[0]) if len(s.frame_times) else s.t[0]
        gaze = (((float(t) - t0), 0, k) for k, t in enumerate(s.t))
        frames = (((float(t) - t0), 1, j) for j, t in enumerate(s.frame_times))
        for dt, kind, i in heapq.merge(gaze, frames):
            if self.duration_s is not None and dt > self.duration_s:
                return
            yield dt, kind, i

    def _play(self, pub) -> None:
        cap = cv2.VideoCapture(str(self.stream.video))
        try:
            while not pub.poll(50):             # an XPUB: a subscription arrives as a message
                if self._stop.is_set():
                    return
            self.started.set()
            t0 = time.monotonic()
            for dt, kind, i in self._schedule():
                while (wait := t0 + dt - time.monotonic()) > 0:
                    if self._stop.wait(min(wait, 0.05)):
                        return
                if self._stop.is_set():
                    return
                if kind == 0:
                    self._send_gaze(pub, i, t0 + dt + self.clock_s)
                else:
                    ok, img = cap.read()
                    if ok and self.frame_format is not None:
                        pub.send_multipart(frame_message(i, t0 + dt + self.clock_s, img, self.frame_format))
                        self.frames_sent += 1
            self._stop.wait(0.3)                    # let subscribers take the last messages
        finally:
            cap.release()
            pub.close()
            self.finished.set()

    def _send_gaze(self, pub, k: int, t_pupil: float) -> None:
        s = self.stream
        left = s.left[k] if s.left_valid[k] else None
        right = s.right[k] if s.right_valid[k] else None
        if left is not None or right is not None:
            if self.sent_log is not None:
                self.sent_log.append((time.monotonic(), k))
            pub.send_multipart(gaze_message(t_pupil, left, right))
            self.sent += 1
        for parts in self.inject.get(k, ()):
            pub.send_multipart(parts)

    def stop(self, timeout: float = 2.0) -> None:
        """End the stream and close every socket (the port is free again)."""
        self._stop.set()
        for th in self._threads:
            th.join(timeout)
        self.ctx.term()
