"""Recording a live session as a session folder (docs/session.md, docs/live.md).

Every file is written as data arrive and flushed on one schedule (``flush_s``, at most 1 s) by
the recorder's own thread, together with the manifest and its counts (written atomically: a
temporary file, then ``os.replace``). A recording killed at any moment (even SIGKILL) therefore
loses at most the last ``flush_s`` of eye samples, raw bytes and messages, and ``process``
reads it; ``complete`` is true in the manifest only once the session was closed cleanly.
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import threading
from pathlib import Path

from ..errors import UserError
from ..formats.eye_rays import RAY_HEADER, ray_csv_lines
from ..formats.eye_samples import EYE_HEADER, eye_csv_line
from ..formats.markermap import marker_map_dict, write_marker_map
from ..formats.poses import POSE_HEADER, pose_csv_lines
from ..formats.session import FORMAT, VERSION, write_manifest
from ..formats.video import FRAME_TIME_HEADER, frame_time_line, open_video_writer

log = logging.getLogger(__name__)

FILES = {"scene_video": "scene.avi", "scene_timestamps": "scene_timestamps.csv", "eye_samples": "eye.csv",
         "eye_serial": "eye_serial.bin", "marker_map": "markers.json", "camera": "camera.json", "eyes": "eyes.json",
         "live_messages": "live.jsonl"}
DEVICE_FILES = {"scene_video": "scene.avi", "scene_timestamps": "scene_timestamps.csv", "eye_rays": "eye_rays.csv",
                "marker_map": "markers.json", "camera": "camera.json", "live_messages": "live.jsonl",
                "live_poses": "live_poses.csv"}
"""A device that gives eye rays (``live --device``): its rays, head frame, in place of the raw
readings, the serial bytes and the eye calibration; ``process`` reads it as an imported session.
``live_poses.csv`` (a pose CSV) holds the head pose the session gave each eye sample it estimated
from, at that sample's time (empty: none), which ``process`` takes in place of tracking the video
again, so that it re-runs on the poses the session used."""
_BUFFER = 1 << 20      # large enough that only the flush schedule writes (whole lines) to the files
VIDEO_NICE = 5
"""The video encoder thread's niceness above the session's: it encodes each flush period's frames
in one burst (15 at 30 fps, 1-3 ms each), during which a loop with samples waiting had half the
core; it still has all the core the gaze path leaves (its queue holds 2 s of frames)."""


class Recorder:
    """Writes everything received as a session folder.

    The camera thread calls ``frame``, the serial reader ``raw_bytes`` and ``eye_sample``, the
    loop ``message``; a thread of its own flushes every file and rewrites the manifest every
    ``flush_s`` seconds. ``close`` finishes the video and marks the manifest complete (or not).

    Args:
        root: the new session folder (must not exist or be empty).
        size: (width, height) of the frames, px; fps: their rate.
        camera_path, eyes_path: calibrations copied into the folder; marker_map: the map used.
        flush_s: the flush period, s (<= 1).
        device: the name of a device giving eye rays (``live --device``; ``eyes_path`` is then
            unused): ``eye_sample`` takes its ``RaySample``s and writes ``eye_rays.csv``; None:
            the serial recorder's raw readings (``eye.csv``) and bytes (``eye_serial.bin``).

    Raises:
        UserError: ``root`` exists and is not empty.
    """

    def __init__(self, root: Path, size, fps: float, camera_path, eyes_path, marker_map, flush_s: float = 0.5,
                 device: str | None = None):
        if not 0 < flush_s <= 1.0:
            raise ValueError(f"flush_s must be in (0, 1] s, got {flush_s!r}")
        self.root = Path(root)
        if self.root.exists() and any(self.root.iterdir()):
            raise UserError(f"--record {self.root}: already exists and is not empty; choose a new folder")
        self.root.mkdir(parents=True, exist_ok=True)
        self.device = device
        self.files = dict(FILES if device is None else DEVICE_FILES)
        shutil.copy(camera_path, self.root / FILES["camera"])
        if device is None:
            shutil.copy(eyes_path, self.root / FILES["eyes"])
        write_marker_map(self.root / FILES["marker_map"], marker_map_dict(
            marker_map.dictionary, marker_map.marker_size_mm, marker_map.poses, marker_map.labels,
            sizes=marker_map.sizes))
        self.video = open_video_writer(self.root / FILES["scene_video"], "MJPG", fps, size, is_color=False, refused=(
            f"--record {self.root}: OpenCV cannot write an MJPG video there; check that the folder is writable and "
            "that OpenCV has its FFMPEG backend"))
        # frames are encoded in their own thread (bounded: the live loop never waits on the disk)
        self.video_q: queue.Queue = queue.Queue(maxsize=60)
        self.video_thread = threading.Thread(target=self._video_worker, daemon=True, name="recorder-video")
        self.video_thread.start()
        self.ts = open(self.root / FILES["scene_timestamps"], "w", encoding="utf-8", buffering=_BUFFER)
        self.ts.write(FRAME_TIME_HEADER)
        eye_file = FILES["eye_samples"] if device is None else DEVICE_FILES["eye_rays"]
        self.eye = open(self.root / eye_file, "w", encoding="utf-8", buffering=_BUFFER)
        self.eye.write(EYE_HEADER if device is None else RAY_HEADER)
        self.raw = open(self.root / FILES["eye_serial"] if device is None else os.devnull, "wb", buffering=_BUFFER)
        self.messages = open(self.root / FILES["live_messages"], "wb", buffering=_BUFFER)
        self.poses = open(self.root / DEVICE_FILES["live_poses"] if device is not None else os.devnull, "w",
                          encoding="utf-8", buffering=_BUFFER)
        self.poses.write(POSE_HEADER)
        self.pose_rows: list = []        # (t, row, pose) of the sample poses since the last flush
        self.ray_rows: list = []         # (t, left, left valid, right, right valid) of a device's rays, likewise
        self.n_frames = self.n_eye = self.n_messages = self.n_poses = 0
        self.lock = threading.Lock()
        self.frames_flushed = 0          # frames whose timestamp rows have been flushed: the video may hold these
        self.timestamps_out = threading.Condition(self.lock)
        self.fps = fps
        self.size = size
        self.flush_s = flush_s
        self.closed = False
        self._write_manifest(complete=False)
        self._stop = threading.Event()
        self.flusher = threading.Thread(target=self._flush_loop, daemon=True, name="recorder-flush")
        self.flusher.start()

    # --- what the streams hand in --------------------------------------------------------------

    def raw_bytes(self, data: bytes) -> None:
        """Bytes as received on the serial line (garbage included)."""
        with self.lock:
            if not self.closed:
                self.raw.write(data)

    def eye_sample(self, t: float, rec) -> None:
        """One intact record at session time ``t``, s. A device's rays are kept and written by the
        next flush, the period's rows converted in one batch (one by one they cost its reader
        about 0.3 ms a sample at 200 Hz)."""
        if self.device is None:
            line = eye_csv_line(t, rec.counter, rec.left, rec.right, rec.left_valid, rec.right_valid)
        with self.lock:
            if not self.closed:
                if self.device is None:
                    self.eye.write(line)
                else:
                    self.ray_rows.append((t, rec.left, rec.left_valid, rec.right, rec.right_valid))
                self.n_eye += 1

    def frame(self, t: float, index: int, gray) -> None:
        """A captured frame at session time ``t``, s (the video thread encodes it once its
        timestamp row has been flushed, so that a killed recording's video holds no frame
        without a time)."""
        with self.lock:
            if self.closed:
                return
            self.ts.write(frame_time_line(index, t))
            self.n_frames += 1
        self.video_q.put(gray)

    def sample_pose(self, t: float, T_world_from_cam) -> None:
        """The head pose (4, 4) mm the session gave its eye sample at session time ``t``, s (None:
        it had none); kept, and written to ``live_poses.csv`` by the next flush, all the period's
        rows converted in one batch (one by one they cost the loop about 0.3 ms a sample)."""
        with self.lock:
            if not self.closed:
                self.pose_rows.append((t, self.n_poses, T_world_from_cam))
                self.n_poses += 1

    def message(self, line: bytes) -> None:
        """A published message, one encoded JSON line."""
        with self.lock:
            if not self.closed:
                self.messages.write(line)
                self.n_messages += 1

    # --- the schedule ----------------------------------------------------------------------------

    def _video_worker(self):
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(),
                           min(19, os.getpriority(os.PRIO_PROCESS, 0) + VIDEO_NICE))
        except (AttributeError, OSError):          # not on Linux: the same priority
            pass
        written = 0
        while True:
            item = self.video_q.get()
            if item is None:
                return
            with self.timestamps_out:
                self.timestamps_out.wait_for(lambda w=written: self.frames_flushed > w)
            self.video.write(item)
            written += 1

    def _flush_loop(self):
        while not self._stop.wait(self.flush_s):
            try:
                self.flush()
            except OSError as exc:                   # a full disk: say so once a period, keep going
                log.error("recording %s: cannot write (%s)", self.root, exc)

    def flush(self) -> None:
        """Every file to the OS, then the manifest with the counts written (atomically)."""
        with self.lock:
            if self.closed:
                return
            rows, self.pose_rows = self.pose_rows, []
            rays, self.ray_rows = self.ray_rows, []
        text = pose_csv_lines(*zip(*rows, strict=True)) if rows else ""      # outside the lock: the loop goes on
        ray_text = ray_csv_lines(*zip(*rays, strict=True)) if rays else ""
        with self.lock:
            if self.closed:
                return
            self.poses.write(text)
            self.eye.write(ray_text)
            for fh in (self.ts, self.eye, self.raw, self.messages, self.poses):
                fh.flush()
            self.frames_flushed = self.n_frames
            self.timestamps_out.notify_all()
            self._write_manifest(complete=False)

    def _write_manifest(self, complete: bool) -> None:
        man = {"format": FORMAT, "version": VERSION, "producer": "wearable-gaze live", "image_size": list(self.size),
               "fps": self.fps, "has_recording": True, "complete": complete,
               "files": dict(self.files), "n_frames": self.n_frames, "n_eye_samples": self.n_eye,
               "n_messages": self.n_messages}
        if self.device is not None:      # read as an imported session: poses tracked in the scene video
            man["source"] = {"device": self.device, "clock_offset_s": 0.0, "pose_source": "scene_video"}
        write_manifest(self.root, man)

    def close(self, complete: bool = True) -> None:
        """Finish the video and every file; the manifest says ``complete`` only when the session
        ended cleanly."""
        self._stop.set()
        self.flusher.join(2.0)
        self.flush()
        self.video_q.put(None)
        self.video_thread.join()
        self.video.release()
        with self.lock:
            for fh in (self.ts, self.eye, self.raw, self.messages, self.poses):
                fh.close()
            self.closed = True
            self._write_manifest(complete=complete)
