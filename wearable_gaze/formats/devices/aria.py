"""Project Aria gen1 MPS outputs (``aria-mps``; docs/importers.md; research: docs/devices/aria-mps.md).

Files read (columns by name; the eye-gaze model told by the header, not the file name):

- eye gaze, ``eye_gaze*/*.csv``: preferred a per-eye file (the March-2024 model; personalized
  before general): ``tracking_timestamp_us, left_yaw_rads_cpf, right_yaw_rads_cpf,
  pitch_rads_cpf`` (one pitch shared by both eyes), ``depth_m`` and the eye positions
  ``t{x,y,z}_{left,right}_eye_cpf`` (m, as given; nominal +-31.5 mm if absent). Else the pre-2024
  model (``generalized_eye_gaze.csv``, else ``eyegaze.csv``: ``yaw_rads_cpf, pitch_rads_cpf``):
  one cyclopean line per sample from the CPF origin, as the left eye (right invalid). Gen2
  files (per-eye pitch) are refused.
- head poses, ``closed_loop_trajectory.csv`` (in ``trajectory/``, ``slam/`` or the folder; 1 kHz):
  ``tracking_timestamp_us``, ``t{x,y,z}_world_device`` (m), ``q{x,y,z,w}_world_device`` (Hamilton,
  scalar last) of T_world_device, ``graph_uid``, ``quality_score``. Streamed in chunks, merged with
  the eye samples: only the poses around eye samples are kept, and each eye sample gets the pose
  interpolated between its two neighbours (SLERP + linear, ``tracking.timeline``).

Frames (the constants below):

- CPF (central pupil frame, CAD only): X to the wearer's left, Y up, Z forward, m. Our head frame
  is CPF turned 180 deg about Z, in mm (``T_HEAD_FROM_CPF``: x right, y down, z forward). MPS has
  no scene video here, so the head frame is CPF, not a camera.
- device = the left SLAM camera; ``T_DEVICE_FROM_CPF`` = inverse of the gen1 CAD row
  ``camera-slam-left`` (T_Cpf_Sensor) in projectaria_tools core/calibration/ConfigData.cpp @90f70ffe,
  built as DeviceCadExtrinsics.cpp does (rotation columns [Y x Z, Y, Z]); the S row (the L row is
  2.4 mm away; MPS CSVs do not say which).
- world = Aria's SLAM world (its origin; +z up, m) turned +90 deg about x to y down, in mm
  (``T_WORLD_FROM_ARIAWORLD``). T_world_from_head = T_WORLD_FROM_ARIAWORLD T_ariaworld_from_device
  T_DEVICE_FROM_HEAD.
- a view line: direction normalise(tan yaw, tan pitch, 1) in CPF (EyeGaze.h
  getUnitVectorFromYawPitch) from the file's eye position (MPS's nominal pupils, not rotation
  centres). When most rows' two lines diverge as labelled (the gen1 sample: 117 of 123), the
  yaw columns are taken as swapped: decided once per file, reported (``eye_labels``).
- the device's 3D gaze (comparison only): ``depth_m`` along the combined direction (yaw
  atan((tan l + tan r)/2), the shared pitch), head frame; none where ``depth_m`` is empty.

Clock: ``tracking_timestamp_us`` (device clock of gaze and trajectory); session t = 0 at the first
eye sample imported, ``clock_offset_s`` = its device time, s.

Dropped and counted: rows with missing cells (a truncated line); NaN or non-numeric times, angles
or eye positions; an angle >= 80 deg; an eye position > 50 mm from CPF's origin; a repeated time;
eye samples with no pose within ``max_pose_gap_s`` (before, after, or in a gap of the trajectory);
trajectory rows with NaN, a non-unit quaternion, a repeated time or another SLAM world (graph_uid)
than the first. Refused (``UserError``): a missing file or column, an ``eye_gaze*/*.csv`` with neither
model's angle columns (garbage or renamed: not passed over for another file), times going back,
gen2 gaze.

Not given by the device: per-eye pitch, eye rotation centres, per-sample validity, a scene video.
Not read by the import: online calibration, open-loop trajectory, summary.json. The semi-dense
point cloud (``global_points.csv.gz``: ``px,py,pz_world`` m, ``dist_std`` m) is read by
``read_point_cloud``, for the reference depths of the real-data tests and README table.

projectaria-tools is not used: it pulls a ~450 MB closure (jupyter, a pinned rerun-sdk), cannot
stream, prints to stdout and returns empty lists on errors; the files are documented CSVs and the
one non-trivial piece, T_Device_Cpf, is a constant cited above.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tracking.timeline import interpolate_poses

from ...errors import UserError
from ..tables import TableWriter, chunk_numbers, iter_csv_chunks
from .aria_trajectory import POSE_COLS, TIME, TrajectoryStream, in_order, mps_header
from .common import ImportOptions, SessionImport, SimulatedRecording

log = logging.getLogger(__name__)

NAME = "aria-mps"


def _cad_T_cpf_from_sensor(t_m, y_axis, z_axis) -> np.ndarray:
    """A CAD row (translation m, Y and Z axes) as T_cpf_from_sensor (4, 4), mm."""
    y = np.asarray(y_axis, float) / np.linalg.norm(y_axis)
    z = np.asarray(z_axis, float) / np.linalg.norm(z_axis)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T[:3, 3] = np.asarray(t_m, float) * 1000.0
    return T


CAD_SLAM_LEFT = {"S": ((0.069051, 0.002372, 0.009254), (0.793353, 0.0, -0.608761), (0.607927, -0.052336, 0.792266)),
                 "L": ((0.071351, 0.002372, 0.008454), (0.793353, 0.0, -0.608761), (0.607927, -0.052336, 0.792266))}
"""Gen1 CAD rows ``camera-slam-left`` (tx, ty, tz m; Y; Z) = T_Cpf_Sensor, projectaria_tools
core/calibration/ConfigData.cpp @90f70ffe (DVT-S/EVT-S and DVT-L/EVT-L)."""

CAD_VARIANT = "S"
T_DEVICE_FROM_CPF = np.linalg.inv(_cad_T_cpf_from_sensor(*CAD_SLAM_LEFT[CAD_VARIANT]))
"""p_device_mm = T_DEVICE_FROM_CPF @ p_cpf_mm: Aria's T_Device_Cpf (gen1, S), the inverse of the
CAD row (DeviceCadExtrinsics.cpp sets T_Device_Cpf = T_Cpf_Sensor(camera-slam-left).inverse())."""

T_HEAD_FROM_CPF = np.diag([-1.0, -1.0, 1.0, 1.0])
"""Our head frame (x right, y down, z forward) from CPF (X left, Y up, Z forward), both mm: 180
deg about Z (its own inverse). CPF axes: projectaria_tools website cpf-coor.mdx."""

T_DEVICE_FROM_HEAD = T_DEVICE_FROM_CPF @ T_HEAD_FROM_CPF

T_WORLD_FROM_ARIAWORLD = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                                   [0.0, 0.0, 0.0, 1.0]])
"""Our world (y down, mm) from Aria's SLAM world (z up; gravity (0, 0, -9.81) in
closed_loop_trajectory.csv), both mm: +90 deg about x; the origin is Aria's."""

