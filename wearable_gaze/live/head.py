"""Head tracking in the live session (docs/live.md, The loop): the head pose of each tracked
scene frame (markers detected, pose computed: ``tracking``), and the pose at any eye sample's
time, SLERP between the frames around it or the last two frames' motion continued for a moment."""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections import deque

import numpy as np

from tracking.markers import MarkerDetector
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import extrapolate_pose, pose_between

log = logging.getLogger(__name__)

MAX_GAP_S = 0.2         # no pose is interpolated between frames further apart than this, s
MAX_WAIT_S = 0.2        # a sample newer than the last frame waits for the next one at most this long, s
TRACK_NICE = 5          # the tracking thread's niceness above the session's (TrackingThread)
YIELD_MAX_S = 0.1       # a frame waits at most this long for the eye samples' backlog to clear (TrackingThread)


class HeadTracker:
    """The recent frames' head poses (``T_world_from_cam``, mm) and the pose at a sample's time.

    Args:
        detect: grey image (H, W) uint8 -> marker detections (``MarkerDetector.detect``).
        estimate: detections -> a ``tracking.pose.PoseResult`` (``MarkerPoseEstimator.estimate``).
        hold_s: a sample up to this much newer than the last frame need not wait for the next:
            its pose continues the last two frames' motion (``tracking.timeline.extrapolate_pose``;
            the last frame's own pose when there is no frame before it within ``MAX_GAP_S``), s.
        history: how many frames' poses are kept.
        max_age_s: a sample up to this much newer than the last frame still gets a pose: the
            motion continued for ``hold_s``, then held (None: ``hold_s``; a device session, whose
            samples never wait for a frame, ``MAX_WAIT_S``), s.

    ``track`` may run in one thread (``TrackingThread``) while ``pose_at`` runs in another.
    """

    def __init__(self, detect, estimate, hold_s: float = 0.05, history: int = 120, max_age_s: float | None = None):
        self.detect = detect
        self.estimate = estimate
        self.hold_s = hold_s
        self.max_age_s = hold_s if max_age_s is None else max(max_age_s, hold_s)
        self.poses: deque = deque(maxlen=history)     # (t_s, T_world_from_cam) of recent frames, oldest first
        self.markers_in_view = 0                      # markers the last tracked frame's pose used
        self.lock = threading.Lock()                  # poses: appended by the tracker, read by the loop

    @classmethod
    def for_map(cls, marker_map, camera, hold_s: float = 0.05, max_age_s: float | None = None) -> HeadTracker:
        """A tracker for a ``tracking.MarkerMap`` seen by a ``CameraCalibration``."""
        return cls(MarkerDetector(marker_map.dictionary).detect, MarkerPoseEstimator(marker_map, camera).estimate,
                   hold_s, max_age_s=max_age_s)

    def track(self, t_s: float, gray) -> bool:
        """Track one frame taken at session time ``t_s`` (s); True when it gave a pose."""
        res = self.estimate(self.detect(gray))
        return self.add(t_s, bool(res.ok), res.T_world_from_cam, len(res.markers))

    def add(self, t_s: float, ok: bool, T_world_from_cam, n_markers: int) -> bool:
        """A frame at session time ``t_s`` (s) tracked elsewhere (``track_process``): whether it
        gave a pose, the pose (4, 4) mm, the markers it used; returns ``ok``."""
        self.markers_in_view = n_markers
        if ok:
            with self.lock:
                self.poses.append((t_s, T_world_from_cam))
        return ok

    @property
    def last_t(self) -> float | None:
        """Time of the newest pose, s (None before the first)."""
        with self.lock:
            return self.poses[-1][0] if self.poses else None

    def must_wait(self, t_s: float, age_s: float) -> bool:
        """Whether a sample at ``t_s`` that arrived ``age_s`` ago should wait for the next frame:
        it is newer than the last pose can be held, and has not waited ``MAX_WAIT_S`` yet."""
        last = self.last_t
        return last is not None and t_s > last + self.hold_s and age_s < MAX_WAIT_S

    def pose_at(self, t_s: float) -> np.ndarray | None:
        """``T_world_from_cam`` (4, 4) at session time ``t_s``: SLERP between the two frames
        around it (``tracking.timeline.interpolate_poses``), or up to ``hold_s`` past the last
        frame the last two frames' motion continued (docs/live.md: under load, a held pose
        was off by about twice as much), and from there up to ``max_age_s`` held; None when there
        is no pose that near."""
        with self.lock:
            poses = list(self.poses)[-3:] if self.poses and t_s >= self.poses[-1][0] else list(self.poses)
        if not poses:
            return None
        t_last, T_last = poses[-1]
        if t_s >= t_last:
            if t_s - t_last > self.max_age_s:
                return None
            t_to = min(t_s, t_last + self.hold_s)
            if len(poses) > 1 and 0 < t_last - poses[-2][0] <= MAX_GAP_S and t_to > t_last:
                return extrapolate_pose(*poses[-2], t_last, T_last, t_to)
            return T_last
        for k in range(len(poses) - 2, -1, -1):
            ta, Ta = poses[k]
            if ta <= t_s:
                tb, Tb = poses[k + 1]
                if tb - ta > MAX_GAP_S:
                    return None
                return pose_between(ta, Ta, tb, Tb, t_s)     # SLERP, as interpolate_poses
        return None


