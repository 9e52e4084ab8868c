"""The Neon emulator's streams (``neon_emu``): a session's eye rays as gaze with eye states, and its
scene video as H.264, sent over RTP at their own pace to every subscriber that has sent PLAY,
with RTCP sender reports that give the phone's clock (layouts: ``formats.devices.neon_rtp``).

One thread plays both streams from one schedule (the eye samples' and the frames' times merged);
a subscriber is sent to over UDP (``client_port``) or interleaved on its RTSP connection. The
frames are encoded ahead of their time in a thread of their own (as the phone's hardware encoder
takes a few ms, the emulator's encoding is kept out of the stream's timing); a video subscriber
gets frames from the next keyframe on (one every ``GOP`` frames).
"""

from __future__ import annotations

import heapq
import queue
import threading
import time
from dataclasses import dataclass, field
from fractions import Fraction

import av
import cv2
import numpy as np

from ..formats.devices.neon_rtp import (
    GAZE_PT,
    RTP_CLOCK_HZ,
    VIDEO_PT,
    gaze_payload,
    h264_payloads,
    rtcp_sender_report,
    rtp_packet,
    split_annexb,
)
from ..formats.devices.pupil_net import _nearest_point

SR_EVERY_S = 1.0          # an RTCP sender report to each subscriber this often (and before its first packet)
GOP = 15                  # frames between keyframes: a new video subscriber waits at most this many
AHEAD = 30                # frames encoded ahead of their time (the encoder's own thread)
AUD = b"\x09\xf0"           # an access unit delimiter (H.264 7.3.2.4): sent after each frame, it is the next one's
# start, so that the client's parser (FFmpeg's, which finds a frame's end at the next one's start) hands the
# frame on at once instead of when the next frame comes, a frame period later


@dataclass(eq=False)
class Subscriber:
    """One RTSP session that has sent PLAY: ``send(kind, data)`` sends RTP (kind 0) or RTCP (1)."""

    kind: str                             # 'gaze' or 'world'
    send: object
    ssrc: int
    seq: int = 0
    packets: int = 0
    octets: int = 0
    last_sr: float = -np.inf
    waiting_key: bool = True              # video: nothing until a keyframe
    closed: bool = False
    errors: int = field(default=0)


class H264Encoder:
    """Scene frames -> H.264 access units (Annex B NAL units), no B-frames, a keyframe every ``GOP``
    frames or on request; ``parameter_sets`` are the SPS and PPS for the SDP."""

    def __init__(self, size, fps: float):
        self.size, self.fps = tuple(size), fps
        self.ctx = self._open()
        probe = self._open()
        sps = pps = None
        for unit in self._units(probe, np.zeros((size[1], size[0], 3), np.uint8), True):
            if unit[0] & 0x1F == 7:
                sps = unit
            elif unit[0] & 0x1F == 8:
                pps = unit
        self.parameter_sets = (sps, pps)

    def _open(self):
        ctx = av.CodecContext.create("libx264", "w")
        ctx.width, ctx.height = self.size
        ctx.pix_fmt = "yuv420p"
        ctx.framerate = Fraction(round(self.fps * 1000), 1000)
        ctx.time_base = 1 / ctx.framerate
        ctx.gop_size = GOP
        ctx.max_b_frames = 0
        ctx.options = {"preset": "ultrafast", "tune": "zerolatency", "repeat-headers": "1"}
        return ctx

    def _units(self, ctx, bgr, key: bool) -> list[bytes]:
        frame = av.VideoFrame.from_ndarray(bgr, format="bgr24")
        if key:
            frame.pict_type = av.video.frame.PictureType.I
        return [u for pkt in ctx.encode(frame) for u in split_annexb(bytes(pkt))]

    def encode(self, bgr) -> tuple[list[bytes], bool]:
        """(NAL units, is a keyframe) of one frame (H, W, 3) BGR."""
        units = self._units(self.ctx, bgr, False)
        return units, any(u[0] & 0x1F == 5 for u in units)


def _gaze_px(camera, left, right) -> np.ndarray:
    """(2,) the gaze point in the scene image: the projection of the two lines' nearest point; one
    line, or lines that meet behind the head: the point 1 m along their mean direction."""
    lines = [v for v in (left, right) if v is not None]
    p = _nearest_point(left, right) if len(lines) == 2 else None
    if p is None or p[2] <= 100.0:
        d = np.mean([v[3:] for v in lines], axis=0)
        p = np.mean([v[:3] for v in lines], axis=0) + 1000.0 * d / np.linalg.norm(d)
    return camera.project(p[None])[0]


