"""Pupil Core (Pupil Capture, exported by Pupil Player) in: ``--format pupil-core``.

Files read (docs/importers.md; research: docs/devices/tobii-pupil.md 3, 5). ``SRC`` is a
recording folder with ``exports/NNN/`` (the highest-numbered export is read), an export folder,
or a ``gaze_positions.csv``-like CSV file given by its path (the Tufts gaze-depth table):

- ``gaze_positions.csv`` (Raw Data Exporter), streamed ``CHUNK_ROWS`` rows at a time. Fields used:
  ``gaze_timestamp`` (Pupil time, s), ``confidence``, ``eye_center{0,1}_3d_{x,y,z}`` (mm),
  ``gaze_normal{0,1}_{x,y,z}``, ``gaze_point_3d_{x,y,z}`` (mm; the device's own 3D gaze, kept
  for comparison from binocular rows only: a monocular row's lies at an assumed depth). A
  monocular row (the other eye's cells empty) is a sample with one eye valid.
- ``head_pose_tracker_poses.csv`` (``timestamp, rotation_*, translation_*``) and
  ``head_pose_tracker_model.csv`` (``marker_id, vert_{0..3}_*``), in marker sides, scaled by
  ``--marker-size-mm`` (the files do not give the size); the model is checked (sides ~1).
- Without poses: ``world.mp4`` + ``world_timestamps.npy`` (or ``.csv``) with ``--camera`` and
  ``--markers``, for ``process`` to track (``world.intrinsics`` is msgpack, a new dependency: not
  read); otherwise the head is taken as still (vergence only; the report says so).

Frames: ``T_HEAD_FROM_WORLD_CAMERA`` (identity); eye0 is the RIGHT eye, eye1 the LEFT; a pose row
is ``T_world_from_camera`` (``head_pose_matrices``).
Clock: Pupil time, s; ``clock_offset_s`` = the first valid ``gaze_timestamp`` of the first chunk
holding one; poses and world frames share it. A file without ``gaze_timestamp`` (Tufts) is
numbered in file order at ``UNTIMED_RATE_HZ`` and the report says the times are invented.

Dropped and counted in ``import_report.json`` (reasons starting "right eye"/"left eye" count
eyes, whose sample stays with the other eye; the others count samples):

- ``confidence`` below ``MIN_CONFIDENCE`` = 0.6, Pupil's default ``min_data_confidence`` (the
  exporter: useful data has confidence "greater than ~0.6"; Player exports low rows by default);
- an empty or non-finite time; a row shorter than the header (truncated file);
- per eye: non-finite cells; a centre equal to Pupil's hard-coded prior (``EYE_PRIOR_MM``: the 3D
  eye model was not fitted); a centre over ``MAX_EYE_DISTANCE_MM`` = 100 mm from the world
  camera, which sits on the frame at the brow, at most about an interocular distance (~65 mm) to
  the side of, ~40 mm above and ~60 mm in front of an eyeball centre (Tufts puts eye1 200-450 mm
  away); a normal not unit or pointing backwards (z < 0: beyond any eye rotation);
- eye centres closer than 40 or farther than 80 mm (``EYE_SEPARATION_MM``): the extremes of human
  interpupillary distance (Dodgson 2004: adults 50-75 mm nearly all, ~40-80 with children);
  outside them one centre is wrong and the row cannot say which, so both go;
- a repeated ``gaze_timestamp`` (binocular matching; the sample with more valid eyes, then more
  confidence, stays) and rows over ``REORDER_WINDOW_S`` out of order (sorted within it);
- with device poses, samples without a valid pose within ``max_pose_gap_s`` on both sides.

Not given by Pupil Core: eye validity beyond confidence; the marker size; intrinsics read here.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tracking.timeline import interpolate_poses

from ...errors import UserError
from ..camera import load_camera
from ..markermap import load_marker_map
from ..tables import TableWriter, chunk_numbers, csv_header, iter_csv_chunks, read_table, write_table
from .common import ImportOptions, SessionImport, SimulatedRecording

log = logging.getLogger(__name__)

NAME = "pupil-core"
GAZE_FILE, POSES_FILE, MODEL_FILE = "gaze_positions.csv", "head_pose_tracker_poses.csv", "head_pose_tracker_model.csv"

T_HEAD_FROM_WORLD_CAMERA = np.eye(4)
"""Our head frame from Pupil Core's world-camera frame: the identity. Both are OpenCV camera
axes (x right, y down, z forward), mm, origin at the world camera's optical centre (Pupil's
``gazer_headset.py`` projects ``gaze_point_3d`` with the world camera's OpenCV model; papr in
pupil-labs/pupil#567: "unit of the gaze_point_3d is mm. The origin ... is the optical center of
the scene camera")."""

