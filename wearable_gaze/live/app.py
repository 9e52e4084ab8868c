"""The live wearable session (docs/live.md): eye samples from the serial line and frames from
the scene camera, head tracking, view lines, online fixation detection and a streaming
estimator; every estimate and target published as JSON lines; everything recorded as a
session folder that ``process`` reads."""

from __future__ import annotations

import json
import queue
import shutil
import signal
import socket
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlparse

import cv2
import numpy as np

from estimator import BinocularSample, make_estimator
from estimator.frames import rotate_directions, transform_points
from estimator.segments import OnlineSegmenter, same_target
from tracking.markers import MarkerDetector
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import interpolate_poses

from ..calibrate_cmd import load_camera, load_eyes
from ..errors import UserError
from ..session import EYE_FORMATS, FORMAT, VERSION, marker_map_dict
from ..track_cmd import load_marker_map
from .camera_in import FrameSource
from .serial_in import EyeReader

MESSAGE_VERSION = 1


class Publisher:
    """JSON lines to stdout and/or a UDP or TCP endpoint (``udp://host:port``, ``tcp://host:port``)."""

    def __init__(self, url: str | None = None, stdout: bool = True, stream=None):
        self.stdout = stdout
        self.stream = stream or sys.stdout
        self.sock = None
        self.kind = None
        if url:
            u = urlparse(url)
            if u.scheme not in ("udp", "tcp") or not u.hostname or not u.port:
                raise UserError(f"--publish {url!r}: expected udp://HOST:PORT or tcp://HOST:PORT")
            self.kind, self.addr = u.scheme, (u.hostname, u.port)
            if u.scheme == "udp":
                self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            else:
                try:
                    self.sock = socket.create_connection(self.addr, timeout=2.0)
                except OSError as exc:
                    raise UserError(f"--publish {url}: cannot connect ({exc})") from None
        self.sent = 0

    def send(self, msg: dict) -> None:
        line = json.dumps(msg, separators=(",", ":")) + "\n"
        if self.stdout:
            self.stream.write(line)
            self.stream.flush()
        if self.sock is not None:
            try:
                if self.kind == "udp":
                    self.sock.sendto(line.encode(), self.addr)
                else:
                    self.sock.sendall(line.encode())
            except OSError:
                pass                                       # a listener that went away must not stop the session
        self.sent += 1

    def close(self):
        if self.sock is not None:
            self.sock.close()


class Recorder:
    """Writes everything received as a session folder (docs/session.md), flushed at least once
    a second; ``close`` finishes the video and the manifest."""

    def __init__(self, root: Path, size, fps: float, camera_path, eyes_path, marker_map):
        self.root = Path(root)
        if self.root.exists() and any(self.root.iterdir()):
            raise UserError(f"--record {self.root}: already exists and is not empty; choose a new folder")
        self.root.mkdir(parents=True, exist_ok=True)
        shutil.copy(camera_path, self.root / "camera.json")
        shutil.copy(eyes_path, self.root / "eyes.json")
        (self.root / "markers.json").write_text(json.dumps(marker_map_dict(
            marker_map.dictionary, marker_map.marker_size_mm, marker_map.poses, marker_map.labels), indent=1))
        self.video = cv2.VideoWriter(str(self.root / "scene.avi"), cv2.CAP_FFMPEG,
                                     cv2.VideoWriter_fourcc(*"MJPG"), fps, tuple(size), isColor=False)
        # frames are encoded in their own thread (bounded: the live loop never waits on the disk)
        self.video_q: queue.Queue = queue.Queue(maxsize=60)
        self.video_thread = threading.Thread(target=self._video_worker, daemon=True, name="recorder-video")
        self.video_thread.start()
        self.ts = open(self.root / "scene_timestamps.csv", "w", encoding="utf-8")
        self.ts.write("frame,t\n")
        self.eye = open(self.root / "eye.csv", "w", encoding="utf-8")
        self.eye.write("t,counter,left_x,left_y,right_x,right_y,left_valid,right_valid\n")
        self.raw = open(self.root / "eye_serial.bin", "wb")
        self.n_frames = self.n_eye = 0
        self.last_flush = time.monotonic()
        self.lock = threading.Lock()
        self.fps = fps
        self.size = size
        self._manifest(final=False)

    def _manifest(self, final: bool):
        man = {"format": FORMAT, "version": VERSION, "producer": "wearable-gaze live", "image_size": list(self.size),
               "fps": self.fps, "eye_rate_hz": None, "has_recording": True, "complete": final,
               "files": {"scene_video": "scene.avi", "scene_timestamps": "scene_timestamps.csv",
                         "eye_samples": "eye.csv", "eye_serial": "eye_serial.bin", "marker_map": "markers.json",
                         "camera": "camera.json", "eyes": "eyes.json", "live_messages": "live.jsonl"},
               "n_frames": self.n_frames, "n_eye_samples": self.n_eye}
        tmp = self.root / ".session.json.tmp"
        tmp.write_text(json.dumps(man, indent=1))
        tmp.replace(self.root / "session.json")

    def raw_bytes(self, data: bytes):
        with self.lock:
            self.raw.write(data)

    def _video_worker(self):
        while True:
            item = self.video_q.get()
            if item is None:
                return
            self.video.write(item)

    def frame(self, t: float, index: int, grey):
        self.video_q.put(grey)
        with self.lock:
            self.ts.write(f"{index},{t:.6f}\n")
            self.n_frames += 1

    def flush_if_due(self):
        if time.monotonic() - self.last_flush >= 1.0:
            self.flush()

    def eye_sample(self, t: float, rec):
        f = EYE_FORMATS
        self.eye.write(f"{format(t, f['t'])},{rec.counter},{format(rec.left[0], f['left_x'])},"
                       f"{format(rec.left[1], f['left_y'])},{format(rec.right[0], f['right_x'])},"
                       f"{format(rec.right[1], f['right_y'])},{int(rec.left_valid)},{int(rec.right_valid)}\n")
        self.n_eye += 1

    def flush(self):
        with self.lock:
            for fh in (self.ts, self.eye, self.raw):
                fh.flush()
        self.last_flush = time.monotonic()

    def close(self):
        self.video_q.put(None)
        self.video_thread.join()
        self.video.release()
        self.flush()
        for fh in (self.ts, self.eye, self.raw):
            fh.close()
        self._manifest(final=True)


