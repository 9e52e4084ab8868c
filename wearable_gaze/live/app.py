"""The live wearable session (docs/live.md): eye samples from the serial line and frames from
the scene camera, head tracking, view lines, online fixation detection and a streaming
estimator; every estimate and target published as JSON lines; everything recorded as a
session folder that ``process`` reads."""

from __future__ import annotations

import logging
import queue
import signal
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import BinocularSample, make_estimator
from estimator.frames import rotate_directions, transform_points
from estimator.segments import OnlineSegmenter, same_target
from tracking.markers import MarkerDetector
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import interpolate_poses

from ..errors import UserError
from ..formats.camera import load_camera
from ..formats.eyes import load_eyes
from ..formats.markermap import load_marker_map
from .camera_in import FrameSource
from .clock import SessionClock
from .publish import Publisher
from .record import Recorder
from .serial_in import EyeReader

log = logging.getLogger(__name__)

MESSAGE_VERSION = 1
QUIET_END_S = 0.5       # after the camera file ends, the session ends once eye data have been quiet this long

__all__ = ["LatencyHistogram", "LiveSession", "LiveStats", "Publisher", "Recorder", "run_live"]


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
    """What a live session counted; each event is counted once, in one counter.

    The serial reader's, camera's and publisher's own counters are copied in by
    ``LiveSession.update_stats`` (the status line and the final summary show them all)."""
    samples: int = 0              # eye samples the loop processed
    published: int = 0            # messages published
    no_pose: int = 0              # samples with a valid eye but no head pose at their time
    targets: int = 0              # target messages (a target seen again is published again)
    distinct_targets: int = 0     # distinct target ids
    frames_skipped: int = 0       # frames tracking did not see: passed over for a newer one, or the
    #                               camera queue had no room (every one still recorded)
    frames: int = 0               # frames captured
    frames_missed: int = 0        # frames a camera device did not deliver (short gaps)
    camera_stalls: int = 0        # waits of over 5 frame periods
    eye_records: int = 0          # intact records received
    corrupt: int = 0              # records that failed their checksum or format
    lost: int = 0                 # records missing by the counter, never received at all
    reader_dropped: int = 0       # intact records the loop had no room for (still recorded)
    publish_dropped: int = 0      # messages a subscriber did not get (its queue was full, or it was disconnected)
    reconnects: int = 0
    end_reason: str = ""
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=5000))   # the recent ones, for the status line
    latency_all: LatencyHistogram = field(default_factory=LatencyHistogram)   # the whole run

    def counters(self) -> str:
        """Every counter, one line."""
        return (f"frames {self.frames} (skipped {self.frames_skipped}, missed {self.frames_missed}, stalls "
                f"{self.camera_stalls})  eye {self.eye_records} (corrupt {self.corrupt}, lost {self.lost}, dropped "
                f"{self.reader_dropped}, reconnects {self.reconnects}, no pose {self.no_pose})  messages "
                f"{self.published} (dropped {self.publish_dropped})")


def _warm_up(method: str) -> None:
    """Run the estimator once on synthetic lines before the session starts: its first update
    in a process pays one-time costs (about 1.5 s for ``voxel``) that would otherwise hold up the
    first eye samples of the session."""
    est = make_estimator(method)
    X = np.array([100.0, -50.0, 1500.0])                       # a point 1.5 m ahead, mm
    for k in range(30):
        lo = np.array([-32.0 + 3.0 * np.sin(k), 0.0, 0.0])
        ro = lo + [64.0, 0.0, 0.0]
        est.update(BinocularSample(k / 60.0, lo, (X - lo) / np.linalg.norm(X - lo), ro,
                                   (X - ro) / np.linalg.norm(X - ro)))