PER_EYE = ("left_yaw_rads_cpf", "right_yaw_rads_cpf", "pitch_rads_cpf")
LEGACY = ("yaw_rads_cpf", "pitch_rads_cpf")
EYE_POS = tuple(f"t{a}_{s}_eye_cpf" for s in ("left", "right") for a in "xyz")
NOMINAL_EYE_X_M = 0.0315                     # EyeGazeReader.h: IPD_meters = 0.063, left eye at +X
TRAJ_NAMES = ("trajectory/closed_loop_trajectory.csv", "slam/closed_loop_trajectory.csv", "closed_loop_trajectory.csv")
MAX_ANGLE_RAD = np.deg2rad(80.0)
MAX_EYE_MM = 50.0
DEPTH_CAP_M = 4.0                            # MPS caps depth_m at 4 m
CHUNK_ROWS = 2048                            # gaze rows per chunk


def detect(src: Path) -> bool:
    """The folder holds MPS eye gaze (``eye_gaze*/*.csv``) and a closed-loop trajectory."""
    src = Path(src)
    return any((src / n).is_file() for n in TRAJ_NAMES) and any(src.glob("eye_gaze*/*.csv"))


# --- geometry ---------------------------------------------------------------------------------

def head_directions(yaw, pitch) -> np.ndarray:
    """(n,) CPF yaw and pitch, rad -> (n, 3) unit directions in our head frame."""
    d = np.column_stack([-np.tan(yaw), -np.tan(pitch), np.ones(len(yaw))])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def cpf_to_head_mm(p_cpf_m) -> np.ndarray:
    """(n, 3) CPF points, m -> our head frame, mm."""
    return np.asarray(p_cpf_m, float) * 1000.0 @ T_HEAD_FROM_CPF[:3, :3].T


