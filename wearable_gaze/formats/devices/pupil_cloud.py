"""Pupil Cloud's Timeseries export of a Pupil Invisible or Neon recording ("pupil-cloud";
docs/importers.md): what most Invisible and Neon users download from Pupil Cloud instead of the
native recording.

Files read (one folder per recording, as Cloud's "Timeseries Data" download lays it out):

- ``gaze.csv`` (required): ``timestamp [ns]``, ``gaze x [px]``, ``gaze y [px]``, ``worn``,
  ``fixation id``, ``blink id``, ``azimuth [deg]``, ``elevation [deg]``;
- ``world_timestamps.csv``: ``timestamp [ns]`` of each scene-video frame;
- ``scene_camera.json``: ``camera_matrix`` and ``dist_coefs`` (8 values, OpenCV's rational
  model) of the scene camera;
- ``info.json``: ``start_time`` (ns), the session's time 0, and the app's version for the report;
- the scene video (the one ``*.mp4`` of the folder), when it was downloaded;
- ``fixations.csv``, ``blinks.csv``, ``saccades.csv``, ``events.csv``: the device's own events,
  copied into the session as ``device_fixations.csv`` ... (not inputs to our estimators).

Rays. Cloud's export holds no eye states (Invisible has none; Neon's ``3d_eye_states.csv`` is
not read here yet: use the native Neon recording for per-eye rays). Each gaze sample is one
cyclopean view line from the scene camera's centre along the gaze direction, which
``azimuth [deg]`` (atan2(x, z)) and ``elevation [deg]`` (asin(-y)) give in the scene camera's
frame (OpenCV axes): d = (cos el sin az, -sin el, cos el cos az). On the real Invisible export
this direction and ``gaze x/y [px]`` undistorted through ``scene_camera.json`` agree to 4e-5
degrees; an export without the angle columns uses the pixels that way. The line is written as
the left eye of ``eye_rays.csv`` with the right eye empty (import_report.json ``rays``:
``cyclopean``): a single line per sample has no vergence, so its depth comes from head motion
alone, and with a still head a target has a direction only.

Frames. The scene camera's frame is our head frame (identity). Clock: session t =
(timestamp - start) / 1e9 s with start = ``info.json`` ``start_time`` (else the first scene
frame, else the first gaze sample); ``clock_offset_s`` = start / 1e9 (Unix s).

Dropped and counted: samples not worn (``worn`` 0), inside a blink (``blink id`` set), without a
finite direction, a time that does not increase; gaps in the stream count the samples they lost.

Head poses: the scene video with ``--markers`` (tracked by ``process``), else a still head.
"""

from __future__ import annotations

import json
import logging
import shutil
import uuid
from collections import Counter
from pathlib import Path

import numpy as np

from calibration.cvcompat import undistort_points
from tracking.timeline import nearest_in_time

from ...errors import UserError
from ..camera import load_camera
from ..jsonio import read_json_text
from ..tables import csv_header, iter_csv_chunks, write_table
from . import pupil_cloud_eyes as eyes
from .tobii_common import GapCounter, video_frame_times

NAME = "pupil-cloud"
log = logging.getLogger(__name__)

GAZE = "gaze.csv"
WORLD = "world_timestamps.csv"
CAMERA = "scene_camera.json"
INFO = "info.json"
T_COL = "timestamp [ns]"
ANGLES = ("azimuth [deg]", "elevation [deg]")
PIXELS = ("gaze x [px]", "gaze y [px]")
EVENT_FILES = {"fixations.csv": "device_fixations.csv", "blinks.csv": "device_blinks.csv",
               "saccades.csv": "device_saccades.csv", "events.csv": "device_events.csv"}
CHUNK = 20000
NOMINAL_RATE_HZ = 200.0


def detect(src: Path) -> bool:
    """A Cloud Timeseries export: ``gaze.csv``, ``world_timestamps.csv`` and ``scene_camera.json``."""
    src = Path(src)
    return all((src / n).is_file() for n in (GAZE, WORLD, CAMERA))


def direction_from_angles(azimuth_deg, elevation_deg) -> np.ndarray:
    """(N,) azimuth and elevation, degrees (Pupil Cloud's) -> (N, 3) unit directions in the scene
    camera's frame, OpenCV axes (x right, y down, z forward)."""
    az, el = np.radians(np.asarray(azimuth_deg, float)), np.radians(np.asarray(elevation_deg, float))
    return np.column_stack([np.cos(el) * np.sin(az), -np.sin(el), np.cos(el) * np.cos(az)])


