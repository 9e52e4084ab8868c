"""Tobii Pro Glasses 3 recordings (``--format tobii-g3``; docs/importers.md).

Files read: ``recording.g3`` (JSON: ``scenecamera.file``, ``scenecamera.camera-calibration``,
``gaze.file``), the gaze file it names (``gazedata.gz``: one JSON object per line) and the scene
video it names (``scenevideo.mp4``) when present. Without ``recording.g3`` (a copy of the data
files only) ``gazedata.gz`` is read alone: the nominal glasses -> camera flip, no intrinsics, and
a still head unless a video and ``--camera`` are given; the report lists what was missing.
Kept, not used: ``imudata.gz`` (copied in as ``device/imudata.gz``) and ``eventdata.gz``'s
sync-port events (``device_events.csv``, session clock). Layout and fields: Tobii's G3 SDK
(``G3SDK/ParserHelpers.cs`` ``ParseGazeData``), glassesTools ``importing/tobii_G3.py``
(docs/devices/tobii-pupil.md section 2).

Fields used: lines with ``"type": "gaze"``; ``timestamp`` (s); in ``data``: per eye
(``eyeleft``/``eyeright``) ``gazeorigin`` (mm, the view line's origin) and ``gazedirection``
(unit); ``gaze3d`` (the device's 3D gaze point, mm: comparison only); ``gaze2d`` (normalised, only
to confirm the frame mapping). ``pupildiameter`` and other line types are not used. An eye that
is absent, or a line with ``"data": {}``, is the device's way of saying "no data" (there is no
status field).

Frames: as G2 (``tobii_common``): glasses frame x left, y up, z forward, mm, mapped to our head
frame by the unit's ``camera-calibration`` ``rotation`` and ``position``. The position's sign
convention is decided on the recording by reprojecting ``gaze3d`` onto ``gaze2d``
(import_report.json ``frames.position_convention``).

Clock: the session clock is the G3 ``timestamp`` itself (s; glassesTools uses it as scene-video
time, so ``clock_offset_s`` is 0; the vendor's statement of its origin was not found); the scene
video's frame i is at i / fps.

Dropped and counted: per eye, absent, non-finite values, a gaze origin over 100 mm from the scene
camera, a direction that is not unit or points backwards; per sample, no valid eye, a time that does
not increase; unparsable lines. Gaps in the time stamps count the samples they lost.

What the device does not give: head poses (from the scene video with ``--markers``, else a still
head, vergence only), eye rotation centres (``gazeorigin`` is the pupil position), validity codes.
"""

from __future__ import annotations

import gzip
import json
import logging
import shutil
import uuid
from collections import Counter
from pathlib import Path

import numpy as np

from ...errors import UserError
from ..jsonio import read_json_text
from .tobii_common import (
    CHUNK,
    NAN3,
    GapCounter,
    GlassesCamera,
    JsonLines,
    RayChunks,
    choose_convention,
    finish_import,
    frames_report,
    orthonormal,
    project_norm,
    sim_in_glasses,
    t_cam_from_glasses,
    vec,
    video_frame_times,
    writer_camera,
)

NAME = "tobii-g3"
log = logging.getLogger(__name__)

PREPASS_PAIRS = 200
WRITER_POSITION_MM = (10.0, -30.0, 5.0)
"""The simulated unit's scene-camera position (non-zero, so that the import must decide its
convention)."""


def detect(src: Path) -> bool:
    """A G3 recording: ``recording.g3`` in the folder, or (its manifest lost) a ``gazedata.gz``
    whose first line is a G3 gaze or sync object."""
    src = Path(src)
    if (src / "recording.g3").is_file():
        return True
    if not (src / "gazedata.gz").is_file():
        return False
    try:
        with gzip.open(src / "gazedata.gz", "rt", encoding="utf-8", errors="replace") as fh:
            first = json.loads(fh.readline())
    except (OSError, EOFError, ValueError):
        return False
    return isinstance(first, dict) and first.get("type") in ("gaze", "syncport") and "timestamp" in first