def combined_yaw(left_yaw, right_yaw) -> np.ndarray:
    """MPS's combined (cyclopean) yaw, rad (computeDepthAndCombinedGazeDirection)."""
    return np.arctan((np.tan(left_yaw) + np.tan(right_yaw)) / 2.0)


# --- the eye-gaze file ------------------------------------------------------------------------

def _gaze_file(src: Path):
    """(path, header, model) of the eye-gaze CSV to read (see the module docstring)."""
    best = None
    for p in sorted(src.glob("eye_gaze*/*.csv")):
        names = mps_header(p, "eye-gaze CSV", "pass an MPS output folder")
        if "yaw_rads_cpf" in names and "left_pitch_rads_cpf" in names and "right_pitch_rads_cpf" in names:
            raise UserError(f"{p}: an Aria Gen2 eye-gaze file (per-eye pitch), which --format aria-mps (gen1) "
                            "does not read; import it with --format aria-gen2, or leave --format out")
        model = "per-eye" if all(c in names for c in PER_EYE) else "pre-2024" if all(c in names for c in LEGACY) else ""
        part = PER_EYE if any(c in names for c in PER_EYE[:2]) else LEGACY if LEGACY[0] in names else ()
        if part and not model:           # a damaged file must not silently give way to an older model's
            raise UserError(f"{p}: missing column(s) {', '.join(c for c in part if c not in names)} of an MPS "
                            "eye-gaze CSV (a damaged copy); copy it again from the MPS output, or remove it")
        if not model:                    # garbage, or every angle column renamed: damaged too
            raise UserError(f"{p}: not an MPS eye-gaze CSV (no {', '.join(PER_EYE)} nor {', '.join(LEGACY)} "
                            "columns; a damaged copy?); copy it again from the MPS output, or remove it")
        if model:
            rank = (model == "per-eye", "personalized" in p.name, not p.name.startswith("eyegaze"))
            if best is None or rank > best[0]:
                best = (rank, p, names, model)
    if best is None:
        raise UserError(f"{src}: no MPS eye-gaze CSV in eye_gaze*/ (with {TIME}, left_yaw_rads_cpf, "
                        "right_yaw_rads_cpf, pitch_rads_cpf); pass the MPS output folder of one recording")
    _, path, names, model = best
    mps_header(path, "eye-gaze CSV", "pass an MPS output folder", (TIME,))
    return path, names, model