def angles_from_direction(d) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of ``direction_from_angles``: (N, 3) directions -> azimuth, elevation (N,), deg."""
    d = np.asarray(d, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return np.degrees(np.arctan2(d[:, 0], d[:, 2])), np.degrees(np.arcsin(np.clip(-d[:, 1], -1, 1)))


def read_scene_camera(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3), dist (k,)) from ``scene_camera.json``.

    Raises:
        UserError: missing fields or values that are not a camera matrix.
    """
    cam = read_json_text(path, "Pupil Cloud scene_camera.json")
    try:
        K = np.asarray(cam["camera_matrix"], float).reshape(3, 3)
        D = np.asarray(cam.get("dist_coefs", cam.get("distortion_coefficients")), float).ravel()
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise UserError(f"{path}: not a scene-camera file with camera_matrix and dist_coefs ({type(exc).__name__}); "
                        "download the recording's Timeseries export again") from None
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and np.all(np.isfinite(D))
            and len(D) in (4, 5, 8, 12, 14)):
        raise UserError(f"{path}: camera_matrix or dist_coefs is not a valid camera; download the export again")
    return K, D


def _start_ns(src: Path) -> tuple[int, str]:
    """The session's time 0 (ns) and where it came from."""
    if (src / INFO).is_file():
        info = read_json_text(src / INFO, "Pupil Cloud info.json")
        if isinstance(info, dict) and isinstance(info.get("start_time"), int) and info["start_time"] > 0:
            return int(info["start_time"]), "info.json start_time"
    for name in (WORLD, GAZE):
        head = csv_header(src / name, name, "download the export again", [T_COL])
        for rows, lines in iter_csv_chunks(src / name, name, 1):
            return int(eyes.int_times([rows[0][head.index(T_COL)]], src / name, lines)[0]), f"the first {name} row"
    raise UserError(f"{src / GAZE}: no gaze samples; download the export again")


def _world_times(src: Path, start_ns: int) -> np.ndarray:
    path = src / WORLD
    head = csv_header(path, "world timestamps CSV", "download the export again", [T_COL])
    out = [(eyes.int_times([r[head.index(T_COL)] for r in rows], path, lines) - start_ns) / 1e9
           for rows, lines in iter_csv_chunks(path, "world timestamps CSV", CHUNK)]
    return np.concatenate(out) if out else np.zeros(0)