EYE_SIDE = {0: "right", 1: "left"}   # docs.pupil-labs.com/core/terminology: eye0 right, eye1 left
EYE_PRIOR_MM = {0: (20.0, 15.0, -20.0), 1: (-40.0, 15.0, -20.0)}   # gazer_headset.py hard-coded eye translations
MIN_CONFIDENCE = 0.6
MAX_EYE_DISTANCE_MM = 100.0
EYE_SEPARATION_MM = (40.0, 80.0)
REORDER_WINDOW_S = 1.0
CHUNK_ROWS = 4000
UNTIMED_RATE_HZ = 200.0

EYE_COLUMNS = {e: [f"eye_center{e}_3d_{a}" for a in "xyz"] + [f"gaze_normal{e}_{a}" for a in "xyz"] for e in (0, 1)}
GAZE_COLUMNS = (["gaze_timestamp", "world_index", "confidence", "norm_pos_x", "norm_pos_y", "base_data"]
                + [f"gaze_point_3d_{a}" for a in "xyz"] + EYE_COLUMNS[0] + EYE_COLUMNS[1])
POSE_COLUMNS = (["timestamp"] + [f"rotation_{a}" for a in "xyz"] + [f"translation_{a}" for a in "xyz"]
                + ["pitch", "yaw", "roll"])
MODEL_COLUMNS = ["marker_id"] + [f"vert_{i}_{a}" for i in range(4) for a in "xyz"]
WORLD_TIME = "# timestamps [seconds]"   # Player's world_timestamps.csv (np.savetxt header); written, not read

FRAMES = {"head_from_world_camera": {"matrix": T_HEAD_FROM_WORLD_CAMERA.tolist(),
                                    "words": "Pupil Core's world camera frame (OpenCV axes, mm) is our head frame"},
          "eyes": "eye0 = the wearer's RIGHT eye (eye_center0_3d, gaze_normal0), eye1 = the LEFT eye",
          "world_from_head": "head_pose_tracker_poses.csv rows are T_world_from_camera in the head-pose model: "
                             "R = Rodrigues(rotation_xyz), t = translation_xyz x --marker-size-mm"}


def detect(src: Path) -> bool:
    """A Pupil recording (``info.player.json``), a Player export folder, or a recording with one."""
    src = Path(src)
    return src.is_dir() and ((src / "info.player.json").is_file() or (src / GAZE_FILE).is_file()
                             or any((src / "exports").glob(f"*/{GAZE_FILE}")))


def _locate(src: Path, imp: SessionImport) -> tuple[Path, Path, Path | None]:
    """(gaze CSV, export folder, recording folder or None) of ``src``."""
    if src.is_file():
        return src, src.parent, None
    if (src / GAZE_FILE).is_file():
        return src / GAZE_FILE, src, src.parent.parent if src.parent.name == "exports" else None
    exports = sorted((p.parent for p in (src / "exports").glob(f"*/{GAZE_FILE}")), key=lambda p: p.name)
    if exports:
        if len(exports) > 1:
            imp.note(f"{len(exports)} Player exports found; read the last, exports/{exports[-1].name}")
        return exports[-1] / GAZE_FILE, exports[-1], src
    if (src / "pupil_data").is_file():
        raise UserError(f"{src}: a Pupil recording older than v1.8 (pupil_data); open it once in Pupil Player (it "
                        "upgrades it) and export with the Raw Data Exporter")
    raise UserError(f"{src}: no {GAZE_FILE} here or in exports/NNN/; export the recording with Pupil Player's Raw "
                    "Data Exporter, or pass the CSV file itself")