class _Gaze:
    """Parsed gaze rows of one chunk: times (us), angles, eye positions (CPF, m), depth, masks."""

    def __init__(self, rows, index: dict, model: str):
        angles = PER_EYE if model == "per-eye" else LEGACY
        pos = [c for c in EYE_POS if c in index]
        cols, self.whole, ok = chunk_numbers(rows, index, (TIME, *angles, *pos))
        self.t_us = cols[TIME]
        if model == "per-eye":
            self.yaw = np.column_stack([cols[PER_EYE[0]], cols[PER_EYE[1]]])
            self.pitch = cols[PER_EYE[2]]
            self.eyes_m = (np.column_stack([cols[c] for c in EYE_POS]).reshape(-1, 2, 3) if len(pos) == 6 else
                           np.tile([[NOMINAL_EYE_X_M, 0.0, 0.0], [-NOMINAL_EYE_X_M, 0.0, 0.0]], (len(rows), 1, 1)))
        else:
            self.yaw, self.pitch = cols[LEGACY[0]][:, None], cols[LEGACY[1]]
            self.eyes_m = np.zeros((len(rows), 1, 3))
        self.has_depth = "depth_m" in index
        self.depth_m = (chunk_numbers(rows, index, ("depth_m",))[0]["depth_m"] if self.has_depth
                        else np.full(len(rows), np.nan))
        self.finite = ok & np.all(np.isfinite(self.eyes_m.reshape(len(rows), -1)), axis=1)
        with np.errstate(invalid="ignore"):
            self.wild = self.finite & ((np.abs(self.yaw) >= MAX_ANGLE_RAD).any(axis=1)
                                       | (np.abs(self.pitch) >= MAX_ANGLE_RAD))
            self.far_eye = self.finite & ~self.wild & (np.linalg.norm(self.eyes_m, axis=2) * 1000 > MAX_EYE_MM).any(1)
        self.usable = self.finite & ~self.wild & ~self.far_eye

    def converging(self) -> np.ndarray:
        """(n,) +1 where the two lines as labelled meet in front, -1 where they diverge (0: no
        per-eye lines or unusable). Lines x = x_e + z tan(yaw_e) meet at z = dx / (tan r - tan l)."""
        if self.yaw.shape[1] < 2:
            return np.zeros(len(self.t_us))
        s = np.sign((self.eyes_m[:, 0, 0] - self.eyes_m[:, 1, 0]) * (np.tan(self.yaw[:, 1]) - np.tan(self.yaw[:, 0])))
        return np.where(self.usable, s, 0.0)


def _survey(path: Path, names: list[str], model: str) -> dict:
    """First pass over the gaze CSV (small: 10 Hz): the first time, the rate, the label votes."""
    index = {n: j for j, n in enumerate(names) if n}
    info = {"t_first_us": None, "dt_us": None, "rows": 0, "diverging": 0, "converging": 0, "uids": set()}
    for rows, _ in iter_csv_chunks(path, "eye-gaze CSV", CHUNK_ROWS):
        g = _Gaze(rows, index, model)
        info["rows"] += len(rows)
        t = g.t_us[g.usable]
        if info["t_first_us"] is None and len(t):
            info["t_first_us"] = float(t[0])
        if info["dt_us"] is None and len(t) > 1 and np.any(np.diff(t) > 0):
            info["dt_us"] = float(np.median(np.diff(t)[np.diff(t) > 0]))
        s = g.converging()
        info["diverging"] += int(np.sum(s < 0))
        info["converging"] += int(np.sum(s > 0))
        if "session_uid" in index and len(info["uids"]) < 20:
            info["uids"].update(r[index["session_uid"]].strip() for r in rows if len(r) > index["session_uid"])
    if info["t_first_us"] is None:
        raise UserError(f"{path}: no eye-gaze row with finite, plausible angles ({info['rows']} rows); is the file "
                        "complete?")
    rate = 1e6 / info["dt_us"] if info["dt_us"] else 10.0
    if not 1.0 <= rate <= 2000.0:
        raise UserError(f"{path}: {TIME} steps by {info['dt_us']:g} per sample ({rate:.3g} Hz if microseconds); "
                        "the column must hold microseconds of the device clock")
    info["rate_hz"] = rate
    return info


# --- the reader -------------------------------------------------------------------------------

POINTS_NAMES = ("trajectory/global_points.csv.gz", "slam/global_points.csv.gz", "global_points.csv.gz")


