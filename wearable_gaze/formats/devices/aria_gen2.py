"""Project Aria Gen2 MPS eye gaze (``aria-gen2``; docs/importers.md).

Files read (columns by name; a Gen2 file is told by its per-eye pitch columns, as projectaria_tools
``EyeGazeReader.cpp`` tells it, not by its name):

- eye gaze, ``*eye_gaze*.csv`` in the folder or in ``eye_gaze*/``: ``personalized_eye_gaze.csv``
  (after the in-session gaze calibration) before ``general_eye_gaze.csv``; the choice is in the
  import report. Columns used: ``tracking_timestamp_us``, ``{left,right}_yaw_rads_cpf``,
  ``{left,right}_pitch_rads_cpf`` and the eye origins ``t{x,y,z}_{left,right}_eye_cpf`` (m, CPF).
  ``yaw_rads_cpf``/``pitch_rads_cpf`` (the combined gaze) are not needed: the two lines carry it.
- head poses, ``closed_loop_trajectory.csv`` (``trajectory/``, ``slam/``, the folder, or beside an
  ``eye_gaze*`` folder given itself), the same schema as gen1 (``aria_trajectory``). Without one
  the head is taken as still (``still_head``), and the report says so.

Frames: CPF (X left, Y up, Z forward, m) to our head frame as gen1 (``aria.T_HEAD_FROM_CPF``). A
view line's direction is ``(sin yaw cos pitch, sin pitch, cos yaw cos pitch)`` in CPF
(EyeGazeReader.cpp ``yawPitchToDirection``; gen1's is ``(tan yaw, tan pitch, 1)``), from the
eye origin the file gives. The device frame of Gen2's trajectory is ``slam-front-left``
(DeviceCadExtrinsics.cpp: Gen2's origin sensor); ``T_DEVICE_FROM_CPF`` is the inverse of its CAD
row. The world is gen1's (``aria.T_WORLD_FROM_ARIAWORLD``).

The device's 3D gaze (comparison only, ``device_gaze.csv``): the reader's vergence point
(``getGazeVergencePoint``: the midpoint of the two lines' closest points, none when the lines
are within 0.75 deg of parallel, meet behind an eye, pass over 3 cm apart, or meet over 6 m ahead).

Clock: ``tracking_timestamp_us`` (device clock, us, shared with the trajectory); session t = 0 at
the first sample imported, ``clock_offset_s`` its device time.

Dropped and counted: rows with missing cells, NaN or non-numbers, an angle of 80 deg or more, an
eye origin over 50 mm from CPF's origin, a repeated time; with a trajectory, samples with no pose
within ``max_pose_gap_s``. Refused (one line): a Gen2 file missing one of the columns used,
times going back.

Not given by the device: eye rotation centres (the origins are nominal, +-32.5 mm), per-sample
validity, a scene video in MPS.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import UserError
from ..tables import chunk_numbers, iter_csv_chunks
from .aria import (
    EYE_POS,
    MAX_ANGLE_RAD,
    MAX_EYE_MM,
    T_HEAD_FROM_CPF,
    T_WORLD_FROM_ARIAWORLD,
    TRAJ_NAMES,
    _cad_T_cpf_from_sensor,
    cpf_to_head_mm,
    posed_rows,
    session_times,
    usable_rows,
)
from .aria_trajectory import TIME, TrajectoryStream, mps_header
from .common import ImportOptions, SessionImport

NAME = "aria-gen2"
SUPERSEDES = ("aria-mps",)
"""A Gen2 folder with a trajectory also has gen1's file names; its columns make it Gen2."""

GEN2_MARK = ("left_pitch_rads_cpf", "right_pitch_rads_cpf")
ANGLES = ("left_yaw_rads_cpf", "right_yaw_rads_cpf", *GEN2_MARK)
GAZE_GLOBS = ("*eye_gaze*.csv", "eye_gaze*/*.csv")
CHUNK_ROWS = 4096

CAD_SLAM_FRONT_LEFT = ((0.067294194, 0.006033819, 0.011768852), (-0.138127, -0.912873, -0.384166),
                       (0.308866, -0.408244, 0.859034))