# --- CSV column chunks ------------------------------------------------------------------------------

def column_chunks(path: Path, columns, required, imp: SessionImport | None = None, rows: int | None = None,
               progress=None):
    """Stream a CSV (``tables.iter_csv_chunks``) as {column: (n,) float} chunks of ``rows`` rows
    (empty cell: NaN), for the ``columns`` in its header (``required`` must be); a row too short
    for them is dropped and counted in ``imp`` (a truncated file). Bytes that are not UTF-8 are
    read as U+FFFD (a number cell holding one is refused; other cells are not read).

    Raises:
        UserError: missing file or column, a cell that is not a number (line and column named).
    """
    what, fix = "Pupil Player CSV", "export it again from Pupil Player"
    header = csv_header(path, what, fix, required, "export it with Pupil Player's Raw Data Exporter")
    index = {c: header.index(c) for c in columns if c in header}
    for cells, lines in iter_csv_chunks(path, what, rows or CHUNK_ROWS, progress, errors="replace"):
        ch, whole, _ = chunk_numbers(cells, index, list(index), lines, path, "fix the cell or export again")
        if imp is not None and not whole.all():
            imp.drop("row with fewer cells than the header (truncated file?)",
                     sum(any(c.strip() for c in r) for r, w in zip(cells, whole, strict=True) if not w))
        del cells, lines                                # free the text before the caller works on the chunk
        if whole.any():
            yield {n: v[whole] for n, v in ch.items()}


# --- checks -----------------------------------------------------------------------------------

def eye_validity(c: np.ndarray, n: np.ndarray, eye: int, imp: SessionImport) -> np.ndarray:
    """(n,) bool: eye ``eye``'s centre ``c`` (n, 3) mm and normal ``n`` (n, 3) are usable. Each
    rejected eye is counted once, under its first failed check; an eye whose cells are all empty
    (a monocular row of the other eye) is not valid and not counted."""
    cn = np.hstack([c, n])
    ok = ~np.all(np.isnan(cn), axis=1)
    with np.errstate(invalid="ignore"):
        checks = [(~np.all(np.isfinite(cn), axis=1), "non-finite centre or normal"),
                  (np.all(c == EYE_PRIOR_MM[eye], axis=1),
                   f"eye centre is Pupil's default {EYE_PRIOR_MM[eye]} mm (3D eye model not fitted)"),
                  (np.linalg.norm(c, axis=1) > MAX_EYE_DISTANCE_MM,
                   f"eye centre more than {MAX_EYE_DISTANCE_MM:g} mm from the world camera"),
                  (np.abs(np.linalg.norm(n, axis=1) - 1) > 0.01, "gaze normal not a unit vector"),
                  (n[:, 2] < 0, "gaze normal points backwards (z < 0)")]
    for bad, why in checks:
        imp.drop(f"{EYE_SIDE[eye]} eye (eye{eye}): {why}", int((ok & bad).sum()))
        ok &= ~bad
    return ok