class _GazeChunks:
    """Turns chunks of gaze.csv rows into cyclopean rays, counting what it drops."""

    def __init__(self, imp, path: Path, start_ns: int, K, D):
        self.imp, self.path, self.start_ns, self.K, self.D = imp, path, start_ns, K, D
        self.head = csv_header(path, "Pupil Cloud gaze CSV", "download the export again", [T_COL])
        self.index = {n: i for i, n in enumerate(self.head)}
        self.use_angles = all(a in self.index for a in ANGLES)
        if not self.use_angles and not all(p in self.index for p in PIXELS):
            raise UserError(f"{path}: neither '{ANGLES[0]}'/'{ANGLES[1]}' nor '{PIXELS[0]}'/'{PIXELS[1]}' columns; "
                            "is it a Pupil Cloud gaze.csv?")
        self.drops, self.t_last, self.times = Counter(), -np.inf, []
        self.gaps = None

    def _column(self, rows, name) -> np.ndarray:
        if name not in self.index:
            return np.full(len(rows), np.nan)
        k = self.index[name]
        cells = [r[k] if len(r) > k else "" for r in rows]
        return np.array([float(c) if c.strip() else np.nan for c in cells], float)

    def parse(self, rows, lines) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_ns (n,) int64, directions (n, 3) in the scene camera's frame, the reason each row
        is dropped (n,) object, '': kept) of a chunk of gaze.csv rows; the gaps counted."""
        t_ns = eyes.int_times([r[self.index[T_COL]] for r in rows], self.path, lines)
        t = (t_ns - self.start_ns) / 1e9
        if self.gaps is None:
            steps = np.diff(t[:2000])
            steps = steps[steps > 0]
            self.rate = 1.0 / float(np.median(steps)) if len(steps) else NOMINAL_RATE_HZ
            self.gaps = GapCounter(self.rate)
        self.gaps.feed(np.sort(t), self.drops)
        if self.use_angles:
            d = direction_from_angles(self._column(rows, ANGLES[0]), self._column(rows, ANGLES[1]))
        else:
            xy = undistort_points(np.column_stack([self._column(rows, p) for p in PIXELS]), self.K, self.D)
            d = np.column_stack([xy, np.ones(len(xy))])
            d /= np.linalg.norm(d, axis=1, keepdims=True)
        why = np.full(len(t), "", object)
        for reason, bad in (("not worn (worn 0)", self._column(rows, "worn") == 0),
                            ("inside a blink (blink id)", np.isfinite(self._column(rows, "blink id"))),
                            ("no gaze direction (empty or not finite)", ~np.all(np.isfinite(d), axis=1))):
            why[bad & (why == "")] = reason
        self.imp.count("gaze.csv rows", len(t))
        return t_ns, d, why

    def add(self, rows, lines) -> None:
        """A chunk of gaze.csv rows as cyclopean rays (one line per sample from the camera's centre)."""
        t_ns, d, why = self.parse(rows, lines)
        t = (t_ns - self.start_ns) / 1e9
        for reason in set(why[why != ""]):
            self.drops[reason] += int(np.sum(why == reason))
        keep = why == ""
        increasing = np.maximum.accumulate(np.concatenate([[self.t_last], t]))[:-1] < t
        self.drops["time does not increase"] += int((keep & ~increasing).sum())
        keep &= increasing
        if keep.any():
            n = int(keep.sum())
            self.imp.add_rays(t[keep], np.zeros((n, 3)), d[keep], np.ones(n, bool), np.full((n, 3), np.nan),
                              np.full((n, 3), np.nan), np.zeros(n, bool))
            self.t_last = float(t[keep][-1])


def _binocular(src: Path, imp, chunks: _GazeChunks, progress) -> dict:
    """Neon's eye states (``pupil_cloud_eyes``): per-eye visual axes, the export's gaze for the
    kappa offset and its drops (not worn, in a blink); the report's ``kappa`` entry."""
    parts = [chunks.parse(rows, lines) for rows, lines in iter_csv_chunks(src / GAZE, "Pupil Cloud gaze CSV", CHUNK,
                                                                          progress)]
    g_t = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
    g_d = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 3))
    g_why = np.concatenate([p[2] for p in parts]) if parts else np.zeros(0, object)
    order = np.argsort(g_t, kind="stable")
    g_t, g_d, g_why = g_t[order], g_d[order], g_why[order]
    t_ns, centers, axes = eyes.read_eye_states(src / eyes.EYE_STATES)
    imp.count(f"{eyes.EYE_STATES} rows", len(t_ns))
    ok = eyes.eye_validity(centers, axes, chunks.drops)
    gaze = nearest_in_time(g_t, g_d, t_ns, eyes.MATCH_NS, inclusive=True)
    j = np.clip(np.searchsorted(g_t, t_ns), 0, max(len(g_t) - 1, 0))
    if len(g_t):
        for reason in ("not worn (worn 0)", "inside a blink (blink id)"):
            bad = (g_t[j] == t_ns) & (g_why[j] == reason) & ok.any(axis=0)
            chunks.drops[reason] += int(bad.sum())
            ok[:, bad] = False
    vis, kappa = eyes.visual_axes(src, centers, axes, ok, gaze)
    t = (t_ns - chunks.start_ns) / 1e9
    keep = ok.any(axis=0) & (np.maximum.accumulate(np.concatenate([[-np.inf], t]))[:-1] < t)
    chunks.drops["sample: no valid eye or a time that does not increase"] += int((~keep).sum())
    k = np.flatnonzero(keep)
    for a in range(0, len(k), CHUNK):
        s = k[a:a + CHUNK]
        imp.add_rays(t[s], centers[0][s], vis[0][s], ok[0][s], centers[1][s], vis[1][s], ok[1][s])
    imp.note(f"per-eye rays from {eyes.EYE_STATES}: optical axes turned into visual axes by the kappa offset fitted "
             f"on the export's gaze ray at {eyes.KAPPA_DEPTH_MM:g} mm (an assumed depth; docs/importers.md)")
    return kappa