class TrackingThread(threading.Thread):
    """The scene frames tracked outside the loop's thread (a device session, docs/live.md, The
    loop), so that no eye sample waits behind a frame's marker detection: the newest waiting
    frame is tracked, older ones are skipped (``skipped``; every frame is still recorded); the
    poses it gives are the newest the samples can use. With ``remote`` (a
    ``track_process.RemoteTracker``) the frame goes to the tracking process and this thread only
    waits for its answer; without, it is tracked here, in a thread ``TRACK_NICE`` nicer than the
    session's (it still shares the interpreter's lock with the loop).

    Args:
        frames: the camera (``queue`` of ``(t_monotonic_s, index, grey, colour)``, ``t0``).
        head: the ``HeadTracker`` it feeds; on_pose: called with (t_s, T) after each pose, or None.
        remote: the tracking process (closed with the thread: ``close``), or None.
        samples_waiting: () -> whether eye samples wait for the loop; a frame is not started
            while they do (for at most ``YIELD_MAX_S``, so that poses do not go stale): on a
            core too busy for both, the samples go first. None: frames never wait.
    """

    def __init__(self, frames, head: HeadTracker, on_pose=None, remote=None, samples_waiting=None):
        super().__init__(name="tracking", daemon=True)
        self.frames, self.head, self.on_pose, self.remote = frames, head, on_pose, remote
        self.samples_waiting = samples_waiting
        self.skipped = 0                  # frames passed over for a newer one
        self.tracked = 0
        self.busy = False                 # a frame taken and not yet tracked
        self.failure: str | None = None
        self.stop_event = threading.Event()

    def stop(self) -> None:
        self.stop_event.set()

    def close(self) -> None:
        """End the tracking process, if any (after ``stop`` and a join)."""
        if self.remote is not None:
            self.remote.close()

    def _track(self, t_s: float, gray) -> bool:
        if self.remote is None:
            return self.head.track(t_s, gray)
        return self.head.add(t_s, *self.remote.track(gray))

    def run(self) -> None:
        try:
            if self.remote is not None:
                raise AttributeError           # the process is the nicer one
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(),
                           min(19, os.getpriority(os.PRIO_PROCESS, 0) + TRACK_NICE))
        except (AttributeError, OSError):          # not on Linux: the same priority
            pass
        try:
            while not self.stop_event.is_set():
                try:
                    item = self.frames.queue.get(timeout=0.05)
                except queue.Empty:
                    continue
                self.busy = True
                if self.samples_waiting is not None:
                    end = time.monotonic() + YIELD_MAX_S
                    while self.samples_waiting() and time.monotonic() < end:
                        time.sleep(0.002)
                while True:
                    try:
                        item = self.frames.queue.get_nowait()
                        self.skipped += 1
                    except queue.Empty:
                        break
                t = item[0] - self.frames.t0
                if self._track(t, item[2]) and self.on_pose is not None:
                    self.on_pose(*self.head.poses[-1])
                self.tracked += 1
                self.busy = False
        except Exception as exc:
            log.debug("the tracking thread failed", exc_info=True)
            self.failure = f"{type(exc).__name__}: {exc}"