def read_camera(meta: dict, path: Path) -> GlassesCamera | None:
    """The scene camera from ``recording.g3`` ``scenecamera.camera-calibration`` (None: absent).

    K = [[f0, skew, c0], [0, f1, c1], [0, 0, 1]], dist = [k1, k2, p1, p2, k3] from
    ``radial-distortion`` [k1, k2, k3] and ``tangential-distortion`` [p1, p2].

    Raises:
        UserError: a calibration with a missing or malformed field.
    """
    cal = (meta.get("scenecamera") or {}).get("camera-calibration")
    if cal is None:
        return None
    try:
        f = np.asarray(cal["focal-length"], float).reshape(2)
        c = np.asarray(cal["principal-point"], float).reshape(2)
        k = np.asarray(cal["radial-distortion"], float).reshape(3)
        p = np.asarray(cal["tangential-distortion"], float).reshape(2)
        R = np.asarray(cal["rotation"], float).reshape(3, 3)
        pos = np.asarray(cal["position"], float).reshape(3)
        size = tuple(int(v) for v in np.asarray(cal["resolution"]).reshape(2))
        skew = float(cal.get("skew", 0.0))
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{path}: scenecamera.camera-calibration is malformed ({type(exc).__name__}: {exc}); copy "
                        "recording.g3 again from the recording, or give --camera camera.json") from None
    K = np.array([[f[0], skew, c[0]], [0.0, f[1], c[1]], [0.0, 0.0, 1.0]])
    if not (np.all(np.isfinite(K)) and np.all(f > 0) and min(size) > 0 and np.all(np.isfinite(R))):
        raise UserError(f"{path}: scenecamera.camera-calibration has a non-positive focal length or resolution; "
                        "give --camera camera.json")
    return GlassesCamera(orthonormal(R), pos, K, np.array([k[0], k[1], p[0], p[1], k[2]]), size,
                         "recording.g3 scenecamera.camera-calibration")


def _eye(data: dict, key: str):
    e = data.get(key)
    if not isinstance(e, dict):
        return NAN3, NAN3, False
    return vec(e.get("gazeorigin")), vec(e.get("gazedirection")), True


def _rows(lines: JsonLines, counts: Counter):
    """(timestamp, origin L, direction L, present L, origin R, direction R, present R, gaze3d, gaze2d)
    of each gaze line."""
    for obj in lines:
        if obj.get("type") != "gaze":
            counts[f"gazedata {obj.get('type')!s:.20} lines (not used)"] += 1
            continue
        ts, data = obj.get("timestamp"), obj.get("data")
        if not isinstance(ts, (int, float)) or isinstance(ts, bool) or not isinstance(data, dict):
            lines.drops["line: gaze line without a timestamp or data"] += 1
            continue
        counts["gazedata gaze lines"] += 1
        yield (float(ts), *_eye(data, "eyeleft"), *_eye(data, "eyeright"), vec(data.get("gaze3d")),
               vec(data.get("gaze2d"), 2))


def prepass(path: Path) -> dict:
    """From the start of the gaze file: the eye rate (median step of the first samples, Hz) and up
    to ``PREPASS_PAIRS`` (gaze3d, gaze2d) pairs for ``choose_convention``."""
    ts, g3, g2 = [], [], []
    for r in _rows(JsonLines(path, Counter()), Counter()):
        if len(ts) < PREPASS_PAIRS:
            ts.append(r[0])
        if np.all(np.isfinite(r[7])) and np.all(np.isfinite(r[8])):
            g3.append(r[7])
            g2.append(r[8])
        if len(ts) >= PREPASS_PAIRS and len(g3) >= PREPASS_PAIRS:
            break
    steps = np.diff(np.sort(ts))
    steps = steps[steps > 0]
    return {"rate_hz": 1.0 / float(np.median(steps)) if len(steps) else 50.0,
            "gaze3d": np.array(g3, float).reshape(-1, 3), "gaze2d": np.array(g2, float).reshape(-1, 2)}