def _video(src: Path) -> Path | None:
    videos = sorted(p for p in src.glob("*.mp4") if p.is_file())
    if len(videos) > 1:
        raise UserError(f"{src}: {len(videos)} videos ({', '.join(p.name for p in videos[:3])}); keep only the scene "
                        "video of the export in the folder")
    return videos[0] if videos else None


def read_recording(src: Path, imp, options, progress=None) -> None:
    """Stream a Cloud Timeseries export into ``imp`` (see the module docstring)."""
    src = Path(src)
    K, D = read_scene_camera(src / CAMERA)
    start_ns, start_from = _start_ns(src)
    frame_times = _world_times(src, start_ns)
    chunks = _GazeChunks(imp, src / GAZE, start_ns, K, D)
    kappa = None
    if (src / eyes.EYE_STATES).is_file():
        kappa = _binocular(src, imp, chunks, progress)
    else:
        for rows, lines in iter_csv_chunks(src / GAZE, "Pupil Cloud gaze CSV", CHUNK, progress):
            chunks.add(rows, lines)
    for reason, n in chunks.drops.most_common():
        imp.drop(reason, n)
    if chunks.gaps is None:
        raise UserError(f"{src / GAZE}: no gaze samples; download the export again")
    video = _video(src)
    size = None
    if video is not None:
        video_times, size = video_frame_times(video)
        n_video = len(video_times)
        if n_video != len(frame_times):
            imp.note(f"the scene video has {n_video} frames and {WORLD} {len(frame_times)}: the first "
                     f"{min(n_video, len(frame_times))} are placed by {WORLD}")
            frame_times = frame_times[:min(n_video, len(frame_times))]
    for name, dst in EVENT_FILES.items():
        if (src / name).is_file():
            shutil.copyfile(src / name, imp.out / dst)
            imp.files[dst.removesuffix(".csv")] = dst
            imp.count(f"{name} rows (the device's own, kept)", max(0, _count_rows(src / name)))
    _finish(imp, options, K, D, size, video, frame_times, chunks, start_ns, start_from, kappa)


def _finish(imp, options, K, D, size, video, frame_times, chunks, start_ns: int, start_from: str,
            kappa: dict | None) -> None:
    """The camera (the export's, or ``--camera``), the scene video, the marker map, the pose
    source and the report, then ``imp.finish``."""
    if options.camera is not None:
        user = load_camera(options.camera)
        K, D, size = user.camera_matrix, user.dist_coeffs, user.image_size
        imp.note(f"scene-camera intrinsics from {options.camera} (--camera), not {CAMERA}")
    if size is not None:
        imp.set_camera(K, D, size)
    if video is not None:
        imp.add_scene_video(video, frame_times)
    if options.markers is not None:
        imp.set_marker_map(options.markers)
    if kappa is None:
        imp.note("one cyclopean view line per sample (the export has no eye states): a depth comes from head motion "
                 "alone")
    missing = [what for what, have in (("a scene video", video is not None),
                                       ("a marker map (--markers)", options.markers is not None)) if not have]
    if missing:
        imp.note(f"no head poses ({', '.join(missing)} missing): the head is taken as still, and "
                 + ("one line per sample from a still head gives a direction but no depth" if kappa is None
                    else "only the two eyes' vergence fixes a depth"))
    frames = {"head": "scene camera, OpenCV axes (x right, y down, z forward), mm",
              "device": "Pupil's scene camera frame (OpenCV axes): identity",
              "T_head_from_device": np.eye(4).tolist(),
              "gaze": ("azimuth = atan2(x, z), elevation = asin(-y) of the gaze direction" if chunks.use_angles
                       else "gaze px undistorted through scene_camera.json")}
    extra = {"rays": "cyclopean"} if kappa is None else {"rays": "binocular", "kappa": kappa}
    imp.finish(chunks.rate, start_ns / 1e9, "still_head" if missing else "scene_video", frames, image_size=size,
               clock_start=start_from, **extra)


def _count_rows(path: Path) -> int:
    with open(path, "rb") as fh:
        return sum(1 for line in fh if line.strip()) - 1


# --- the writer ---------------------------------------------------------------------------------