class Player:
    """Plays ``stream`` (a ``pupil_core_emu.DeviceStream``) from ``start`` on to the subscribers.

    Args:
        stream: eye rays and scene video. camera: the scene camera (the gaze pixel). phone_time:
            the phone's clock, Unix s. rtp_time: phone time -> RTP timestamp. duration_s: stop
            after this much stream time. log_sent: keep ``sent_log``, ``(time.monotonic(), k,
            phone time)`` as the k-th eye sample goes out.
    """

    def __init__(self, stream, camera, phone_time, rtp_time, duration_s=None, log_sent=False):
        self.stream, self.camera = stream, camera
        self.phone_time, self.rtp_time = phone_time, rtp_time
        self.duration_s = duration_s
        self.sent = self.frames_sent = 0
        self.sent_log: list | None = [] if log_sent else None
        self.lock = threading.Lock()
        self.subscribers: list[Subscriber] = []
        self.started = threading.Event()
        self.finished = threading.Event()
        self.stop_event = threading.Event()
        cap = cv2.VideoCapture(str(stream.video))
        self.size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        cap.release()
        ft = stream.frame_times
        self.fps = float((len(ft) - 1) / (ft[-1] - ft[0])) if len(ft) > 1 and ft[-1] > ft[0] else 30.0
        self.encoder = H264Encoder(self.size, self.fps)

    def add(self, sub: Subscriber) -> None:
        with self.lock:
            self.subscribers.append(sub)
        self.started.set()

    def remove(self, sub: Subscriber) -> None:
        with self.lock:
            sub.closed = True
            if sub in self.subscribers:
                self.subscribers.remove(sub)

    def _schedule(self):
        s = self.stream
        t0 = min(s.t[0], s.frame_times[0]) if len(s.frame_times) else s.t[0]
        gaze = ((float(t) - t0, 0, k) for k, t in enumerate(s.t))
        frames = ((float(t) - t0, 1, j) for j, t in enumerate(s.frame_times))
        for dt, kind, i in heapq.merge(gaze, frames):
            if self.duration_s is not None and dt > self.duration_s:
                return
            yield dt, kind, i

    def run(self) -> None:
        """The playing thread: waits for a first subscriber, then plays the gaze once, while a
        thread of its own sends the frames at their times (a slow encoder delays frames, never
        gaze)."""
        encoded: queue.Queue = queue.Queue(maxsize=AHEAD)
        threading.Thread(target=self._encode, args=(encoded,), daemon=True, name="neon-encoder").start()
        try:
            while not self.started.wait(0.05):
                if self.stop_event.is_set():
                    return
            t0, p0 = time.monotonic(), self.phone_time()
            video = threading.Thread(target=self._play, args=(1, t0, p0, encoded), daemon=True, name="neon-video")
            video.start()
            self._play(0, t0, p0, encoded)
            video.join()
            self.stop_event.wait(0.3)
        finally:
            self.finished.set()

    def _play(self, which: int, t0: float, p0: float, encoded: queue.Queue) -> None:
        """Send the gaze samples (``which`` 0) or the frames (1) at their times from ``t0``
        (``time.monotonic()``), phone time ``p0``."""
        for dt, kind, i in self._schedule():
            if kind != which:
                continue
            while (wait := t0 + dt - time.monotonic()) > 0:
                if self.stop_event.wait(min(wait, 0.05)):
                    return
            if self.stop_event.is_set():
                return
            if kind == 0:
                self._gaze(i, p0 + dt)
                continue
            item = self._next(encoded)
            if item is None:
                return
            self._frame(*item, p0 + dt)

    def _next(self, encoded: queue.Queue):
        """The next encoded frame, waiting for the encoder; None at the end or on stop."""
        while not self.stop_event.is_set():
            try:
                return encoded.get(timeout=0.1)
            except queue.Empty:
                pass
        return None

    def _encode(self, out: queue.Queue) -> None:
        """The encoder's thread: each frame of the video as (NAL units, keyframe) on ``out``, in order,
        None at the end."""
        cap = cv2.VideoCapture(str(self.stream.video))
        try:
            while not self.stop_event.is_set():
                ok, img = cap.read()
                if not ok:
                    break
                if img.shape[1::-1] != self.size:
                    img = cv2.resize(img, self.size)
                item = self.encoder.encode(img)
                while not self.stop_event.is_set():
                    try:
                        out.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        pass
        finally:
            cap.release()
            out.put(None)

    def _targets(self, kind: str) -> list[Subscriber]:
        with self.lock:
            return [s for s in self.subscribers if s.kind == kind and not s.closed]

    def _send(self, sub: Subscriber, pt: int, ts: int, payload: bytes, marker: bool) -> None:
        now = self.phone_time()
        if now - sub.last_sr >= SR_EVERY_S:
            sub.send(1, rtcp_sender_report(sub.ssrc, now, self.rtp_time(now), sub.packets, sub.octets))
            sub.last_sr = now
        sub.send(0, rtp_packet(pt, sub.seq, ts, sub.ssrc, payload, marker))
        sub.seq += 1
        sub.packets += 1
        sub.octets += len(payload)

    def _gaze(self, k: int, t_phone: float) -> None:
        s = self.stream
        left = s.left[k] if s.left_valid[k] else None
        right = s.right[k] if s.right_valid[k] else None
        if left is None and right is None:
            return
        nan = np.full(6, np.nan)
        payload = gaze_payload(_gaze_px(self.camera, left, right), True, nan if left is None else left,
                               nan if right is None else right)
        subs = self._targets("gaze")
        if self.sent_log is not None and subs:
            self.sent_log.append((time.monotonic(), k, t_phone))
        ts = self.rtp_time(t_phone)
        for sub in subs:
            self._send(sub, GAZE_PT, ts, payload, True)
        self.sent += bool(subs)

    def _frame(self, units: list[bytes], key: bool, t_phone: float) -> None:
        ts = self.rtp_time(t_phone)
        subs = self._targets("world")
        for sub in subs:
            if sub.waiting_key and not key:
                continue
            sub.waiting_key = False
            payloads = [p for u in units for p in h264_payloads(u)] + [AUD]
            for j, p in enumerate(payloads):
                self._send(sub, VIDEO_PT, ts, p, j == len(payloads) - 1)
        self.frames_sent += bool(subs)


def rtp_clock(epoch: float):
    """Phone time (Unix s) -> RTP timestamp at ``RTP_CLOCK_HZ``, counted from ``epoch``."""
    return lambda t: int(round((t - epoch) * RTP_CLOCK_HZ)) & 0xFFFFFFFF