class LatencyHistogram:
    """Latencies of a whole run in fixed memory: counts in ``bin_ms`` bins up to ``max_ms``
    (longer ones in the last bin), so percentiles of an hour-long run need no sample list."""

    def __init__(self, bin_ms: float = 0.1, max_ms: float = 2000.0):
        self.bin_ms = bin_ms
        self.counts = np.zeros(int(round(max_ms / bin_ms)) + 1, np.int64)

    def add(self, ms: float) -> None:
        self.counts[min(int(ms / self.bin_ms), len(self.counts) - 1)] += 1

    @property
    def n(self) -> int:
        return int(self.counts.sum())

    def percentile(self, q: float) -> float:
        """The q-th percentile in ms (upper edge of its bin: never under the true value by more
        than nothing, never over by more than one bin); NaN when empty."""
        n = self.n
        if n == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(self.counts), max(1, int(np.ceil(q / 100.0 * n)))))
        return (k + 1) * self.bin_ms


@dataclass
class LiveStats:
    samples: int = 0
    published: int = 0
    no_pose: int = 0
    targets: int = 0
    frames_skipped: int = 0   # waiting frames tracking passed over for a newer one (all still recorded)
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=5000))   # the recent ones, for the status line
    latency_all: LatencyHistogram = field(default_factory=LatencyHistogram)   # the whole run