def check_rows(ch: dict, imp: SessionImport) -> tuple[np.ndarray, dict]:
    """The sample and eye checks of one chunk (``ch`` gains 'c0', 'n0', 'c1', 'n1'): (rows kept,
    {eye: (n,) valid})."""
    t, conf = ch["t"], ch.get("confidence")
    keep = np.isfinite(t)
    imp.drop("gaze_timestamp empty or not finite", int((~keep).sum()))
    if conf is not None:
        low = keep & ~(conf >= MIN_CONFIDENCE)
        imp.drop(f"confidence below {MIN_CONFIDENCE:g}", int(low.sum()))
        keep &= ~low
    valid = {}
    for e in (0, 1):
        ch[f"c{e}"], ch[f"n{e}"] = (np.column_stack([ch.get(k, np.full(len(t), np.nan)) for k in cols])
                                    for cols in (EYE_COLUMNS[e][:3], EYE_COLUMNS[e][3:]))
        valid[e] = np.zeros(len(t), bool)
        valid[e][keep] = eye_validity(ch[f"c{e}"][keep], ch[f"n{e}"][keep], e, imp)
    sep = np.linalg.norm(ch["c0"] - ch["c1"], axis=1)
    apart = valid[0] & valid[1] & ((sep < EYE_SEPARATION_MM[0]) | (sep > EYE_SEPARATION_MM[1]))
    imp.drop(f"eye centres outside {EYE_SEPARATION_MM[0]:g}-{EYE_SEPARATION_MM[1]:g} mm apart", int(apart.sum()))
    none = keep & ~apart & ~valid[0] & ~valid[1]
    imp.drop("no usable eye (per-eye reasons above, or no eye cells)", int(none.sum()))
    return keep & ~apart & ~none, valid


class _Reorder:
    """Sorts samples within ``REORDER_WINDOW_S``: a row more than that before the latest time read
    so far is dropped, a repeated time too (both counted); the rest come out in time order."""

    def __init__(self, imp: SessionImport):
        self.imp, self.held, self.last, self.latest = imp, None, -np.inf, -np.inf

    def push(self, s: dict, final: bool = False) -> dict | None:
        """Add samples {key: (n, ...)} in file order ('t' s, 'nvalid', 'conf', ...); return those
        now safe to write (all when ``final``), sorted, with unique times, or None."""
        run = np.maximum.accumulate(np.r_[self.latest, s["t"]])
        late = s["t"] < run[:-1] - REORDER_WINDOW_S
        self.imp.drop(f"gaze_timestamp more than {REORDER_WINDOW_S:g} s out of order", int(late.sum()))
        self.latest = float(run[-1])
        s = {k: v[~late] for k, v in s.items()}
        if self.held is not None:
            s = {k: np.concatenate([self.held[k], s[k]]) for k in s}
        s = {k: v[np.lexsort((-s["conf"], -s["nvalid"], s["t"]))] for k, v in s.items()}
        t = s["t"]
        rep = (t == self.last) | np.r_[False, t[1:] == t[:-1]]
        self.imp.drop("repeated gaze_timestamp (the sample with more eyes, then more confidence, kept)",
                      int(rep.sum()))
        s = {k: v[~rep] for k, v in s.items()}
        cut = len(s["t"]) if final else int(np.searchsorted(s["t"], self.latest - REORDER_WINDOW_S, "right"))
        self.held = {k: v[cut:] for k, v in s.items()}
        if not cut:
            return None
        self.last = float(s["t"][cut - 1])
        return {k: v[:cut] for k, v in s.items()}


# --- head poses -------------------------------------------------------------------------------

def head_pose_matrices(rotation, translation, marker_size_mm: float) -> np.ndarray:
    """(n, 4, 4) ``T_world_from_head``, mm, of pose rows: ``rotation`` (n, 3) Rodrigues vectors and
    ``translation`` (n, 3) in marker sides, the world camera's pose in the head-pose model
    (Pupil's ``get_camera_pose`` inverts the PnP extrinsics: ``-rvec``, ``-R^T t``), i.e.
    ``T_world_from_camera``. NaN rows give NaN matrices."""
    r, tr = np.asarray(rotation, float).reshape(-1, 3), np.asarray(translation, float).reshape(-1, 3)
    ok = np.all(np.isfinite(np.hstack([r, tr])), axis=1)
    T = np.full((len(r), 4, 4), np.nan)
    T[ok] = np.eye(4)
    if ok.any():
        T[ok, :3, :3] = Rotation.from_rotvec(r[ok]).as_matrix()
        T[ok, :3, 3] = tr[ok] * marker_size_mm
        T[ok] = T[ok] @ np.linalg.inv(T_HEAD_FROM_WORLD_CAMERA)     # T_world_from_cam @ T_cam_from_head
    return T


