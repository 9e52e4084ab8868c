"""The live wearable session (docs/live.md): eye samples from the serial line and frames from
the scene camera, head tracking, view lines, online fixation detection and a streaming
estimator; every estimate and target published as JSON lines; everything recorded as a
session folder that ``process`` reads.

The parts, each in its module and tested alone: the input readers (``serial_in``,
``camera_in``), the session clock (``clock``), head tracking (``head``), estimation
(``estimation``), the messages (``messages``), publishing (``publish``), recording
(``record``); the loop that composes them (``loop``). ``open_session`` loads the files, builds
the parts and wires them; ``run_live`` runs the session as the CLI does."""

from __future__ import annotations

import logging
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

from ..errors import UserError
from ..formats.camera import load_camera
from ..formats.eyes import load_eyes
from ..formats.markermap import load_marker_map
from ..pipeline.steps.live_estimation import GazeEstimation, warm_up
from .allocator import bound_heap
from .camera_in import FrameSource
from .clock import SessionClock
from .head import HeadTracker
from .loop import LiveSession
from .publish import Publisher
from .record import Recorder
from .serial_in import EyeReader
from .stats import LiveStats
from .viewer import RerunViewer

log = logging.getLogger(__name__)

__all__ = ["LiveSession", "LiveStats", "open_session", "run_live", "run_session"]


def _stamp_and_record(clock: SessionClock, recorder: Recorder | None):
    """The eye reader's ``on_record``: in the reader's thread, for every intact record, its
    session time, and the record kept (before any queue that could drop it)."""
    def on_record(arrival, rec):
        t_s = clock.map(arrival, rec.t)
        if recorder is not None:
            recorder.eye_sample(t_s, rec)
        return arrival, t_s, rec
    return on_record


def _open_camera(camera_source: str, camera) -> FrameSource:
    try:
        frames = FrameSource(camera_source)
    except OSError as exc:
        raise UserError(str(exc)) from None
    if tuple(frames.size) != tuple(camera.image_size):
        frames.cap.release()
        raise UserError(f"camera {camera_source} gives {frames.size[0]}x{frames.size[1]} frames but the "
                        f"calibration is for {camera.image_size[0]}x{camera.image_size[1]}")
    return frames


def open_session(serial_port: str, camera_source: str, camera_calib, eyes_path, markers_path, record=None,
                 publish=None, baud: int = 115200, method: str = "voxel", stdout: bool = True, status_stream=None,
                 hold_s: float = 0.05, stream=None, publish_queue: int = 1000,
                 publish_stuck_s: float = 5.0, rerun=None) -> LiveSession:
    """Load the calibrations and the marker map, open the camera, the publisher and the
    recording, and wire the parts into a ``LiveSession`` (the serial port opens when it runs).

    Args:
        serial_port: ``--serial``; camera_source: ``--camera``; camera_calib, eyes_path,
            markers_path: the calibration and marker-map files; record: the recording folder or
            None; publish: the ``--publish`` URL or None; baud: serial speed; method: the
            estimator; stdout, stream: publish to ``stream`` (default stdout) too; hold_s: see
            ``HeadTracker``; publish_queue, publish_stuck_s: see ``publish.Subscriber``;
            rerun: ``--rerun``'s value (an .rrd file, a viewer's address, 'spawn') or None
            (``viewer.RerunViewer``).

    Raises:
        UserError: a file that is missing or malformed, a camera that will not open or does not
            match its calibration, a bad ``--publish`` URL, a ``--record`` folder not empty.
    """
    bound_heap()                     # before the session's threads start (allocator.py)
    camera = load_camera(camera_calib)
    eyes = load_eyes(eyes_path)
    marker_map = load_marker_map(markers_path)
    frames = _open_camera(camera_source, camera)
    opened = _Opened(frames)
    try:
        opened.publisher = Publisher(publish, stdout, stream, maxsize=publish_queue,
                                     stuck_s=publish_stuck_s)
        opened.viewer = RerunViewer(rerun, camera, marker_map) if rerun is not None else None
        recorder = (Recorder(Path(record), frames.size, frames.fps, camera_calib, eyes_path, marker_map)
                    if record else None)
        opened.recorder = recorder
        if recorder is not None:
            frames.sink = recorder.frame              # every captured frame, even those tracking skips
        clock = SessionClock(lambda: frames.t0)
        reader = EyeReader(serial_port, baud, raw_sink=recorder.raw_bytes if recorder else None,
                           on_record=_stamp_and_record(clock, recorder))
        head = HeadTracker.for_map(marker_map, camera, hold_s)
        warm_up(method)
        estimation = GazeEstimation(eyes, method)
    except BaseException:
        opened.close()
        raise
    return LiveSession(reader, frames, head, estimation, opened.publisher, recorder, status_stream,
                       opened.viewer)


@dataclass
class _Opened:
    """What ``open_session`` has opened so far, closed in this order when a later part fails."""
    frames: FrameSource
    publisher: Publisher | None = None
    viewer: RerunViewer | None = None
    recorder: Recorder | None = None

    def close(self) -> None:
        """Close the publisher, the viewer, the (incomplete) recording and the camera."""
        if self.publisher is not None:
            self.publisher.close(0.1)
        if self.viewer is not None:
            self.viewer.close(0.1)
        if self.recorder is not None:
            self.recorder.close(complete=False)
        self.frames.cap.release()


def run_live(serial_port, camera_source, camera_calib, eyes_path, markers_path, record=None, publish=None,
             baud: int = 115200, duration_s=None, status_stream=None, rerun=None) -> LiveStats:
    """``wearable-gaze live``: run until the camera file ends, the duration passes, Ctrl-C or
    SIGTERM; everything recorded stays complete."""
    session = open_session(serial_port, camera_source, camera_calib, eyes_path, markers_path, record, publish, baud,
                           status_stream=status_stream, rerun=rerun)
    return run_session(session, duration_s)


def run_session(session: LiveSession, duration_s=None) -> LiveStats:
    """Run an opened session until it ends, ``duration_s`` passes, Ctrl-C or SIGTERM (caught
    while it runs, in the main thread)."""
    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, session.stop)
    try:
        return session.run(duration_s)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
