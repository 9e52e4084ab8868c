"""What every device importer shares: ``SessionImport``, the writer of an imported session
folder (docs/session.md, "Imported sessions"; docs/importers.md), and ``read_simulated_recording``,
which each device module's writer uses to export a simulated session in the device's format (the
round-trip tests).

An importer streams: it reads the device's files in chunks and appends each chunk of eye rays
(head frame), head poses and device gaze to the session as it goes, so memory stays flat in the
recording's length. Every sample it cannot use is counted with its reason (``drop``) in
``import_report.json``; ``session.json`` is written last, so a folder without it is an import
that did not finish.
"""

from __future__ import annotations

import logging
import os
import shutil
from collections import Counter
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.lines import BinocularSamples
from tracking.timeline import interpolate_poses

from ... import __version__
from ...errors import UserError
from .. import eye_rays as rays_fmt
from ..camera import camera_dict, load_camera, write_camera
from ..eye_samples import read_eye_csv
from ..jsonio import load_json, read_json_text, write_json
from ..poses import POSE_COLUMNS, POSE_FORMATS, pose_columns, read_poses_csv
from ..session import FORMAT, VERSION, write_manifest
from ..tables import TableWriter, read_table
from ..video import read_frame_times, write_frame_times

log = logging.getLogger(__name__)

POSE_SOURCES = ("device", "scene_video", "still_head")
REPORT = "import_report.json"


@dataclass(frozen=True)
class ImportOptions:
    """What the user may add to an import (``wearable-gaze import`` options).

    Attributes:
        markers: a marker map (markers.json) of the room, for head poses tracked in the scene
            video by ``process`` when the device has no poses of its own.
        camera: a camera file to use instead of the device's scene-camera calibration.
        marker_size_mm: the printed marker side, mm (Pupil Core's head-pose model is in
            marker-side units).
        kappa_recording: a recording of known targets, to estimate the visual-axis offset
            (Neon).
        max_pose_gap_s: an eye sample with no device pose within this is dropped, s.
    """

    markers: Path | None = None
    camera: Path | None = None
    marker_size_mm: float | None = None
    kappa_recording: Path | None = None
    max_pose_gap_s: float = 0.05