def _import_poses(folder: Path, offset: float, imp: SessionImport, options: ImportOptions) -> np.ndarray:
    """Stream the head poses into ``imp`` after checking the model; return the valid poses' times."""
    if options.marker_size_mm is None or not options.marker_size_mm > 0:
        raise UserError(f"{folder / POSES_FILE}: Pupil's head poses are in marker sides; pass --marker-size-mm "
                        "(the printed marker's side, mm) to import them")
    tab = read_table(folder / MODEL_FILE, MODEL_COLUMNS, what="Pupil head-pose model CSV",
                     fix="export the head pose tracker's model from Pupil Player too")
    v = np.stack([np.column_stack([tab[f"vert_{i}_{a}"] for a in "xyz"]) for i in range(4)], axis=1)
    side = float(np.median(np.linalg.norm(v - np.roll(v, 1, axis=1), axis=2)))
    if not 0.8 < side < 1.25:
        raise UserError(f"{folder / MODEL_FILE}: its markers' sides are {side:.3g} units, not 1 (marker sides); "
                        "export the head-pose model again from Pupil Player")
    imp.count(f"{MODEL_FILE} markers", len(v))
    good, last = [], -np.inf
    for ch in column_chunks(folder / POSES_FILE, POSE_COLUMNS, POSE_COLUMNS[:7], imp):
        t = ch["timestamp"] - offset
        T = head_pose_matrices(np.column_stack([ch[f"rotation_{a}"] for a in "xyz"]),
                               np.column_stack([ch[f"translation_{a}"] for a in "xyz"]), options.marker_size_mm)
        imp.count(f"{POSES_FILE} rows", len(t))
        inc = np.isfinite(t) & (t > np.maximum.accumulate(np.r_[last, t[:-1]]))
        imp.drop("head pose row out of time order or without a time", int((~inc).sum()))
        t, T = t[inc], T[inc]
        ok = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
        imp.drop("head pose row without a pose (the tracker lost the markers)", int((~ok).sum()))
        if len(t):
            imp.add_head_poses(t, T)
            last = float(t[-1])
        good.append(t[ok])
    imp.note(f"head poses from {POSES_FILE} (model of {len(v)} markers) x --marker-size-mm {options.marker_size_mm:g}")
    return np.concatenate(good) if good else np.zeros(0)