"""Gen2 CAD row ``slam-front-left`` (tx, ty, tz m; Y; Z) = T_Cpf_Sensor, projectaria_tools
core/calibration/ConfigData.cpp @90f70ffe, ``kDeviceCadExtrinsicsGen2EVTSS`` (the S/S frame; the
L rows put the camera 3.8 mm further out; MPS CSVs do not say which)."""

T_DEVICE_FROM_CPF = np.linalg.inv(_cad_T_cpf_from_sensor(*CAD_SLAM_FRONT_LEFT))
"""p_device_mm = T_DEVICE_FROM_CPF @ p_cpf_mm: Gen2's T_Device_Cpf (Device = slam-front-left)."""

T_DEVICE_FROM_HEAD = T_DEVICE_FROM_CPF @ T_HEAD_FROM_CPF

VERGENCE_MIN_DEG = 0.75          # EyeGazeReader.cpp kVergenceMinAngleDeg
VERGENCE_MAX_MISS_M = 0.03       # kVergenceMaxMissDistanceM
VERGENCE_MAX_DEPTH_M = 6.0       # kVergenceMaxReliableDepthM


def _header(path: Path) -> list[str]:
    """The column names of a CSV (empty: unreadable), for detection."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            return [c.strip() for c in fh.readline().split(",")]
    except OSError:
        return []


def gaze_files(src: Path) -> list[Path]:
    """The Gen2 eye-gaze CSVs of the folder ``src`` (in it or in ``eye_gaze*/``): those whose
    header has a per-eye pitch column."""
    src = Path(src)
    found = {p for g in GAZE_GLOBS for p in src.glob(g) if p.is_file()}
    return sorted(p for p in found if any(c in _header(p) for c in GEN2_MARK))


def detect(src: Path) -> bool:
    """The folder holds a Gen2 MPS eye-gaze CSV (per-eye pitch columns)."""
    return bool(gaze_files(src))


def trajectory_file(src: Path) -> Path | None:
    """``closed_loop_trajectory.csv`` of the recording (see the module docstring), or None."""
    src = Path(src)
    bases = [src, src.parent] if src.name.startswith("eye_gaze") else [src]
    return next((b / n for b in bases for n in TRAJ_NAMES if (b / n).is_file()), None)


# --- geometry ---------------------------------------------------------------------------------

def cpf_directions(yaw, pitch) -> np.ndarray:
    """(n,) yaw and pitch, rad -> (n, 3) unit directions in CPF (``yawPitchToDirection``)."""
    cp = np.cos(pitch)
    return np.column_stack([np.sin(yaw) * cp, np.sin(pitch), np.cos(yaw) * cp])


def reader_vergence(o_left, d_left, o_right, d_right) -> tuple[np.ndarray, np.ndarray]:
    """Aria's reader's vergence point of n pairs of lines (origins (n, 3), unit directions (n, 3),
    one frame and unit, m): (points (n, 3), real (n,) bool). Not real (the reader's far fallback,
    NaN here): within ``VERGENCE_MIN_DEG`` of parallel, meeting behind an eye, closest points over
    ``VERGENCE_MAX_MISS_M`` apart, or over ``VERGENCE_MAX_DEPTH_M`` ahead of the eyes' midpoint."""
    c = np.clip(np.sum(d_left * d_right, axis=1), -1.0, 1.0)
    denom = 1.0 - c * c
    p12 = o_left - o_right
    a, b = np.sum(d_left * p12, axis=1), np.sum(d_right * p12, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (c * b - a) / denom
        s = (b - c * a) / denom
    pl, pr = o_left + t[:, None] * d_left, o_right + s[:, None] * d_right
    point = 0.5 * (pl + pr)
    fused = d_left + d_right
    fused /= np.maximum(np.linalg.norm(fused, axis=1, keepdims=True), 1e-12)
    ahead = np.sum(fused * (point - 0.5 * (o_left + o_right)), axis=1)
    real = ((c <= np.cos(np.deg2rad(VERGENCE_MIN_DEG))) & (denom > 1e-12) & (t >= 0) & (s >= 0)
            & (np.linalg.norm(pl - pr, axis=1) <= VERGENCE_MAX_MISS_M) & (ahead <= VERGENCE_MAX_DEPTH_M))
    return np.where(real[:, None], point, np.nan), real


# --- the eye-gaze file ------------------------------------------------------------------------

def choose_gaze_file(src: Path) -> tuple[Path, list[str], list[Path]]:
    """(the Gen2 gaze CSV to read: personalized before general, its checked header, the others).

    Raises:
        UserError: no Gen2 file, or the chosen one lacks a column used.
    """
    files = gaze_files(src)
    if not files:
        raise UserError(f"{src}: no Aria Gen2 eye-gaze CSV (with {', '.join(GEN2_MARK)}) in the folder or in "
                        "eye_gaze*/; pass the MPS output folder of one Gen2 recording")
    path = sorted(files, key=lambda p: ("personalized" not in p.name, p.name))[0]
    names = mps_header(path, "Gen2 eye-gaze CSV", "copy it again from the MPS output", (TIME, *ANGLES, *EYE_POS))
    return path, names, [p for p in files if p != path]


class _Rows:
    """One chunk of Gen2 rows: times (us), per-eye origins (n, 2, 3) m and directions (n, 2, 3),
    CPF, and the masks of the checks."""

    def __init__(self, rows, index: dict):
        cols, self.whole, self.finite = chunk_numbers(rows, index, (TIME, *ANGLES, *EYE_POS))
        self.t_us = cols[TIME]
        yaw = np.column_stack([cols[ANGLES[0]], cols[ANGLES[1]]])
        pitch = np.column_stack([cols[ANGLES[2]], cols[ANGLES[3]]])
        self.eyes_m = np.column_stack([cols[c] for c in EYE_POS]).reshape(-1, 2, 3)
        self.dirs = np.stack([cpf_directions(yaw[:, e], pitch[:, e]) for e in (0, 1)], axis=1)
        with np.errstate(invalid="ignore"):
            self.wild = self.finite & ((np.abs(yaw) >= MAX_ANGLE_RAD) | (np.abs(pitch) >= MAX_ANGLE_RAD)).any(axis=1)
            self.far_eye = (self.finite & ~self.wild
                            & (np.linalg.norm(self.eyes_m, axis=2) * 1000 > MAX_EYE_MM).any(axis=1))
        self.usable = self.finite & ~self.wild & ~self.far_eye


def _survey(path: Path, index: dict) -> tuple[float, float]:
    """(device time of the first usable row, us; the eye rate, Hz) from the file's first chunk
    with a usable row."""
    for rows, _ in iter_csv_chunks(path, "Gen2 eye-gaze CSV", CHUNK_ROWS):
        g = _Rows(rows, index)
        t = g.t_us[g.usable]
        if len(t):
            steps = np.diff(t)
            steps = steps[steps > 0]
            rate = 1e6 / float(np.median(steps)) if len(steps) else 90.0
            if not 1.0 <= rate <= 2000.0:
                raise UserError(f"{path}: {TIME} steps by {1e6 / rate:g} per sample; the column must hold "
                                "microseconds of the device clock")
            return float(t[0]), rate
    raise UserError(f"{path}: no eye-gaze row with finite, plausible angles and eye origins; is the file complete?")


# --- the reader -------------------------------------------------------------------------------

def read_recording(src: Path, imp: SessionImport, options: ImportOptions, progress=None) -> None:
    """Stream an Aria Gen2 MPS eye-gaze folder into ``imp`` (see the module docstring)."""
    src = Path(src)
    path, names, others = choose_gaze_file(src)
    model = "personalized" if "personalized" in path.name else "general"
    imp.note(f"eye gaze from {path.relative_to(src)} (Gen2, {model} model)"
             + (f"; not read: {', '.join(str(p.relative_to(src)) for p in others)}" if others else ""))
    if model == "general":
        imp.note("the gaze is Aria's general model, not calibrated to this wearer (no personalized_eye_gaze.csv)")
    index = {n: j for j, n in enumerate(names) if n}
    t_first_us, rate = _survey(path, index)
    traj = trajectory_file(src)
    trajectory = None
    if traj is None:
        imp.note("no closed_loop_trajectory.csv (looked in trajectory/, slam/ and the folder): the head is taken as "
                 "still, its frame is the world, so the estimates are vergence only")
    else:
        trajectory = TrajectoryStream(traj, imp, t_first_us, T_WORLD_FROM_ARIAWORLD, T_DEVICE_FROM_HEAD, progress)
    state = {"t0_us": None, "last_us": -np.inf, "real": 0}
    for rows, _ in iter_csv_chunks(path, "Gen2 eye-gaze CSV", CHUNK_ROWS):
        _import_chunk(_Rows(rows, index), imp, options, trajectory, state, path)
    extra = {"eye_gaze": {"file": str(path.relative_to(src)), "model": model,
                          "not_read": [str(p.relative_to(src)) for p in others],
                          "reader_vergence_points": state["real"]}}
    if trajectory is not None:
        trajectory.close()
        if trajectory.n_kept == 0:
            raise UserError(f"{traj}: no usable pose row; is the trajectory file complete?")
        extra["trajectory"] = {"file": str(traj.relative_to(src)) if src in traj.parents else str(traj),
                               "graph_uid": trajectory.graph_uid, "poses_used": trajectory.n_kept}
    t0 = state["t0_us"] if state["t0_us"] is not None else t_first_us
    imp.finish(rate, t0 / 1e6, "device" if trajectory is not None else "still_head",
               _frames(trajectory.graph_uid if trajectory is not None else None), **extra)


def _import_chunk(g: _Rows, imp: SessionImport, options: ImportOptions, trajectory, state: dict, path: Path) -> None:
    """Drop and count the unusable rows of one chunk, pose the rest (with a trajectory), hand
    them to ``imp``."""
    sel = usable_rows(g, imp, state, path, "Gen2 eye-gaze CSV", "eye origin")
    T, sel = posed_rows(trajectory, g.t_us, sel, imp, options.max_pose_gap_s)
    if not len(sel):
        return
    t = session_times(g.t_us[sel], state)
    o, d = g.eyes_m[sel], g.dirs[sel]
    M = T_HEAD_FROM_CPF[:3, :3]
    yes = np.ones(len(sel), bool)
    imp.add_rays(t, cpf_to_head_mm(o[:, 0]), d[:, 0] @ M.T, yes, cpf_to_head_mm(o[:, 1]), d[:, 1] @ M.T, yes)
    if T is not None:
        imp.add_head_poses(t, T)
    point, real = reader_vergence(o[:, 0], d[:, 0], o[:, 1], d[:, 1])
    state["real"] += int(real.sum())
    imp.add_device_gaze(t, cpf_to_head_mm(point))


def _frames(graph_uid) -> dict:
    m = lambda T: np.round(T, 9).tolist()  # noqa: E731
    return {"head": "Aria CPF (X left, Y up, Z forward, m) turned 180 deg about Z, mm: x right, y down, z forward",
            "T_head_from_cpf": m(T_HEAD_FROM_CPF),
            "direction": "(sin yaw cos pitch, sin pitch, cos yaw cos pitch) in CPF (EyeGazeReader.cpp)",
            "device": "Aria Gen2 slam-front-left; T_device_from_cpf from the CAD row (EVT-SS), projectaria_tools "
                      "core/calibration/ConfigData.cpp @90f70ffe",
            "T_device_from_cpf": m(T_DEVICE_FROM_CPF),
            "world": (f"Aria SLAM world (graph_uid {graph_uid}; +z up, m) turned +90 deg about x, mm: y down"
                      if graph_uid is not None else "the head frame at rest (no trajectory: a still head)"),
            "T_world_from_ariaworld": m(T_WORLD_FROM_ARIAWORLD)}


def write_recording(sim, dst: Path) -> None:
    """Not written: the round trip of Aria's MPS files is ``aria-mps``'s (gen1 schema)."""
    raise UserError("export-recording --format aria-gen2 is not available (the simulator writes Aria's gen1 MPS "
                    "files only); use --format aria-mps (Aria gen1 MPS files) for a round trip")
