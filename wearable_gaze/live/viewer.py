"""``live --rerun``: the live session drawn in rerun (docs/viewing.md), a subscriber beside the
JSON ones of ``publish``: its own bounded queue and sender thread, so that a slow viewer never
holds up the loop (when the queue is full the oldest item is dropped, counted).

It is fed the same events as the publisher (every message, for the running estimates) and
two the JSON lines do not carry: each tracked frame's head pose, and each finished fixation's
target with its view lines and covariance. The logging itself is ``pipeline.report.rerun_view``'s.
"""

from __future__ import annotations

import logging

from .publish import Subscriber

log = logging.getLogger(__name__)


class RerunViewer(Subscriber):
    """Items in (``head``, ``message``, ``target``), rerun records out.

    Args:
        dest: ``--rerun``'s value: an .rrd file, a viewer's address, or None / 'spawn'.
        camera: the scene camera's ``CameraCalibration``; marker_map: the ``tracking.MarkerMap``.
        maxsize: queue length in items.

    Raises:
        UserError: rerun-sdk missing, or a bad ``dest``.
    """

    def __init__(self, dest, camera=None, marker_map=None, maxsize: int = 5000):
        super().__init__("rerun", maxsize=maxsize)
        from ..pipeline.report.rerun_view import log_scene, open_recording

        self.rec = open_recording(dest, "wearable-gaze live")
        log_scene(self.rec, camera, marker_map)
        self.start()

    def head(self, t_s: float, T_world_from_cam) -> None:
        """A tracked frame's head pose (4, 4) at session time ``t_s``."""
        self.put(("head", t_s, T_world_from_cam))

    def message(self, msg: dict) -> None:
        """A message as published (``messages``): its running estimate is drawn."""
        self.put(("message", msg))

    def target(self, target, lines) -> None:
        """A finished fixation's ``Target`` and its lines (``BinocularSample`` list, world frame)."""
        self.put(("target", target, lines))

    def _send(self, batch) -> None:
        from ..pipeline.report.rerun_view import log_estimate, log_head_pose, log_target
        from ..pipeline.steps.live_estimation import lines_to_samples

        for item in batch:
            try:
                self._log(item, log_estimate, log_head_pose, log_target, lines_to_samples)
            except Exception as exc:  # the viewer is disconnected, the session goes on
                log.debug("rerun logging failed", exc_info=True)
                raise OSError(f"{type(exc).__name__}: {exc}") from None

    def _log(self, item, log_estimate, log_head_pose, log_target, lines_to_samples) -> None:
        if item[0] == "head":
            log_head_pose(self.rec, item[1], item[2])
        elif item[0] == "message" and item[1].get("type") == "estimate":
            m = item[1]
            log_estimate(self.rec, m["t"], m["position_mm"], m["fixation"])
        elif item[0] == "target":
            target, lines = item[1], item[2]
            log_target(self.rec, target, lines_to_samples(lines) if lines else None,
                       path=f"world/targets/{target.index}/fixation_{target.fixations[0]}")

    def _close_transport(self) -> None:
        from ..errors import UserError
        from ..pipeline.report.rerun_view import close_recording

        try:
            close_recording(self.rec, timeout_s=self.stuck_s)
        except UserError as exc:
            log.warning("%s", exc)