def _emit(rows: list, gaps: GapCounter, chunks: RayChunks) -> None:
    cols = list(zip(*rows, strict=True))
    t = np.array(cols[0], float)
    gaps.feed(np.sort(t), chunks.drops)
    eyes = {}
    for side, (o, d, present) in (("left", cols[1:4]), ("right", cols[4:7])):
        present = np.array(present, bool)
        chunks.drops[f"{side} eye: absent"] += int((~present).sum())
        eyes[side] = (np.array(o, float), np.array(d, float), present)
    chunks.emit(t, eyes, np.array(cols[7], float))


def _paths(src: Path) -> tuple[dict | None, Path, Path | None]:
    """(recording.g3's object, None without one; the gaze file; the scene video or None)."""
    meta_path = src / "recording.g3"
    if not meta_path.is_file():
        gaze, video = src / "gazedata.gz", src / "scenevideo.mp4"
        if not gaze.is_file():
            raise UserError(f"{src}: no recording.g3 and no gazedata.gz; pass a Tobii Glasses 3 recording folder")
        return None, gaze, video if video.is_file() else None
    meta = read_json_text(meta_path, "Tobii Glasses 3 recording.g3")
    if not isinstance(meta, dict):
        raise UserError(f"{meta_path}: not a recording.g3 object; copy it again from the recording")
    gaze = src / str((meta.get("gaze") or {}).get("file", "gazedata.gz"))
    if not gaze.is_file():
        raise UserError(f"{gaze}: no such file (recording.g3 gaze.file); copy the whole recording folder")
    video = src / str((meta.get("scenecamera") or {}).get("file", "scenevideo.mp4"))
    return meta, gaze, video if video.is_file() else None


def _side_files(src: Path, meta: dict | None, imp) -> dict:
    """Keep the streams the session does not use yet: ``imudata.gz`` copied in unchanged
    (``device/imudata.gz``) and ``eventdata.gz``'s sync-port events as ``device_events.csv``
    (session clock). Returns what the report says of them."""
    meta = meta or {}
    out = {}
    imu = src / str((meta.get("imu") or {}).get("file", "imudata.gz"))
    if imu.is_file():
        imp.keep_device_file(imu, "device_imu")
        out["imu"] = {"file": imu.name, "kept_as": f"device/{imu.name}"}
    events = src / str((meta.get("events") or {}).get("file", "eventdata.gz"))
    if events.is_file():
        drops, t, rows = Counter(), [], []
        for obj in JsonLines(events, drops):
            data, ts = obj.get("data"), obj.get("timestamp")
            if not isinstance(data, dict) or not isinstance(ts, (int, float)) or isinstance(ts, bool):
                drops["line: event without a timestamp or data"] += 1
                continue
            t.append(float(ts))
            rows.append((str(obj.get("type", "")), str(data.get("direction", "")), data.get("value", "")))
        order = np.argsort(t, kind="stable")
        imp.add_device_events(np.asarray(t, float)[order], [rows[i] for i in order])
        imp.count("eventdata events", len(t))
        out["events"] = {"file": events.name, "kept_as": "device_events.csv", "events": len(t),
                         "not_read": dict(drops)}
    return out


def read_recording(src: Path, imp, options, progress=None) -> None:
    """Stream a G3 recording into ``imp`` (see the module docstring)."""
    src = Path(src)
    meta, gaze, video = _paths(src)
    cam = read_camera(meta, src / "recording.g3") if meta is not None else None
    if cam is None and video is not None and options.camera is None:
        raise UserError(f"{src}: a scene video but no scene-camera calibration (recording.g3); give --camera "
                        "camera.json (calibrate-camera)")
    if meta is None:
        imp.note("no recording.g3 (the recording's manifest): no scene-camera calibration, so the glasses frame is "
                 "turned to the camera's by the nominal flip and the view lines start where the device put the pupils; "
                 + ("the head is taken as still (no scene video)" if video is None else
                    "the scene video is read with --camera"))
    side = _side_files(src, meta, imp)
    pre = prepass(gaze)
    T, convention = choose_convention(cam, pre["gaze3d"], pre["gaze2d"], imp)
    chunks, gaps, counts = RayChunks(imp, T), GapCounter(pre["rate_hz"]), Counter()
    lines = JsonLines(gaze, chunks.drops, progress)
    rows = []
    for row in _rows(lines, counts):
        rows.append(row)
        if len(rows) >= CHUNK:
            _emit(rows, gaps, chunks)
            rows.clear()
    if rows:
        _emit(rows, gaps, chunks)
    if lines.truncated:
        imp.note(lines.truncated)
    for stream, n in counts.items():
        imp.count(stream, n)
    chunks.flush_drops()
    frame_times = video_frame_times(video)[0] if video is not None else None
    missing = [] if meta is not None else ["recording.g3"]
    missing += [] if video is not None else ["scenevideo.mp4"]
    finish_import(imp, options, cam, video, frame_times, pre["rate_hz"], 0.0, frames_report(T, cam, convention),
                  largest_gap_s=round(gaps.largest_s, 6), gazedata_lines=lines.n_lines, missing_files=missing, **side)