class SessionImport:
    """Writes one imported session into an empty folder ``out``.

    Use as a context manager; on an error the partial folder is left without ``session.json``
    (and ``process`` refuses it). Between, call ``add_rays`` (required), and as the device gives
    them ``add_head_poses``, ``add_device_gaze``, ``set_camera``, ``add_scene_video``,
    ``set_marker_map``, ``count``/``drop``/``note``; then ``finish``.

    Args:
        out: the session folder (created; must not hold a session already).
        device: the format name ('aria-mps', 'tobii-g2', ...).
        source: the recording imported, for the manifest and report.
    """

    def __init__(self, out, device: str, source):
        self.out = Path(out)
        self.device = device
        self.source = Path(source)
        self.read = Counter()          # stream -> records read
        self.dropped = Counter()       # reason -> samples dropped
        self.notes: list[str] = []
        self.files: dict[str, str] = {}
        self.n_rays = 0
        self._t_last = {}
        self._stack = ExitStack()
        self._rays = self._poses = self._gaze = None

    def __enter__(self) -> SessionImport:
        self.out.mkdir(parents=True, exist_ok=True)
        self._rays = self._stack.enter_context(rays_fmt.EyeRaysWriter(self.out / "eye_rays.csv"))
        self.files["eye_rays"] = "eye_rays.csv"
        return self

    def __exit__(self, exc_type, exc, tb):
        return self._stack.__exit__(exc_type, exc, tb)

    # --- streams ----------------------------------------------------------------------------

    def _increasing(self, name: str, t: np.ndarray) -> None:
        if len(t) and (np.any(np.diff(t) <= 0) or t[0] <= self._t_last.get(name, -np.inf)):
            raise ValueError(f"{name}: times must increase across chunks (the importer must sort them)")
        if len(t):
            self._t_last[name] = float(t[-1])

    def add_rays(self, t, left_origin_mm, left_direction, left_valid, right_origin_mm, right_direction,
                 right_valid) -> None:
        """Append n eye samples: t (n,) s on the session clock, increasing; per eye the centre
        (n, 3) mm and direction (n, 3) in the head frame (OpenCV axes), and valid (n,) bool."""
        t = np.asarray(t, float).reshape(-1)
        self._increasing("eye rays", t)
        self._rays.add(t, left_origin_mm, left_direction, left_valid, right_origin_mm, right_direction, right_valid)
        self.n_rays += len(t)

    def add_head_poses(self, t, T_world_from_head) -> None:
        """Append n head poses from the device: t (n,) s, ``T_world_from_head`` (n, 4, 4), mm,
        our axes (NaN: no pose). Written to ``head_poses.csv`` in the pose-CSV format."""
        t = np.asarray(t, float).reshape(-1)
        self._increasing("head poses", t)
        if self._poses is None:
            self._poses = self._stack.enter_context(TableWriter(self.out / "head_poses.csv", POSE_COLUMNS,
                                                                POSE_FORMATS))
            self.files["head_poses"] = "head_poses.csv"
        start = self._poses.n_rows
        self._poses.write(pose_columns(t, np.arange(start, start + len(t)), T_world_from_head))

    def add_device_gaze(self, t, points_mm) -> None:
        """Append the device's own 3D gaze: t (n,) s, points (n, 3) mm, head frame (NaN: none)."""
        t = np.asarray(t, float).reshape(-1)
        self._increasing("device gaze", t)
        if self._gaze is None:
            self._gaze = self._stack.enter_context(rays_fmt.DeviceGazeWriter(self.out / "device_gaze.csv"))
            self.files["device_gaze"] = "device_gaze.csv"
        self._gaze.add(t, points_mm)

    # --- other files ------------------------------------------------------------------------

    def set_camera(self, camera_matrix, dist_coeffs, image_size, model: str = "pinhole", **extra) -> None:
        """The scene camera's intrinsics from the device's calibration: ``camera.json``."""
        write_camera(self.out / "camera.json", camera_dict(camera_matrix, dist_coeffs, image_size, model,
                                                           source=f"{self.device} calibration", **extra))
        self.files["camera"] = "camera.json"

    def add_scene_video(self, video, frame_times_s) -> None:
        """Link (or, across file systems, copy) the scene video in as ``scene<ext>`` and write
        ``scene_timestamps.csv`` (frame times on the session clock, s, increasing)."""
        video = Path(video)
        dst = self.out / f"scene{video.suffix.lower()}"
        try:                                    # an hour of video: a second name, not a second copy
            os.link(video, dst)
        except OSError:                         # another file system, or links not allowed
            shutil.copyfile(video, dst)
        t = np.asarray(frame_times_s, float)
        write_frame_times(self.out / "scene_timestamps.csv", np.arange(len(t)), t)
        self.files["scene_video"] = dst.name
        self.files["scene_timestamps"] = "scene_timestamps.csv"

    def keep_device_file(self, path, key: str) -> None:
        """Copy a device stream the session does not use (Tobii G3 ``imudata.gz``) in unchanged as
        ``device/<name>``, named in the manifest's ``files.<key>``."""
        path = Path(path)
        (self.out / "device").mkdir(exist_ok=True)
        shutil.copyfile(path, self.out / "device" / path.name)
        self.files[key] = f"device/{path.name}"

    def add_device_points(self, points_mm) -> None:
        """The device's own map of the room (Aria's semi-dense SLAM points): (P, 3) world frame,
        mm -> ``device_points.ply`` (vertices only), drawn in the report's 3D view."""
        from ..ply import PlyMesh, write_ply

        pts = np.asarray(points_mm, float).reshape(-1, 3)
        write_ply(self.out / "device_points.ply", PlyMesh(pts, np.full((len(pts), 3), 128, np.uint8),
                                                          comments=["the device's map points (its SLAM)"]))
        self.files["device_points"] = "device_points.ply"

    def add_device_events(self, t, rows) -> None:
        """The device's own events (sync-port pulses): t (n,) s on the session clock, in order,
        and per event (type, direction, value) -> ``device_events.csv``."""
        t = np.asarray(t, float).reshape(-1)
        cols = {"t": t, "type": np.array([r[0] for r in rows], object),
                "direction": np.array([r[1] for r in rows], object),
                "value": np.array([str(r[2]) for r in rows], object)}
        with TableWriter(self.out / "device_events.csv", tuple(cols), {"t": ".6f"}) as w:
            w.write(cols)
        self.files["device_events"] = "device_events.csv"

    def set_marker_map(self, path) -> None:
        """Copy a marker map (checked) in as ``markers.json``."""
        load_json(path, "marker-map")
        shutil.copyfile(path, self.out / "markers.json")
        self.files["marker_map"] = "markers.json"

    def count(self, stream: str, n: int = 1) -> None:
        """``n`` records read from ``stream`` (for the report)."""
        self.read[stream] += int(n)

    def drop(self, reason: str, n: int = 1) -> None:
        """``n`` samples not used, and why (one short phrase per reason: counts add up)."""
        if n:
            self.dropped[reason] += int(n)

    def note(self, text: str) -> None:
        """A fact about the import the report must say (a fallback taken, a swap detected)."""
        log.info("%s: %s", self.device, text)
        self.notes.append(text)

    def finish(self, eye_rate_hz: float, clock_offset_s: float, pose_source: str, frames: dict,
               image_size=None, fps=None, **extra) -> dict:
        """Close the streams, write ``import_report.json`` then ``session.json``; return the manifest.

        Args:
            eye_rate_hz: the device's eye-sample rate.
            clock_offset_s: t_session = t_device - clock_offset_s (the device clock's reading,
                s, at session time 0).
            pose_source: 'device', 'scene_video' (tracked by ``process``) or 'still_head'.
            frames: how each device frame was mapped to ours, in words and matrices.
            extra: further report entries (``kappa``, ``eye_labels``, ...).

        Raises:
            UserError: no usable eye sample was found.
        """
        if pose_source not in POSE_SOURCES:
            raise ValueError(f"pose_source must be one of {POSE_SOURCES}, got {pose_source!r}")
        self._stack.close()
        if self.n_rays == 0:
            why = "; ".join(f"{n} {r}" for r, n in self.dropped.most_common()) or "the recording has no eye samples"
            raise UserError(f"{self.source}: no usable eye sample ({why}); check that it is a complete "
                            f"{self.device} recording")
        if pose_source == "scene_video" and not {"scene_video", "camera"} <= set(self.files):
            raise ValueError("pose_source 'scene_video' needs add_scene_video and set_camera")
        report = {"version": 1, "device": self.device, "source": str(self.source), "read": dict(self.read),
                  "eye_samples_written": self.n_rays, "dropped": dict(self.dropped.most_common()),
                  "notes": self.notes, "pose_source": pose_source, "clock_offset_s": clock_offset_s,
                  "frames": frames, **extra}
        write_json(self.out / REPORT, report)
        self.files["import_report"] = REPORT
        manifest = {"format": FORMAT, "version": VERSION, "producer": f"wearable-gaze {__version__} import",
                    "eye_rate_hz": float(eye_rate_hz), "has_recording": True, "n_eye_samples": self.n_rays,
                    "files": dict(self.files),
                    "source": {"device": self.device, "path": str(self.source), "clock_offset_s": clock_offset_s,
                               "pose_source": pose_source}}
        if image_size is not None:
            manifest["image_size"] = [int(image_size[0]), int(image_size[1])]
        if fps is not None:
            manifest["fps"] = float(fps)
        write_manifest(self.out, manifest)
        return manifest


