"""The live session from a networked eye tracker (``live --device``, docs/live.md, "Devices"):
the device's eye rays and scene frames into the same loop, head tracking, estimation, publishing
and recording as the serial input (``app``). The device calibrated the eyes: its rays (head
frame) are the view lines (``estimation.RayEyes``), so no eyes.json is read; the recording
holds them as ``eye_rays.csv``, which ``process`` reads as an imported session's."""

from __future__ import annotations

import logging
from pathlib import Path

from ..errors import UserError
from ..formats.camera import load_camera
from ..formats.markermap import load_marker_map
from ..pipeline.steps.live_estimation import GazeEstimation, RayEyes, warm_up
from . import pupil_core_in
from .allocator import bound_heap
from .app import run_session
from .head import MAX_WAIT_S, HeadTracker, TrackingThread
from .loop import LiveSession
from .publish import Publisher
from .record import Recorder
from .stats import LiveStats
from .target_process import RemoteTargets
from .track_process import RemoteTracker
from .viewer import RerunViewer

log = logging.getLogger(__name__)

DEVICES = ("pupil-core", "neon")
"""The ``--device`` schemes ``live`` reads (``SCHEME://HOST:PORT``)."""
RECORDED_AS = {"pupil-core": "pupil-core", "neon": "pupil-neon"}
"""The device a recording's manifest names (the importers' names: ``formats.devices.MODULES``)."""


def _reader_module(name: str):
    """The module with the device's ``open_link``, ``probe_frames``, ``GazeReader``, ``WorldFrames``."""
    if name == "neon":
        from . import neon_in
        return neon_in
    return pupil_core_in


def device_scheme(url: str) -> str:
    """The device named by ``--device`` (the URL's scheme).

    Raises:
        UserError: a scheme ``live`` does not read.
    """
    scheme = url.split("://", 1)[0] if "://" in url else ""
    if scheme not in DEVICES:
        raise UserError(f"--device {url}: expected pupil-core://HOST:PORT or neon://HOST[:PORT] (docs/live.md)")
    return scheme


def _start_processes(method: str, marker_map, camera) -> tuple[RemoteTargets, RemoteTracker]:
    """The target process and the tracking process, started together (each takes a second or more
    to import its libraries), once both are ready."""
    targets = RemoteTargets(method)
    try:
        remote = RemoteTracker(marker_map, camera)
    except BaseException:
        targets.close()
        raise
    try:
        targets.ready()
    except BaseException:
        remote.close()
        raise
    return targets, remote


def open_device_session(device_url: str, camera_calib, markers_path, record=None, publish=None,
                        method: str = "voxel", stdout: bool = True, status_stream=None, hold_s: float = 0.05,
                        stream=None, publish_queue: int = 1000, publish_stuck_s: float = 5.0,
                        rerun=None) -> tuple[LiveSession, object]:
    """Connect to the device, check its scene frames against the camera calibration, open the
    publisher and the recording, and wire the parts into a ``LiveSession``; returns it with the
    device link (closed by the caller once the session has run: ``run_device_live``). The
    arguments are ``app.open_session``'s.

    Raises:
        UserError: a bad ``--device``, a device that does not answer or sends no scene frame,
            frames of another size than the calibration's, a bad file or ``--publish``, a
            ``--record`` folder not empty.
    """
    bound_heap()                     # before the session's threads start (allocator.py)
    name = device_scheme(device_url)
    camera = load_camera(camera_calib)
    marker_map = load_marker_map(markers_path)
    warm_up(method)                        # before connecting: the device streams meanwhile
    dev = _reader_module(name)
    targets, remote = _start_processes(method, marker_map, camera)     # ... and the two processes' start
    closers = [targets.close, remote.close]
    try:
        link = dev.open_link(device_url, camera) if name == "neon" else dev.open_link(device_url)
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    closers.append(link.close)
    try:
        size, fps = dev.probe_frames(link)
        if tuple(size) != tuple(camera.image_size):
            raise UserError(f"--device {device_url} sends {size[0]}x{size[1]} scene frames but the calibration is for "
                            f"{camera.image_size[0]}x{camera.image_size[1]}; calibrate that camera at that resolution")
        publisher = Publisher(publish, stdout, stream, maxsize=publish_queue, stuck_s=publish_stuck_s)
        closers.append(lambda: publisher.close(0.1))
        viewer = RerunViewer(rerun, camera, marker_map) if rerun is not None else None
        if viewer is not None:
            closers.append(lambda: viewer.close(0.1))
        recorder = (Recorder(Path(record), size, fps, camera_calib, None, marker_map, device=RECORDED_AS[name])
                    if record else None)
        if recorder is not None:
            closers.append(lambda: recorder.close(complete=False))
        frames = dev.WorldFrames(link, size, fps)
        if recorder is not None:
            frames.sink = recorder.frame
        reader = dev.GazeReader(link, on_record=recorder.eye_sample if recorder else None)
        head = HeadTracker.for_map(marker_map, camera, hold_s, max_age_s=MAX_WAIT_S)
        estimation = GazeEstimation([RayEyes(), RayEyes()], method)
        tracker = TrackingThread(frames, head, viewer.head if viewer is not None else None, remote,
                                 samples_waiting=lambda: reader.queue.qsize() > 0)
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    return (LiveSession(reader, frames, head, estimation, publisher, recorder, status_stream, viewer, tracker, targets),
            link)


def run_device_live(device_url: str, camera_calib, markers_path, record=None, publish=None, duration_s=None,
                    status_stream=None, rerun=None) -> LiveStats:
    """``wearable-gaze live --device``: run until the duration passes, Ctrl-C or SIGTERM;
    everything recorded stays complete."""
    session, link = open_device_session(device_url, camera_calib, markers_path, record, publish,
                                        status_stream=status_stream, rerun=rerun)
    try:
        return run_session(session, duration_s)
    finally:
        link.close()