def _cyclopean(sim) -> np.ndarray:
    """(N, 3) the gaze direction a 2D-only tracker reports, head frame: toward the gazed point from
    the scene camera's centre, turned by the mean of the two eyes' own measurement errors (so its
    noise is the binocular tracker's, per sample); NaN where neither eye is valid."""
    g = np.asarray(sim.gaze_head_mm, float)
    d_true = g / np.linalg.norm(g, axis=1, keepdims=True)
    errs = []
    for side in ("left", "right"):
        o = np.asarray(getattr(sim.rays, f"{side}_origin_mm"))
        d = np.asarray(getattr(sim.rays, f"{side}_direction"))
        t_eye = g - o
        t_eye /= np.linalg.norm(t_eye, axis=1, keepdims=True)
        errs.append(d / np.linalg.norm(d, axis=1, keepdims=True) - t_eye)
    stack = np.stack(errs)
    n = np.sum(np.isfinite(stack[..., 0]), axis=0)[:, None]
    err = np.where(n > 0, np.nansum(stack, axis=0) / np.maximum(n, 1), np.nan)   # NaN: neither eye valid
    out = d_true + err
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def write_recording(sim, dst: Path, start_ns: int = 1_700_000_000_000_000_000, eye_states: bool = False) -> None:
    """Write a simulated session as a Cloud Timeseries export folder ``dst``: ``gaze.csv``
    (angles and px, ``worn`` 1), ``world_timestamps.csv``, ``scene_camera.json`` (the
    simulation's intrinsics), ``info.json`` and the scene video; with ``eye_states``, also
    Neon's ``3d_eye_states.csv`` (the simulated eyes' centres and measured directions, as optical
    axes). Times are the session's plus ``start_ns``."""
    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    d = _cyclopean(sim)
    ok = np.all(np.isfinite(d), axis=1)
    az, el = angles_from_direction(np.where(ok[:, None], d, [0.0, 0.0, 1.0]))
    px = sim.camera.project(np.where(ok[:, None], d, [0.0, 0.0, 1.0]))
    rec, sec = str(uuid.uuid5(uuid.NAMESPACE_URL, str(dst))), str(uuid.uuid5(uuid.NAMESPACE_DNS, str(dst)))
    t_ns = start_ns + np.round(np.asarray(sim.t) * 1e9).astype(np.int64)
    nan = np.where(ok, 0.0, np.nan)
    write_table(dst / GAZE, {"section id": [sec] * len(t_ns), "recording id": [rec] * len(t_ns),
                             T_COL: t_ns, PIXELS[0]: px[:, 0] + nan, PIXELS[1]: px[:, 1] + nan,
                             "worn": np.ones(len(t_ns)), "fixation id": np.full(len(t_ns), np.nan),
                             "blink id": np.full(len(t_ns), np.nan), ANGLES[0]: az + nan, ANGLES[1]: el + nan},
                {T_COL: "d", PIXELS[0]: ".3f", PIXELS[1]: ".3f", "worn": ".1f", "fixation id": ".0f",
                 "blink id": ".0f", ANGLES[0]: ".8f", ANGLES[1]: ".8f"})
    f_ns = start_ns + np.round(np.asarray(sim.frame_times) * 1e9).astype(np.int64)
    write_table(dst / WORLD, {"section id": [sec] * len(f_ns), "recording id": [rec] * len(f_ns), T_COL: f_ns},
                {T_COL: "d"})
    cam = {"camera_matrix": np.asarray(sim.camera.camera_matrix).tolist(),
           "dist_coefs": [np.asarray(sim.camera.dist_coeffs, float).ravel().tolist()],
           "serial_number": "sim", "version": "v1"}
    (dst / CAMERA).write_text(json.dumps(cam, indent=4) + "\n", encoding="utf-8")
    info = {"recording_id": rec, "start_time": int(start_ns), "duration": int(round(float(sim.t[-1]) * 1e9)),
            "data_format_version": "1.4", "app_version": "simulated"}
    (dst / INFO).write_text(json.dumps(info, indent=4) + "\n", encoding="utf-8")
    shutil.copyfile(sim.video, dst / f"{sec[:8]}_0.0-{float(sim.t[-1]):.3f}.mp4")
    if eye_states:
        r = sim.rays
        valid = [np.asarray(r.left_valid, bool)[:, None], np.asarray(r.right_valid, bool)[:, None]]
        centers = np.stack([np.where(valid[e], o, np.nan) for e, o in enumerate((r.left_origin_mm, r.right_origin_mm))])
        axes = np.stack([np.where(valid[e], d, np.nan) for e, d in enumerate((r.left_direction, r.right_direction))])
        eyes.write_eye_states(dst / eyes.EYE_STATES, t_ns, centers, axes, sec, rec)