def pose_covered(t_pose: np.ndarray, t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """(n,) bool: a valid pose lies within ``max_gap_s`` before and after each time (or at it),
    as ``tracking.timeline.interpolate_poses`` answers only there."""
    if not len(t_pose):
        return np.zeros(len(t), bool)
    j = np.searchsorted(t_pose, t, side="right")
    lo, hi = t_pose[np.clip(j - 1, 0, len(t_pose) - 1)], t_pose[np.clip(j, 0, len(t_pose) - 1)]
    inside = (j > 0) & (j < len(t_pose)) & (t - lo <= max_gap_s) & (hi - t <= max_gap_s)
    return np.isclose(lo, t, atol=1e-9, rtol=0) | inside


# --- the reader -------------------------------------------------------------------------------

def _world_video(export: Path, rec: Path | None):
    """(world video, its frame times from world_timestamps.npy in Pupil time) from the export or the
    recording folder, or (None, None)."""
    for folder in (f for f in (export, rec) if f is not None):
        video = next((v for v in (folder / f"world{x}" for x in (".mp4", ".mkv", ".avi")) if v.is_file()), None)
        if video is not None and (folder / "world_timestamps.npy").is_file():
            try:
                return video, np.asarray(np.load(folder / "world_timestamps.npy", allow_pickle=False), float).ravel()
            except ValueError as exc:
                raise UserError(f"{folder / 'world_timestamps.npy'}: not a numpy array file ({exc}); export the "
                                "world video again from Pupil Player") from None
    return None, None


def _scene_video(export: Path, rec: Path | None, offset: float, imp: SessionImport, options: ImportOptions):
    """Without device poses: the world video for ``process`` to track, or a still head. Returns
    (pose_source, image_size, fps)."""
    video, times = _world_video(export, rec)
    missing = [what for what, gone in (("world.mp4 with world_timestamps", video is None),
                                       ("--camera (world.intrinsics is not read)", options.camera is None),
                                       ("--markers", options.markers is None)) if gone]
    if missing:
        imp.note(f"no {POSES_FILE}: the head is taken as still (vergence only); for head poses tracked in the world "
                 f"video give {', '.join(missing)}")
        return "still_head", None, None
    cal = load_camera(options.camera)
    imp.set_camera(cal.camera_matrix, cal.dist_coeffs, cal.image_size, cal.model)
    imp.add_scene_video(video, times - offset)
    imp.count("world frames", len(times))
    imp.note(f"head poses to be tracked in {video.name} with {Path(options.camera).name} and the marker map")
    return "scene_video", cal.image_size, 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else None


def _emit(s: dict | None, pose_t, imp: SessionImport, options: ImportOptions, dts: list) -> None:
    """Write sorted samples: rays (eye1 -> left, eye0 -> right) and the device's 3D gaze."""
    if s is not None and pose_t is not None:
        ok = pose_covered(pose_t, s["t"], options.max_pose_gap_s)
        imp.drop(f"no head pose within {options.max_pose_gap_s:g} s", int((~ok).sum()))
        s = {k: v[ok] for k, v in s.items()}
    if s is None or not len(s["t"]):
        return None
    imp.add_rays(s["t"], s["c1"], s["n1"], s["v1"], s["c0"], s["n0"], s["v0"])
    if "gp" in s:
        imp.add_device_gaze(s["t"], np.where(s["binocular"][:, None], s["gp"], np.nan))
    if sum(len(d) for d in dts) < 10000:
        dts.append(np.diff(s["t"]))


def _stream_gaze(path: Path, offset: float | None, pose_t, imp: SessionImport, options: ImportOptions,
                 progress) -> float:
    """Stream ``gaze_positions.csv`` into ``imp``; return the eye rate (Hz)."""
    reorder, dts, seen = _Reorder(imp), [], 0
    required = EYE_COLUMNS[0] + EYE_COLUMNS[1]
    for ch in column_chunks(path, [c for c in GAZE_COLUMNS if c != "base_data"], required, imp, progress=progress):
        n = len(ch[required[0]])
        imp.count(f"{path.name} rows", n)
        ch["t"] = ch["gaze_timestamp"] - offset if offset is not None else (seen + np.arange(n)) / UNTIMED_RATE_HZ
        seen += n
        keep, valid = check_rows(ch, imp)
        s = {"t": ch["t"], "conf": ch.get("confidence", np.ones(n)), "nvalid": valid[0].astype(int) + valid[1],
             "v0": valid[0], "v1": valid[1], "c0": ch["c0"], "n0": ch["n0"], "c1": ch["c1"], "n1": ch["n1"]}
        if "gaze_point_3d_x" in ch:
            s["gp"] = np.column_stack([ch[f"gaze_point_3d_{a}"] for a in "xyz"])
            s["binocular"] = ~np.all(np.isnan(ch["c0"]), axis=1) & ~np.all(np.isnan(ch["c1"]), axis=1)
        _emit(reorder.push({k: v[keep] for k, v in s.items()}), pose_t, imp, options, dts)
    if reorder.held is not None:
        _emit(reorder.push({k: v[:0] for k, v in reorder.held.items()}, final=True), pose_t, imp, options, dts)
    dt = np.concatenate(dts) if dts else np.zeros(0)
    dt = dt[dt > 0]
    return UNTIMED_RATE_HZ if offset is None or not len(dt) else 1.0 / float(np.median(dt))


def _first_time(path: Path) -> tuple[float | None, bool]:
    """(the first finite ``gaze_timestamp`` or None without the column, has a confidence column)."""
    for ch in column_chunks(path, ["gaze_timestamp", "confidence"], []):
        t = ch.get("gaze_timestamp", np.ones(1))
        if "gaze_timestamp" not in ch or np.isfinite(t).any():
            return (float(t[np.isfinite(t)].min()) if "gaze_timestamp" in ch else None), "confidence" in ch
    return 0.0, True


def read_recording(src: Path, imp: SessionImport, options: ImportOptions, progress=None) -> None:
    """Import a Pupil Core recording, Player export or gaze CSV (module docstring) into ``imp``.

    Raises:
        UserError: no gaze_positions.csv, a missing column or unparsable cell, head poses without
            ``options.marker_size_mm``, a head-pose model not in marker sides.
    """
    gaze_csv, export, rec = _locate(Path(src), imp)
    offset, has_conf = _first_time(gaze_csv)
    if not has_conf:
        imp.note(f"{gaze_csv.name} has no confidence column: rows are not filtered by confidence")
    pose_t, image_size, fps = None, None, None
    if offset is None:
        imp.note(f"{gaze_csv.name} has no gaze_timestamp column, so it is no Pupil recording: samples are numbered "
                 f"in file order at {UNTIMED_RATE_HZ:g} Hz (invented times) and the head is taken as still")
        pose_source = "still_head"
    elif (export / POSES_FILE).is_file():
        pose_t, pose_source = _import_poses(export, offset, imp, options), "device"
    else:
        pose_source, image_size, fps = _scene_video(export, rec, offset, imp, options)
    if options.markers is not None:
        imp.set_marker_map(options.markers)
    rate = _stream_gaze(gaze_csv, offset, pose_t, imp, options, progress)
    imp.finish(rate, offset or 0.0, pose_source, FRAMES, image_size=image_size, fps=fps,
               eye_labels={"eye0": "right", "eye1": "left"},
               thresholds={"min_confidence": MIN_CONFIDENCE, "max_eye_distance_mm": MAX_EYE_DISTANCE_MM,
                           "eye_separation_mm": list(EYE_SEPARATION_MM), "reorder_window_s": REORDER_WINDOW_S},
               clock="Pupil time, s: session t = gaze_timestamp - clock_offset_s" if offset is not None
               else f"none in the file: t = row number / {UNTIMED_RATE_HZ:g} Hz")


# --- the writer -------------------------------------------------------------------------------

PUPIL_EPOCH_S = 4321.5   # the simulated recording's Pupil time at session time 0 (Pupil time has no fixed epoch)


def write_recording(sim: SimulatedRecording, dst: Path) -> None:
    """A simulated session as a Pupil recording with one Player export, ``dst/exports/000/``:
    ``gaze_positions.csv`` (documented columns; eye0 = right; samples with no valid eye left out),
    ``head_pose_tracker_poses.csv`` and ``_model.csv`` in marker sides (with the marker map's
    size; none without a marker map), ``world.mp4`` with ``world_timestamps.npy`` and ``.csv``;
    and ``dst/info.player.json``. Pupil time = session time + ``PUPIL_EPOCH_S``."""
    export = Path(dst) / "exports" / "000"
    export.mkdir(parents=True, exist_ok=True)
    r, ts, (W, H) = sim.rays, sim.t + PUPIL_EPOCH_S, sim.image_size
    uv = _project(sim, sim.gaze_head_mm)
    cols = {"gaze_timestamp": ts, "world_index": np.clip(np.searchsorted(sim.frame_times, sim.t), 0,
                                                           len(sim.frame_times) - 1),
            "confidence": np.full(len(ts), 0.97), "norm_pos_x": uv[:, 0] / W, "norm_pos_y": 1.0 - uv[:, 1] / H,
            "base_data": np.array([f"{float(x)!r}-0 {float(x)!r}-1" for x in ts], dtype=object),
            **{f"gaze_point_3d_{a}": np.where(r.left_valid & r.right_valid, sim.gaze_head_mm[:, j], np.nan)
               for j, a in enumerate("xyz")}}
    for e, od in ((0, (r.right_origin_mm, r.right_direction)), (1, (r.left_origin_mm, r.left_direction))):
        cols.update({name: od[k // 3][:, k % 3] for k, name in enumerate(EYE_COLUMNS[e])})
    keep = r.left_valid | r.right_valid
    with TableWriter(export / GAZE_FILE, GAZE_COLUMNS) as w:
        w.write({k: v[keep] for k, v in cols.items()})
    if sim.marker_map is not None:
        _write_head_poses(sim, export)
    shutil.copyfile(sim.video, export / f"world{sim.video.suffix.lower()}")
    np.save(export / "world_timestamps.npy", sim.frame_times + PUPIL_EPOCH_S)
    write_table(export / "world_timestamps.csv", {WORLD_TIME: sim.frame_times + PUPIL_EPOCH_S,
                                                  "pts": np.arange(len(sim.frame_times))})
    info = {"meta_version": "2.3", "recording_software_name": "Pupil Capture", "start_time_synced_s": float(ts[0]),
            "duration_s": float(sim.t[-1] - sim.t[0]), "recording_name": "wearable-gaze simulation"}
    (Path(dst) / "info.player.json").write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")


def _project(sim: SimulatedRecording, p_mm: np.ndarray) -> np.ndarray:
    """(n, 2) pixels of head-frame points through the simulated scene camera (NaN behind it)."""
    import cv2

    cam, p = sim.camera, np.asarray(p_mm, float).reshape(-1, 1, 3)
    project = cv2.fisheye.projectPoints if cam.model == "fisheye" else cv2.projectPoints
    uv = project(p, np.zeros(3), np.zeros(3), cam.camera_matrix, cam.dist_coeffs)[0].reshape(-1, 2)
    uv[~(p[:, 0, 2] > 0)] = np.nan
    return uv


def _write_head_poses(sim: SimulatedRecording, export: Path) -> None:
    """``head_pose_tracker_poses.csv`` (a pose per world frame, marker sides) and ``_model.csv``
    (each marker's corners / side, our cv2.aruco corner order: Pupil's order is not confirmed).
    pitch/yaw/roll are left empty (Pupil's Euler convention is not reproduced; not read)."""
    mm = load_marker_map(sim.marker_map)
    s = mm.marker_size_mm
    T, ok = interpolate_poses(sim.t, sim.T_world_from_head, sim.frame_times, max_gap_s=1.0)
    T_wc = T @ T_HEAD_FROM_WORLD_CAMERA
    rot = np.full((len(T), 3), np.nan)
    rot[ok] = Rotation.from_matrix(T_wc[ok, :3, :3]).as_rotvec()
    write_table(export / POSES_FILE, {"timestamp": sim.frame_times + PUPIL_EPOCH_S,
                                      **{f"rotation_{a}": rot[:, j] for j, a in enumerate("xyz")},
                                      **{f"translation_{a}": T_wc[:, j, 3] / s for j, a in enumerate("xyz")},
                                      **{k: np.full(len(T), np.nan) for k in ("pitch", "yaw", "roll")}})
    ids = sorted(mm.poses)
    corners = np.stack([mm.corners(i) / s for i in ids]) if ids else np.zeros((0, 4, 3))
    verts = {f"vert_{k}_{a}": corners[:, k, j] for k in range(4) for j, a in enumerate("xyz")}
    write_table(export / MODEL_FILE, {"marker_id": np.array(ids, int), **verts})