class LiveSession:
    """Runs until the camera file ends, ``duration_s`` passes, or ``stop()`` (Ctrl-C, SIGTERM)."""

    def __init__(self, serial_port: str, camera_source: str, camera_calib, eyes_path, markers_path,
                 record=None, publish=None, baud: int = 115200, method: str = "voxel", stdout: bool = True,
                 status_stream=None, hold_s: float = 0.05, stream=None):
        self.camera = load_camera(camera_calib)
        self.eyes = load_eyes(eyes_path)
        self.map = load_marker_map(markers_path)
        try:
            self.frames = FrameSource(camera_source)
        except OSError as exc:
            raise UserError(str(exc)) from None
        if tuple(self.frames.size) != tuple(self.camera.image_size):
            raise UserError(f"camera {camera_source} gives {self.frames.size[0]}x{self.frames.size[1]} frames but the "
                            f"calibration is for {self.camera.image_size[0]}x{self.camera.image_size[1]}")
        self.publisher = Publisher(publish, stdout, stream)
        self.recorder = (Recorder(Path(record), self.frames.size, self.frames.fps, camera_calib, eyes_path, self.map)
                         if record else None)
        if self.recorder is not None:
            self.frames.sink = self.recorder.frame          # every captured frame, even those tracking skips
        self.reader = EyeReader(serial_port, baud, raw_sink=self.recorder.raw_bytes if self.recorder else None)
        self.detector = MarkerDetector(self.map.dictionary)
        self.poser = MarkerPoseEstimator(self.map, self.camera)
        self.method = method
        self.stats = LiveStats()
        self.stop_event = threading.Event()
        self.status_stream = status_stream
        self.hold_s = hold_s
        self.poses = deque(maxlen=120)            # (t, T_world_from_cam) of recent frames
        self.pending = deque()
        self.offset = None
        self.fix = OnlineSegmenter()
        self.fix_index = 0
        self.estimator = make_estimator(method)
        self.fix_samples = 0
        self.fix_t0 = None
        self.last_est = None
        self.messages = open(Path(record) / "live.jsonl", "w", encoding="utf-8") if record else None
        self.targets: list = []
        self.head = None
        self.markers_in_view = 0
        self.last_arrival: float | None = None    # monotonic time the newest eye record arrived
        self.last_t = -1.0                        # session time of the newest eye sample, s

    def stop(self, *_):
        self.stop_event.set()

    def _publish(self, msg):
        msg = {"version": MESSAGE_VERSION, **msg}
        self.publisher.send(msg)
        if self.messages is not None:
            self.messages.write(json.dumps(msg, separators=(",", ":")) + "\n")
        self.stats.published += 1

    def run(self, duration_s: float | None = None) -> LiveStats:
        self.reader.start()
        self.reader.connected.wait(5.0)
        if self.reader.error and self.reader.error.startswith("cannot open"):
            self._close()
            raise UserError(f"--serial: {self.reader.error}")
        self.frames.start()
        t_start = time.monotonic()
        last_status = 0.0
        try:
            while not self.stop_event.is_set():
                busy = self._drain_frames()
                busy |= self._drain_eye()
                now = time.monotonic()
                if duration_s is not None and now - t_start >= duration_s:
                    break
                if self.frames.finished.is_set() and self.frames.queue.empty() and self.reader.queue.empty():
                    if self.last_arrival is not None and now - self.last_arrival > 0.5:
                        break
                if self.recorder is not None:
                    self.recorder.flush_if_due()
                if self.status_stream is not None and now - last_status > 0.5:
                    self._status()
                    last_status = now
                if not busy:
                    time.sleep(0.002)
        finally:
            self._end_fixation()
            self._close()
        return self.stats

    def _drain_frames(self) -> bool:
        """Track the newest waiting frame; older waiting frames are skipped (counted): under
        load, a fresh pose serves the waiting eye samples better than a backlog of old ones
        (every frame is still recorded)."""
        items = []
        while True:
            try:
                items.append(self.frames.queue.get_nowait())
            except queue.Empty:
                break
        if not items:
            return False
        self.stats.frames_skipped += len(items) - 1
        t, i, grey, _ = items[-1]
        t_s = t - self.frames.t0
        res = self.poser.estimate(self.detector.detect(grey))
        self.markers_in_view = len(res.markers)
        if res.ok:
            self.poses.append((t_s, res.T_world_from_cam))
        return True

    def _drain_eye(self) -> bool:
        busy = False
        while True:
            try:
                arrival, rec = self.reader.queue.get_nowait()
            except queue.Empty:
                break
            busy = True
            self.last_arrival = arrival
            t0 = self.frames.t0 if self.frames.t0 is not None else arrival
            off = arrival - t0 - rec.t
            if self.offset is None or off < self.offset - 0.002:
                self.offset = off                            # the fastest path: the clocks' offset
            # the eye clock mapped onto the session clock; kept strictly increasing when the
            # offset estimate improves (by at most the first samples' extra transport delay)
            t_s = max(rec.t + self.offset, self.last_t + 1e-4)
            self.last_t = t_s
            if self.recorder is not None:
                self.recorder.eye_sample(t_s, rec)
            self.pending.append((arrival, t_s, rec))
        last_frame_t = self.poses[-1][0] if self.poses else None
        while self.pending:
            arrival, t_s, rec = self.pending[0]
            if last_frame_t is not None and t_s > last_frame_t + self.hold_s and time.monotonic() - arrival < 0.2:
                break                                        # wait for the next frame (bounded)
            self.pending.popleft()
            self._sample(arrival, t_s, rec)
        return busy

    def _pose_at(self, t_s):
        """The head pose at a sample's time: SLERP between the two frames around it, or the
        last frame's pose held for up to ``hold_s`` (so a sample need not wait for the next
        frame; the head turns a fraction of a degree in 50 ms)."""
        if not self.poses:
            return None
        t_last, T_last = self.poses[-1]
        if t_s >= t_last:
            return T_last if t_s - t_last <= self.hold_s else None
        for k in range(len(self.poses) - 2, -1, -1):
            ta, Ta = self.poses[k]
            if ta <= t_s:
                tb, Tb = self.poses[k + 1]
                if tb - ta > 0.2:
                    return None
                T, ok = interpolate_poses([ta, tb], np.stack([Ta, Tb]), [t_s], max_gap_s=0.2)
                return T[0] if ok[0] else None
        return None

    def _sample(self, arrival, t_s, rec):
        self.stats.samples += 1
        if not (rec.left_valid or rec.right_valid):
            return
        T = self._pose_at(t_s)
        if T is None:
            self.stats.no_pose += 1
            return
        parts = []
        for e, (raw, valid) in enumerate(((rec.left, rec.left_valid), (rec.right, rec.right_valid))):
            if not valid:
                parts += [None, None]
                continue
            d = self.eyes[e].directions(np.array([raw]))[0]
            parts += [transform_points(T, self.eyes[e].centre_mm[None])[0], rotate_directions(T, d[None])[0]]
        sample = BinocularSample(t_s, *parts)
        self.head = parts[0] if parts[0] is not None else parts[2]
        if rec.left_valid and rec.right_valid:            # one eye alone is off the cyclopean line by
            cyc = parts[1] + parts[3]                     # half the vergence: not a saccade
            if self.fix.update(t_s, cyc / np.linalg.norm(cyc)):
                self._end_fixation()
        if self.fix.in_saccade:                           # between fixations: no target's line
            return
        if self.fix_t0 is None:
            self.fix_t0 = t_s
        est = self.estimator.update(sample)
        self.fix_samples += 1
        if est.ok:
            self.last_est = (est, t_s)
            lat = (time.monotonic() - arrival) * 1000
            self.stats.latencies_ms.append(lat)
            self.stats.latency_all.add(lat)
            r = est.ellipsoid(0.95)
            self._publish({"type": "estimate", "t": round(t_s, 4), "fixation": self.fix_index,
                           "position_mm": [round(v, 1) for v in est.position_mm],
                           "radius95_mm": None if r is None else round(float(r.radii_mm.max()), 1),
                           "n_samples": self.fix_samples, "latency_ms": round(lat, 2)})

    def _target_id(self, est) -> int:
        """The same target seen again (``estimator.segments.same_target``, as ``process``
        merges fixations) keeps its id; otherwise a new id."""
        for k, (x, c) in enumerate(self.targets):
            if same_target(est.position_mm, est.covariance_mm2, x, c, origin=self.head):
                return k
        self.targets.append((est.position_mm, est.covariance_mm2))
        return len(self.targets) - 1

    def _end_fixation(self):
        if self.last_est is not None and self.fix_t0 is not None and self.last_est[1] - self.fix_t0 >= self.fix.config.min_fixation_s:
            est = self.last_est[0]
            r = est.ellipsoid(0.95)
            self._publish({"type": "target", "target": self._target_id(est), "fixation": self.fix_index,
                           "t_start": round(self.fix_t0, 4),
                           "t_end": round(self.last_est[1], 4), "position_mm": [round(v, 1) for v in est.position_mm],
                           "ellipsoid95_radii_mm": None if r is None else [round(float(v), 1) for v in r.radii_mm],
                           "n_samples": self.fix_samples, "method": self.method})
            self.stats.targets += 1
        self.fix_index += 1
        self.estimator = make_estimator(self.method)
        self.fix_samples = 0
        self.fix_t0 = None
        self.last_est = None

    def _status(self):
        s, r, c = self.stats, self.reader.stats, self.frames.stats
        lat = np.percentile(list(s.latencies_ms), 95) if s.latencies_ms else float("nan")
        cur = "-" if self.last_est is None else "(" + ", ".join(f"{v:.0f}" for v in self.last_est[0].position_mm) + ")"
        self.status_stream.write(f"\rframes {c.frames} (dropped {c.dropped}, skipped {s.frames_skipped})  eye {r.records} (corrupt {r.corrupt}, "
                                 f"lost {r.lost}, reconnects {r.reconnects})  markers {self.markers_in_view}"
                                 f"  p95 latency {lat:.1f} ms  target {cur} mm   ")
        self.status_stream.flush()

    def _close(self):
        self.reader.stop()
        self.frames.stop()
        for th in (self.reader, self.frames):
            if th.ident is not None:
                th.join(2.0)
        if self.recorder is not None:
            self.recorder.close()
        if self.messages is not None:
            self.messages.close()
        self.publisher.close()


def run_live(serial_port, camera_source, camera_calib, eyes_path, markers_path, record=None, publish=None,
             baud: int = 115200, duration_s=None, status_stream=None) -> LiveStats:
    """``wearable-gaze live``: run until the camera file ends, the duration passes, Ctrl-C or
    SIGTERM; everything recorded stays complete."""
    session = LiveSession(serial_port, camera_source, camera_calib, eyes_path, markers_path, record, publish, baud,
                          status_stream=status_stream)
    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, session.stop)
    try:
        return session.run(duration_s)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