def read_point_cloud(src: Path, max_dist_std_m: float = 0.02) -> np.ndarray:
    """MPS's semi-dense points as (P, 3) in our world frame, mm, keeping those whose distance
    uncertainty ``dist_std`` is at most ``max_dist_std_m`` (streamed; the file may be gzipped).

    Raises:
        UserError: no point-cloud file, or a missing column.
    """
    path = next((Path(src) / n for n in POINTS_NAMES if (Path(src) / n).is_file()), None)
    if path is None:
        raise UserError(f"{src}: no global_points.csv.gz (MPS's point cloud); download the SLAM outputs too")
    cols = ("px_world", "py_world", "pz_world", "dist_std")
    names = mps_header(path, "point cloud", "download the SLAM outputs again", cols)
    index = {n: i for i, n in enumerate(names)}
    out = []
    for rows, _ in iter_csv_chunks(path, "point cloud", 65536):
        v, _, finite = chunk_numbers(rows, index, cols)
        keep = finite & (v["dist_std"] <= max_dist_std_m)
        p = 1000.0 * np.column_stack([v["px_world"], v["py_world"], v["pz_world"]])[keep]
        out.append(p @ T_WORLD_FROM_ARIAWORLD[:3, :3].T + T_WORLD_FROM_ARIAWORLD[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


MAX_KEPT_POINTS = 50_000
"""The most semi-dense points kept in the session for the report's 3D view (evenly thinned)."""


def _keep_points(src: Path, imp: SessionImport) -> None:
    """MPS's point cloud, where the folder has one (``read_point_cloud``'s well-placed points,
    thinned to ``MAX_KEPT_POINTS``), kept as the session's device points."""
    if not any((src / n).is_file() for n in POINTS_NAMES):
        return
    pts = read_point_cloud(src)
    if len(pts) > MAX_KEPT_POINTS:
        pts = pts[np.linspace(0, len(pts) - 1, MAX_KEPT_POINTS).astype(int)]
    imp.add_device_points(pts)
    imp.note(f"the SLAM point cloud kept for the 3D view: {len(pts)} points with dist_std <= 20 mm")


def read_recording(src: Path, imp: SessionImport, options: ImportOptions, progress=None) -> None:
    """Stream an Aria gen1 MPS folder into ``imp`` (see the module docstring); ``progress(bytes,
    total)`` follows the trajectory file."""
    src = Path(src)
    traj = next((src / n for n in TRAJ_NAMES if (src / n).is_file()), None)
    if traj is None:
        raise UserError(f"{src}: no closed_loop_trajectory.csv (looked in trajectory/, slam/ and the folder); Aria "
                        "head poses come from MPS SLAM: add its trajectory/ folder")
    path, names, model = _gaze_file(src)
    others = [str(p.relative_to(src)) for p in sorted(src.glob("eye_gaze*/*.csv")) if p != path]
    imp.note(f"eye gaze from {path.relative_to(src)} ({model} model)" + (f"; not read: {', '.join(others)}"
                                                                          if others else ""))
    if "personalized" not in path.name:
        imp.note("the gaze is Aria's general model, not calibrated to this wearer: where the head stands still the "
                 "depth comes from its vergence alone, which on MPS's sample reads about 2.7 deg too divergent; the "
                 "error model takes a general model's bias prior there (docs/processing.md, 'The error model')")
    info = _survey(path, names, model)
    swapped = info["diverging"] > info["converging"]
    if model == "per-eye":
        imp.note(f"per-eye labels {'swapped' if swapped else 'kept'}: {info['diverging']} of "
                 f"{info['diverging'] + info['converging']} rows' lines diverge as labelled")
    else:
        imp.note("pre-2024 eye-gaze model: one cyclopean line per sample (left eye), no device depth")
    if len(info["uids"]) > 1:
        imp.note(f"{len(info['uids'])} session_uid values (several calibrations or wearers) imported as one session")
    trajectory = TrajectoryStream(traj, imp, info["t_first_us"], T_WORLD_FROM_ARIAWORLD, T_DEVICE_FROM_HEAD, progress)
    state = {"t0_us": None, "last_us": -np.inf, "capped": 0}
    index = {n: j for j, n in enumerate(names) if n}
    for rows, _ in iter_csv_chunks(path, "eye-gaze CSV", CHUNK_ROWS):
        _import_chunk(_Gaze(rows, index, model), imp, options, trajectory, swapped, state, path)
    trajectory.close()
    if trajectory.n_kept == 0:
        raise UserError(f"{traj}: no usable pose row; is the trajectory file complete?")
    if trajectory.n_low_quality:
        imp.note(f"{trajectory.n_low_quality} trajectory rows have quality_score < 1 (kept: MPS gives no threshold)")
    if state["capped"]:
        imp.note(f"{state['capped']} samples have depth_m at MPS's {DEPTH_CAP_M:g} m cap (censored, not a measurement)")
    _keep_points(src, imp)
    t0 = state["t0_us"] if state["t0_us"] is not None else info["t_first_us"]
    imp.finish(info["rate_hz"], t0 / 1e6, "device", _frames(trajectory.graph_uid),
               eye_labels={"swapped": bool(swapped), "rows_diverging_as_labelled": info["diverging"],
                           "rows_converging_as_labelled": info["converging"],
                           "rule": "swapped when most rows' two lines diverge as labelled"},
               eye_gaze={"file": str(path.relative_to(src)), "model": model, "session_uids": sorted(info["uids"])},
               trajectory={"file": str(traj.relative_to(src)), "graph_uid": trajectory.graph_uid,
                           "poses_used": trajectory.n_kept})


def usable_rows(g, imp: SessionImport, state: dict, path: Path, what: str, eye: str) -> np.ndarray:
    """The indices (k,) of a gaze chunk's usable rows (``g``: ``t_us``, ``whole``, ``finite``,
    ``wild``, ``far_eye``, ``usable``), the others dropped and counted in ``imp``, a repeated time
    too (``state['last_us']``: the last time kept, updated); ``what``, ``eye``: the file and its
    eye field, in the messages. Raises if times go back (``in_order``)."""
    imp.count("eye gaze rows", len(g.t_us))
    imp.drop("gaze row truncated (missing cells)", int(np.sum(~g.whole)))
    imp.drop("gaze row with NaN or a non-number", int(np.sum(g.whole & ~g.finite)))
    imp.drop("gaze angle of 80 deg or more", int(g.wild.sum()))
    imp.drop(f"{eye} over {MAX_EYE_MM:g} mm from CPF", int(g.far_eye.sum()))
    sel = np.flatnonzero(g.usable)
    dup = in_order(path, what, g.t_us[sel], state["last_us"])
    imp.drop("gaze row with a repeated time", int(dup.sum()))
    sel = sel[~dup]
    if len(sel):
        state["last_us"] = float(g.t_us[sel[-1]])
    return sel


def session_times(t_us: np.ndarray, state: dict) -> np.ndarray:
    """Session times (k,) in s of a chunk's kept rows' device times ``t_us`` (k,) in us, from the
    first kept row of the file (``state['t0_us']``, set by the first chunk that keeps a row)."""
    if state["t0_us"] is None:
        state["t0_us"] = float(t_us[0])
    return (t_us - state["t0_us"]) / 1e6


def posed_rows(trajectory, t_us, sel, imp: SessionImport, max_gap_s: float) -> tuple:
    """(T_world_from_head (k, 4, 4), the rows ``sel`` kept) of the rows with a trajectory pose
    within ``max_gap_s``, the others dropped and counted with the trajectory's reason; (None,
    ``sel``) without a ``trajectory``."""
    if trajectory is None or not len(sel):
        return None, sel
    T, ok, why = trajectory.poses_at((t_us[sel] - trajectory.t_ref_us) / 1e6, max_gap_s)
    for reason, n in zip(*np.unique(why[~ok], return_counts=True), strict=True):
        imp.drop(str(reason), int(n))
    if not ok.any():                    # T is None when the trajectory has no pose left at all
        return None, sel[:0]
    return T[ok], sel[ok]


def _import_chunk(g: _Gaze, imp: SessionImport, options: ImportOptions, trajectory: TrajectoryStream, swapped: bool,
                  state: dict, path: Path) -> None:
    """Drop and count the unusable rows of one gaze chunk, pose the rest, hand them to ``imp``."""
    sel = usable_rows(g, imp, state, path, "eye-gaze CSV", "eye position")
    T, sel = posed_rows(trajectory, g.t_us, sel, imp, options.max_pose_gap_s)
    if not len(sel):
        return
    t = session_times(g.t_us[sel], state)
    eyes = cpf_to_head_mm(g.eyes_m[sel].reshape(-1, 3)).reshape(len(sel), -1, 3)
    if g.yaw.shape[1] == 2:
        yl, yr = (g.yaw[sel, 1], g.yaw[sel, 0]) if swapped else (g.yaw[sel, 0], g.yaw[sel, 1])
        yes = np.ones(len(sel), bool)
        imp.add_rays(t, eyes[:, 0], head_directions(yl, g.pitch[sel]), yes,
                     eyes[:, 1], head_directions(yr, g.pitch[sel]), yes)
        yc = combined_yaw(g.yaw[sel, 0], g.yaw[sel, 1])
    else:
        nan = np.full((len(sel), 3), np.nan)
        imp.add_rays(t, eyes[:, 0], head_directions(g.yaw[sel, 0], g.pitch[sel]), np.ones(len(sel), bool),
                     nan, nan, np.zeros(len(sel), bool))
        yc = g.yaw[sel, 0]
    imp.add_head_poses(t, T)
    depth = g.depth_m[sel]
    state["capped"] += int(np.sum(depth >= DEPTH_CAP_M))
    if g.has_depth:
        imp.add_device_gaze(t, head_directions(yc, g.pitch[sel]) * depth[:, None] * 1000.0)


def _frames(graph_uid) -> dict:
    m = lambda T: np.round(T, 9).tolist()  # noqa: E731
    return {"head": "Aria CPF (X left, Y up, Z forward, m) turned 180 deg about Z, mm: x right, y down, z forward",
            "T_head_from_cpf": m(T_HEAD_FROM_CPF),
            "device": f"Aria gen1 camera-slam-left; T_device_from_cpf from the CAD row ({CAD_VARIANT} frame), "
                      "projectaria_tools core/calibration/ConfigData.cpp @90f70ffe",
            "T_device_from_cpf": m(T_DEVICE_FROM_CPF),
            "world": f"Aria SLAM world (graph_uid {graph_uid}; +z up, m) turned +90 deg about x, mm: y down",
            "T_world_from_ariaworld": m(T_WORLD_FROM_ARIAWORLD)}


# --- the writer -------------------------------------------------------------------------------

SIM_T0_US = 100_000_000_000                   # the device clock reads 1e5 s at session t = 0 (beyond 1e10 us)
SIM_GRAPH_UID = "00000000-0000-0000-0000-000000000001"
SIM_SESSION_UID = "00000000-0000-0000-0000-000000000002"
GAZE_OUT = ("tracking_timestamp_us", *PER_EYE, "depth_m", *EYE_POS, "session_uid")
TRAJ_OUT = ("graph_uid", "tracking_timestamp_us", "utc_timestamp_ns", *POSE_COLS,
            "gravity_x_world", "gravity_y_world", "gravity_z_world", "quality_score")


def write_recording(sim: SimulatedRecording, dst: Path) -> None:
    """Write a simulated session as an MPS-like folder: ``eye_gaze/generalized_eye_gaze.csv``
    (per-eye yaw, the pitch shared by both eyes: the two eyes' mean, depth_m from the two lines'
    closest approach capped at 4 m, the eye positions as given; a sample with an invalid eye has
    empty angles) and ``trajectory/closed_loop_trajectory.csv`` (T_world_device at 1 kHz, m,
    interpolated from the head poses at the eye samples). CPF is the simulated head frame moved
    to the eyes' mean midpoint ``c`` (CPF's origin is between the eyes) and turned to Aria's
    axes; labels follow the library's convention (lines meet in front as labelled). Read back,
    the head frame is that CPF: rays come back moved by -c, poses by +c (world lines equal),
    changed only by the shared pitch (each eye's pitch -> the mean of the two)."""
    dst = Path(dst)
    (dst / "eye_gaze").mkdir(parents=True, exist_ok=True)
    (dst / "trajectory").mkdir(parents=True, exist_ok=True)
    t_us = np.round(np.asarray(sim.t, float) * 1e6).astype(np.int64) + SIM_T0_US
    r = sim.rays
    c = np.nanmean(np.concatenate([r.left_origin_mm[r.left_valid], r.right_origin_mm[r.right_valid]]), axis=0)
    T_head_from_cpf = T_HEAD_FROM_CPF.copy()
    T_head_from_cpf[:3, 3] = c
    with TableWriter(dst / "eye_gaze" / "generalized_eye_gaze.csv", GAZE_OUT,
                     {c: ".12f" for c in GAZE_OUT if c not in ("tracking_timestamp_us", "session_uid")}) as w:
        for a in range(0, len(t_us), 4096):
            w.write(_gaze_columns(t_us[a:a + 4096], r.select(slice(a, a + 4096)), c))
    T_dev = np.linalg.inv(T_WORLD_FROM_ARIAWORLD) @ sim.T_world_from_head @ T_head_from_cpf @ np.linalg.inv(
        T_DEVICE_FROM_CPF)
    grid = np.concatenate([np.arange(t_us[0], t_us[-1], 1000, dtype=np.int64), t_us[-1:]])
    with TableWriter(dst / "trajectory" / "closed_loop_trajectory.csv", TRAJ_OUT,
                     {**{c: ".9f" for c in POSE_COLS[3:]}, **{c: ".6f" for c in POSE_COLS[:3]}}) as w:
        for a in range(0, len(grid), 10000):
            tq = grid[a:a + 10000]
            lo = max(int(np.searchsorted(t_us, tq[0], side="right")) - 1, 0)
            hi = int(np.searchsorted(t_us, tq[-1], side="left")) + 1
            T, ok = interpolate_poses((t_us[lo:hi] - SIM_T0_US) / 1e6, T_dev[lo:hi], (tq - SIM_T0_US) / 1e6,
                                      max_gap_s=np.inf)
            if not ok.all():
                raise ValueError("the simulated head poses do not cover the trajectory's times")
            w.write(_trajectory_columns(tq, T))
    log.info("wrote %d eye samples and %d poses (1 kHz) to %s", len(t_us), len(grid), dst)


def _gaze_columns(t_us: np.ndarray, rays, c_mm) -> dict:
    """The eye-gaze CSV columns of n simulated samples (head-frame rays; CPF origin at ``c_mm``)."""
    M = T_HEAD_FROM_CPF[:3, :3]                                  # its own inverse
    both = rays.left_valid & rays.right_valid
    d = [np.where(both[:, None], rays.left_direction, np.nan) @ M.T,
         np.where(both[:, None], rays.right_direction, np.nan) @ M.T]
    o = [(np.where(both[:, None], rays.left_origin_mm, np.nan) - c_mm) @ M.T / 1000.0,
         (np.where(both[:, None], rays.right_origin_mm, np.nan) - c_mm) @ M.T / 1000.0]
    with np.errstate(invalid="ignore", divide="ignore"):
        yaw = [np.arctan(e[:, 0] / e[:, 2]) for e in d]
        pitch = (np.arctan(d[0][:, 1] / d[0][:, 2]) + np.arctan(d[1][:, 1] / d[1][:, 2])) / 2
    cols = {"tracking_timestamp_us": t_us, PER_EYE[0]: yaw[0], PER_EYE[1]: yaw[1], PER_EYE[2]: pitch,
            "depth_m": _vergence_depth_m(o, yaw, pitch), "session_uid": np.full(len(t_us), SIM_SESSION_UID, object)}
    for k, c in enumerate(EYE_POS):
        cols[c] = o[k // 3][:, k % 3]
    return cols


def _vergence_depth_m(origins_m, yaw, pitch) -> np.ndarray:
    """(n,) MPS's depth_m (EyeGazeReader.h getGazeIntersectionPoint, with the written eye
    positions' x): the two lines' crossing in CPF's XZ plane, its norm, capped at 4 m; NaN where
    they do not meet in front (MPS leaves the cell empty)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (origins_m[0][:, 0] - origins_m[1][:, 0]) / (np.tan(yaw[1]) - np.tan(yaw[0]))
        p = np.column_stack([origins_m[0][:, 0] + z * np.tan(yaw[0]), z * np.tan(pitch), z])
        return np.where(z > 0, np.minimum(np.linalg.norm(p, axis=1), DEPTH_CAP_M), np.nan)


def _trajectory_columns(t_us: np.ndarray, T_ariaworld_from_device_mm: np.ndarray) -> dict:
    """The closed-loop trajectory columns of n poses (translation to m, quaternion x, y, z, w)."""
    q = Rotation.from_matrix(T_ariaworld_from_device_mm[:, :3, :3]).as_quat()
    n = len(t_us)
    cols = {"graph_uid": np.full(n, SIM_GRAPH_UID, object), "tracking_timestamp_us": t_us,
            "utc_timestamp_ns": np.full(n, -1), "gravity_x_world": np.zeros(n), "gravity_y_world": np.zeros(n),
            "gravity_z_world": np.full(n, -9.81), "quality_score": np.ones(n)}
    for k, c in enumerate(POSE_COLS[:3]):
        cols[c] = T_ariaworld_from_device_mm[:, k, 3] / 1000.0
    for k, c in enumerate(POSE_COLS[3:]):
        cols[c] = q[:, k]
    return cols
