"""Head tracking in a process of its own (a device session, docs/live.md, The loop): the scene
frames' marker detection and pose, which take most of a core at 30 fps, run where they share no
interpreter lock with the eye samples' thread; on a busy core the frames wait (the newest wins),
the eye samples do not.

``RemoteTracker.track(grey)`` sends one grey frame (its bytes through a pipe) and waits for its
pose; ``TrackingThread`` calls it for the newest waiting frame, one at a time.
"""

from __future__ import annotations

import numpy as np

from . import served

NICE = 0
"""The tracking process's niceness above the session's. 0: the scheduler already serves the eye
samples' thread first (it sleeps between samples, and a waking task preempts one that has run
long); at 5 the process starved under other work on the machine (load 18 on 2 cores: 55 of 379
samples of tests/test_live_pupil_core.py's session had a pose)."""


def _serve(conn, marker_map, camera, nice: int) -> None:
    """The tracking process: (shape) and frame bytes in; (ok, T_world_from_cam (4, 4) or None,
    markers used) out, until a None."""
    served.renice(nice)
    from tracking.markers import MarkerDetector
    from tracking.pose import MarkerPoseEstimator

    detect, estimate = MarkerDetector(marker_map.dictionary).detect, MarkerPoseEstimator(marker_map, camera).estimate
    conn.send("ready")
    while (shape := conn.recv()) is not None:
        gray = np.frombuffer(conn.recv_bytes(), np.uint8).reshape(shape)
        res = estimate(detect(gray))
        conn.send((bool(res.ok), res.T_world_from_cam if res.ok else None, len(res.markers)))


class RemoteTracker:
    """A tracking process for ``marker_map`` seen by ``camera`` (started here: a fresh
    interpreter, so that no thread of this one is copied).

    Raises:
        RuntimeError: the process did not start within ``served.START_TIMEOUT_S``.
    """

    def __init__(self, marker_map, camera, nice: int = NICE):
        self.proc, self.conn = served.start(_serve, (marker_map, camera, nice), "wearable-gaze-tracking")
        if not served.ready(self.conn):
            self.close()
            raise RuntimeError(served.NOT_STARTED.format("head-tracking"))

    def track(self, gray) -> tuple[bool, np.ndarray | None, int]:
        """(pose found, ``T_world_from_cam`` (4, 4) mm or None, markers used) of one grey frame
        (H, W) uint8."""
        gray = np.ascontiguousarray(gray, np.uint8)
        self.conn.send(gray.shape)
        self.conn.send_bytes(memoryview(gray).cast("B"))
        return self.conn.recv()

    def close(self) -> None:
        """End the process (at once if it is inside a frame)."""
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.proc.join(1.0)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(1.0)
        self.conn.close()