# --- the writer ---------------------------------------------------------------------------------

def _gaze_line(t: float, g: dict, i: int, gaze2d) -> str:
    data = {}
    p, q = g["gaze3d"][i], gaze2d[i]
    if np.all(np.isfinite(p)) and np.all(np.isfinite(q)):
        data["gaze2d"] = [round(float(v), 6) for v in q]
        data["gaze3d"] = [round(float(v), 3) for v in p]
    for side, key in (("left", "eyeleft"), ("right", "eyeright")):
        o, d, v = (a[i] for a in g[side])
        if v:
            data[key] = {"gazeorigin": [round(float(x), 3) for x in o],
                         "gazedirection": [round(float(x), 6) for x in d], "pupildiameter": 3.5}
    if "eyeleft" not in data and "eyeright" not in data:
        data = {}
    return json.dumps({"type": "gaze", "timestamp": round(float(t), 6), "data": data}, separators=(",", ":"))


def write_recording(sim, dst: Path) -> None:
    """Write a simulated session as a G3 recording folder ``dst``: ``recording.g3`` (with the
    scene camera's calibration: the G2 sample's rotation, ``WRITER_POSITION_MM`` and the
    simulation's intrinsics), ``gazedata.gz`` (an eye without data is left out; a sample without
    either eye is ``"data": {}``; origins 0.001 mm, directions 1e-6, as the G3 writes them) and
    ``scenevideo.mp4`` (a copy of the simulated video). Timestamps are the session's times, s."""
    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    cam = writer_camera(sim, WRITER_POSITION_MM)
    g = sim_in_glasses(sim, t_cam_from_glasses(cam))
    gaze2d = project_norm(np.nan_to_num(sim.gaze_head_mm, nan=1.0), cam)
    with gzip.open(dst / "gazedata.gz", "wt", encoding="utf-8") as fh:
        for i, t in enumerate(sim.t):
            fh.write(_gaze_line(t, g, i, gaze2d) + "\n")
        fh.write(json.dumps({"type": "syncport", "timestamp": float(sim.t[-1]), "data": {"direction": "in",
                                                                                          "value": 1}}) + "\n")
    shutil.copyfile(sim.video, dst / "scenevideo.mp4")
    K, d = cam.camera_matrix, cam.dist_coeffs
    valid = int(np.sum(g["left"][2] | g["right"][2]))
    meta = {"name": "simulated", "duration": float(sim.t[-1] - sim.t[0]), "created": "2026-01-01T00:00:00.000Z",
            "meta-folder": "meta", "uuid": str(uuid.uuid5(uuid.NAMESPACE_URL, str(dst))), "version": 2,
            "scenecamera": {"file": "scenevideo.mp4", "snapshots": [], "camera-calibration": {
                "position": cam.position_mm.tolist(), "focal-length": [K[0, 0], K[1, 1]],
                "rotation": cam.rotation.tolist(), "skew": float(K[0, 1]), "principal-point": [K[0, 2], K[1, 2]],
                "radial-distortion": [d[0], d[1], d[4]], "tangential-distortion": [d[2], d[3]],
                "resolution": list(cam.image_size)}},
            "gaze": {"file": "gazedata.gz", "samples": len(sim.t), "valid-samples": valid}}
    (dst / "recording.g3").write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