class LiveSession:
    """Runs until the camera file ends, ``duration_s`` passes, or ``stop()`` (Ctrl-C, SIGTERM).

    Readers (serial, camera) run in threads; the recorder takes every intact eye record and
    every frame from them directly, so nothing the loop or the subscribers do can keep a
    sample out of the recording. The loop tracks, estimates and publishes; publishing never
    blocks it (``publish.Publisher``). Any error inside the loop ends the session: the
    recording is kept, marked incomplete, and ``run`` raises a ``UserError`` saying so.
    """

    def __init__(self, serial_port: str, camera_source: str, camera_calib, eyes_path, markers_path,
                 record=None, publish=None, baud: int = 115200, method: str = "voxel", stdout: bool = True,
                 status_stream=None, hold_s: float = 0.05, stream=None, publish_queue: int = 1000,
                 publish_stuck_s: float = 5.0):
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
        self.serial_port = serial_port
        self.publisher = Publisher(publish, stdout, stream, maxsize=publish_queue, stuck_s=publish_stuck_s)
        try:
            self.recorder = (Recorder(Path(record), self.frames.size, self.frames.fps, camera_calib, eyes_path,
                                      self.map) if record else None)
        except BaseException:
            self.publisher.close(0.1)
            raise
        if self.recorder is not None:
            self.frames.sink = self.recorder.frame          # every captured frame, even those tracking skips
        self.clock = SessionClock(lambda: self.frames.t0)
        self.reader = EyeReader(serial_port, baud, raw_sink=self.recorder.raw_bytes if self.recorder else None,
                                on_record=self._on_record)
        self.detector = MarkerDetector(self.map.dictionary)
        self.poser = MarkerPoseEstimator(self.map, self.camera)
        self.method = method
        self.stats = LiveStats()
        self.stop_event = threading.Event()
        self.status_stream = status_stream
        self.hold_s = hold_s
        self.poses = deque(maxlen=120)            # (t, T_world_from_cam) of recent frames
        self.pending = deque()
        self.fix = OnlineSegmenter()
        self.fix_index = 0
        _warm_up(method)
        self.estimator = make_estimator(method)
        self.fix_samples = 0
        self.fix_t0 = None
        self.last_est = None
        self.targets: list = []
        self.head = None
        self.markers_in_view = 0
        self.last_arrival: float | None = None    # monotonic time the newest eye record arrived
        self.camera_ended_at: float | None = None

    def stop(self, *_):
        self.stop_event.set()

    def _on_record(self, arrival, rec):
        """In the reader's thread, for every intact record: its session time, and the record
        kept (before any queue that could drop it)."""
        t_s = self.clock.map(arrival, rec.t)
        if self.recorder is not None:
            self.recorder.eye_sample(t_s, rec)
        return arrival, t_s, rec

    def _publish(self, msg):
        line = self.publisher.send({"version": MESSAGE_VERSION, **msg})
        if self.recorder is not None:
            self.recorder.message(line)
        self.stats.published += 1

    def update_stats(self) -> LiveStats:
        """Copy the readers' and the publisher's counters into ``stats``."""
        s, r, c = self.stats, self.reader.stats, self.frames.stats
        s.frames, s.frames_missed, s.camera_stalls = c.frames, c.missed, c.stalls
        s.eye_records, s.corrupt, s.lost, s.reader_dropped, s.reconnects = (r.records, r.corrupt, r.lost, r.dropped,
                                                                            r.reconnects)
        s.publish_dropped = self.publisher.dropped
        s.distinct_targets = len(self.targets)
        return s

    def run(self, duration_s: float | None = None) -> LiveStats:
        """Run the session; returns its counters.

        Raises:
            UserError: the serial port will not open, or an error inside the session (the
                recording is kept and marked incomplete).
        """
        self.reader.start()
        self.reader.connected.wait(5.0)
        if self.reader.error and self.reader.error.startswith("cannot open"):
            self._close(complete=False)
            raise UserError(f"--serial: {self.reader.error}")
        self.frames.start()
        t_start = time.monotonic()
        last_status = 0.0
        failure = None
        try:
            while not self.stop_event.is_set():
                for th, what in ((self.reader, "the eye reader"), (self.frames, "the camera")):
                    if th.failure:
                        raise RuntimeError(f"{what} failed: {th.failure}")
                busy = self._drain_frames()
                busy |= self._drain_eye()
                now = time.monotonic()
                if duration_s is not None and now - t_start >= duration_s:
                    self.stats.end_reason = f"{duration_s:g} s passed"
                    break
                if self._camera_over(now):
                    break
                if self.status_stream is not None and now - last_status > 0.5:
                    self._status()
                    last_status = now
                if not busy:
                    time.sleep(0.002)
            else:
                self.stats.end_reason = "stopped"
            self._end_fixation()
        except Exception as exc:  # noqa: BLE001  (one line to the user; the recording kept, not complete)
            log.debug("live session failed", exc_info=True)
            failure = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        finally:
            self._close(complete=failure is None)
        self.update_stats()
        if failure is not None:
            kept = f"; the recording in {self.recorder.root} is kept, marked incomplete" if self.recorder else ""
            raise UserError(f"the session stopped on an error ({failure}){kept}")
        return self.stats

    def _camera_over(self, now: float) -> bool:
        """The camera file has ended and its frames are done; the session ends once the eye
        data have been quiet for ``QUIET_END_S`` (at once if none ever came)."""
        if not (self.frames.finished.is_set() and self.frames.queue.empty()):
            return False
        if self.camera_ended_at is None:
            self.camera_ended_at = now
        if not (self.reader.queue.empty() and not self.pending):
            return False
        since = now - max(self.camera_ended_at, self.last_arrival or 0.0)
        if since <= QUIET_END_S:
            return False
        if self.last_arrival is None:
            self.stats.end_reason = (f"the camera ended and no eye data ever arrived from {self.serial_port} "
                                     f"(check --serial and --baud, and that the recorder is sending)")
        else:
            self.stats.end_reason = "the camera ended"
        return True

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
                arrival, t_s, rec = self.reader.queue.get_nowait()
            except queue.Empty:
                break
            busy = True
            self.last_arrival = arrival
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
        if (self.last_est is not None and self.fix_t0 is not None
                and self.last_est[1] - self.fix_t0 >= self.fix.config.min_fixation_s):
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
        s = self.update_stats()
        lat = np.percentile(list(s.latencies_ms), 95) if s.latencies_ms else float("nan")
        cur = "-" if self.last_est is None else "(" + ", ".join(f"{v:.0f}" for v in self.last_est[0].position_mm) + ")"
        self.status_stream.write(f"\r{s.counters()}  markers {self.markers_in_view}  p95 latency {lat:.1f} ms  "
                                 f"target {cur} mm   ")
        self.status_stream.flush()

    def _close(self, complete: bool = True):
        self.reader.stop()
        self.frames.stop()
        for th in (self.reader, self.frames):
            if th.ident is not None:
                th.join(2.0)
        self.publisher.close()
        if self.recorder is not None:
            self.recorder.close(complete=complete)
        self.update_stats()


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


