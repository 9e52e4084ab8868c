"""Head tracking in the live session (docs/live.md, The loop): the head pose of each tracked
scene frame (markers detected, pose computed: ``tracking``), and the pose at any eye sample's
time, SLERP between the frames around it or the last two frames' motion continued for a moment."""

from __future__ import annotations

import logging
from collections import deque

import numpy as np

from tracking.markers import MarkerDetector
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import extrapolate_pose, interpolate_poses

log = logging.getLogger(__name__)

MAX_GAP_S = 0.2         # no pose is interpolated between frames further apart than this, s
MAX_WAIT_S = 0.2        # a sample newer than the last frame waits for the next one at most this long, s


class HeadTracker:
    """The recent frames' head poses (``T_world_from_cam``, mm) and the pose at a sample's time.

    Args:
        detect: grey image (H, W) uint8 -> marker detections (``MarkerDetector.detect``).
        estimate: detections -> a ``tracking.pose.PoseResult`` (``MarkerPoseEstimator.estimate``).
        hold_s: a sample up to this much newer than the last frame need not wait for the next:
            its pose continues the last two frames' motion (``tracking.timeline.extrapolate_pose``;
            the last frame's own pose when there is no frame before it within ``MAX_GAP_S``), s.
        history: how many frames' poses are kept.
    """

    def __init__(self, detect, estimate, hold_s: float = 0.05, history: int = 120):
        self.detect = detect
        self.estimate = estimate
        self.hold_s = hold_s
        self.poses: deque = deque(maxlen=history)     # (t_s, T_world_from_cam) of recent frames, oldest first
        self.markers_in_view = 0                      # markers the last tracked frame's pose used

    @classmethod
    def for_map(cls, marker_map, camera, hold_s: float = 0.05) -> HeadTracker:
        """A tracker for a ``tracking.MarkerMap`` seen by a ``CameraCalibration``."""
        return cls(MarkerDetector(marker_map.dictionary).detect, MarkerPoseEstimator(marker_map, camera).estimate,
                   hold_s)

    def track(self, t_s: float, grey) -> bool:
        """Track one frame taken at session time ``t_s`` (s); True when it gave a pose."""
        res = self.estimate(self.detect(grey))
        self.markers_in_view = len(res.markers)
        if res.ok:
            self.poses.append((t_s, res.T_world_from_cam))
        return bool(res.ok)

    @property
    def last_t(self) -> float | None:
        """Time of the newest pose, s (None before the first)."""
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
        was off by about twice as much); None when there is no pose that near."""
        if not self.poses:
            return None
        t_last, T_last = self.poses[-1]
        if t_s >= t_last:
            if t_s - t_last > self.hold_s:
                return None
            if len(self.poses) > 1 and 0 < t_last - self.poses[-2][0] <= MAX_GAP_S and t_s > t_last:
                return extrapolate_pose(*self.poses[-2], t_last, T_last, t_s)
            return T_last
        for k in range(len(self.poses) - 2, -1, -1):
            ta, Ta = self.poses[k]
            if ta <= t_s:
                tb, Tb = self.poses[k + 1]
                if tb - ta > MAX_GAP_S:
                    return None
                T, ok = interpolate_poses([ta, tb], np.stack([Ta, Tb]), [t_s], max_gap_s=MAX_GAP_S)
                return T[0] if ok[0] else None
        return None