def read_import_report(path) -> dict:
    """``import_report.json`` (written by ``SessionImport.finish``) as a dict.

    Raises:
        UserError: the file is missing, not JSON, or not an import report.
    """
    rep = read_json_text(path, "import report")
    if not isinstance(rep, dict) or "device" not in rep or not isinstance(rep.get("notes", []), list):
        raise UserError(f"{path}: not an import report (no 'device'); re-run 'wearable-gaze import'")
    return rep


# --- the simulator's sessions, for the device writers ------------------------------------------

@dataclass
class SimulatedRecording:
    """A simulated session as a device would have recorded it (all on the session clock).

    Attributes:
        t: (N,) eye-sample times, s.
        rays: the measured view lines, head frame (= scene camera, OpenCV axes, mm), with
            each eye's validity.
        T_world_from_head: (N, 4, 4) head poses at the eye samples, mm (interpolated from the
            per-frame truth).
        gaze_head_mm: (N, 3) the gazed point in the head frame, mm (for a device's own 3D gaze).
        camera: the true scene-camera calibration (``CameraCalibration``).
        video, frame_times: the scene video and its frame times, s.
        marker_map: the session's markers.json (None if it has none).
        image_size: (width, height), px.  eye_rate_hz, fps: nominal rates.
    """

    t: np.ndarray
    rays: BinocularSamples
    T_world_from_head: np.ndarray
    gaze_head_mm: np.ndarray
    camera: object
    video: Path
    frame_times: np.ndarray
    marker_map: Path | None
    image_size: tuple
    eye_rate_hz: float
    fps: float


def read_simulated_recording(session) -> SimulatedRecording:
    """Read a session written by ``wearable-gaze simulate`` (its truth/ folder included)."""
    root = Path(session)
    man = load_json(root / "session.json", "session")
    files = man["files"]
    if "truth_gaze" not in files or "truth_head_poses" not in files:
        raise UserError(f"{root}: not a simulated session (no truth/gaze.csv); export needs 'wearable-gaze simulate' "
                        "output")
    eye, _ = read_eye_csv(root / files["eye_samples"])
    g = read_table(root / files["truth_gaze"], ["t"], what="truth gaze CSV")
    tp, _, Tp, _ = read_poses_csv(root / files["truth_head_poses"])
    # the eye samples run a frame period past the video at either end: those take the end pose
    T, ok = interpolate_poses(tp, Tp, np.clip(eye.t, tp[0], tp[-1]), max_gap_s=1.0)
    if not ok.all():
        raise UserError(f"{root}: truth head poses do not cover every eye sample")
    R_hw = np.transpose(T[:, :3, :3], (0, 2, 1))
    arrays = []
    for e, side in enumerate(("left", "right")):
        o_w = np.column_stack([g[f"{side}_o{a}"] for a in "xyz"])
        d_w = np.column_stack([g[f"{side}_meas_d{a}"] for a in "xyz"])
        o_h = np.einsum("nij,nj->ni", R_hw, o_w - T[:, :3, 3])
        d_h = np.einsum("nij,nj->ni", R_hw, d_w)
        arrays += [o_h, np.where(eye.valid[:, e:e + 1], d_h, np.nan)]
    rays = BinocularSamples.from_arrays(eye.t, *arrays, frame="head")
    gw = np.column_stack([g[f"gaze_{a}"] for a in "xyz"])
    gaze_h = np.einsum("nij,nj->ni", R_hw, gw - T[:, :3, 3])
    _, ft = read_frame_times(root / files["scene_timestamps"])
    cam = load_camera(root / files.get("truth_camera", "truth/camera.json"))
    return SimulatedRecording(eye.t, rays, T, gaze_h, cam, root / files["scene_video"], ft,
                              root / files["marker_map"] if "marker_map" in files else None,
                              tuple(man["image_size"]), float(man.get("eye_rate_hz", 60.0)), float(man.get("fps", 30)))
