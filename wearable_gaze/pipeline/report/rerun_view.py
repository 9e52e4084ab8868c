"""Viewing a session in rerun (docs/viewing.md): ``process --rerun out.rrd`` saves one,
``live --rerun`` streams one. rerun-sdk is an optional extra (``pip install
'wearable-gaze[rerun]'``, a 170 MB wheel): it is imported only inside the functions that log.

Two halves. The records: pure functions turning our results into the arrays rerun draws (the
95 % ellipsoid's half-sizes and rotation from a covariance, view lines as segments, the head path
split at its gaps, marker outlines), tested without rerun. The logging: a recording opened to a
file, a spawned viewer or a viewer's address (``open_recording``), the static scene
(``log_scene``: frame note, markers, camera, truth) and the timed events (``log_head_pose``,
``log_estimate``, ``log_target``), on the timeline ``session_time`` (s).

Everything is logged in our world frame, the marker map's: millimetres, x right, y down,
z forward (``rr.ViewCoordinates.RDF``, which is how the simulator's world is set up and how a map
whose origin marker hangs upright on a wall comes out); the head is the scene camera,
``T_world_from_cam``, with OpenCV camera axes.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ...errors import UserError

log = logging.getLogger(__name__)

RERUN_MISSING = "rerun-sdk is not installed: pip install 'wearable-gaze[rerun]'"
SPAWN = "spawn"             # ``--rerun`` with no value: spawn a viewer, or connect to the one running
TIMELINE = "session_time"   # seconds since the session's start
URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")
FRAME_NOTE = (
    "# wearable-gaze\n\nWorld frame: the marker map's, **millimetres** (1 unit = 1 mm), seconds on the "
    "`session_time` timeline. Axes x right, y down, z forward (RDF) as in the simulator; a real map's axes are "
    "its origin marker's. `world/head` is the scene camera (`T_world_from_cam`, OpenCV axes); its pinhole is the "
    "calibration's linear part (the lens distortion is not drawn). Targets: the estimate and its 95 % "
    "confidence ellipsoid; `view_lines`: the fixation's lines from each eye to a little past the target.")
MAX_LINES_PER_TARGET = 120  # view lines drawn per target and eye (evenly thinned)
LINE_OVERSHOOT = 1.15       # a view line is drawn to this many times the target's depth along it


# --- the records: pure functions, no rerun ----------------------------------------------------------

def parse_rerun_dest(value: str | None) -> tuple[str, str | None]:
    """What ``--rerun`` asks for: ('spawn', None) for no value (spawn a viewer or connect to the
    local one), ('connect', URL) for a viewer's address (``rerun+http://HOST:PORT/proxy``), or
    ('file', PATH) for an .rrd file.

    Raises:
        UserError: anything else, naming the three forms.
    """
    if value is None or value == SPAWN:
        return SPAWN, None
    if value.startswith(URL_SCHEMES):
        return "connect", value
    if value.endswith(".rrd") and len(value) > 4:
        return "file", value
    raise UserError(f"--rerun {value!r}: expected a file ending .rrd, a viewer address such as "
                    "rerun+http://127.0.0.1:9876/proxy, or nothing (spawn a viewer); put --rerun after the "
                    "positional arguments")


def require_rerun() -> None:
    """Check that rerun-sdk can be imported (before any work starts).

    Raises:
        UserError: ``RERUN_MISSING``.
    """
    try:
        import rerun  # noqa: F401
    except ImportError:
        raise UserError(RERUN_MISSING) from None


def ellipsoid_axes(covariances_mm2, probability: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Half-sizes and rotations of the ``probability`` confidence ellipsoids of Gaussians.

    Args:
        covariances_mm2: (M, 3, 3) covariances, world frame, mm^2.

    Returns:
        (half_sizes (M, 3) mm, increasing; R_world_from_axes (M, 3, 3) proper rotations whose
        column j is the direction of half-size j): the ellipsoid is
        {x : (x - c)^T C^-1 (x - c) <= chi2_3(probability)}.
    """
    C = np.asarray(covariances_mm2, float).reshape(-1, 3, 3)
    w, V = np.linalg.eigh(0.5 * (C + np.swapaxes(C, 1, 2)))
    half = np.sqrt(np.clip(w, 0.0, None) * chi2.ppf(probability, df=3))
    V = V.copy()
    V[np.linalg.det(V) < 0, :, 2] *= -1                       # a rotation, not a reflection
    return half, V


def line_of_sight_axes(positions_mm, viewpoints_mm) -> np.ndarray:
    """(M, 3, 3) rotations whose third column points from each viewpoint (M, 3) to its position
    (M, 3), world mm: the orientation given to a target read back from targets.json, which keeps
    the 95 % semi-axes (increasing) but not the covariance; its longest axis lies along the line of
    sight, as that of an estimate from view lines does."""
    P = np.asarray(positions_mm, float).reshape(-1, 3)
    z = P - np.asarray(viewpoints_mm, float).reshape(-1, 3)
    z /= np.maximum(np.linalg.norm(z, axis=1, keepdims=True), 1e-12)
    helper = np.where(np.abs(z[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=2)


def quaternions_xyzw(R) -> np.ndarray:
    """(M, 4) unit quaternions (x, y, z, w: rerun's order) of rotations (M, 3, 3)."""
    return Rotation.from_matrix(np.asarray(R, float).reshape(-1, 3, 3)).as_quat()


def target_ellipsoids(targets: list, viewpoints_mm=None) -> dict:
    """The ellipsoids of targets with a finite position and 95 % semi-axes.

    Args:
        targets: ``pipeline.types.Target`` (with a covariance, or read from a file without one).
        viewpoints_mm: {target index: (3,) where its lines came from, world mm}, used for a target
            without covariance (``line_of_sight_axes``); one without a viewpoint is left out.

    Returns:
        {'index' (M,), 'centers' (M, 3) mm, 'half_sizes' (M, 3) mm, 'quaternions' (M, 4) xyzw,
        'from_covariance' (M,) bool}.
    """
    rows = []
    for t in targets:
        center = np.asarray(t.position_mm, float)
        if not np.all(np.isfinite(center)):
            continue
        if t.covariance_mm2 is not None and np.all(np.isfinite(t.covariance_mm2)):
            half, axes = ellipsoid_axes(t.covariance_mm2)
            rows.append((t.index, center, half[0], axes[0], True))
        elif np.all(np.isfinite(t.axes95_mm)) and viewpoints_mm and t.index in viewpoints_mm:
            axes = line_of_sight_axes(center, viewpoints_mm[t.index])[0]
            rows.append((t.index, center, np.asarray(t.axes95_mm, float), axes, False))
    if not rows:
        return {"index": np.zeros(0, int), "centers": np.zeros((0, 3)), "half_sizes": np.zeros((0, 3)),
                "quaternions": np.zeros((0, 4)), "from_covariance": np.zeros(0, bool)}
    indices, centers, halves, rotations, from_covariance = zip(*rows, strict=True)
    return {"index": np.array(indices), "centers": np.array(centers),
            "half_sizes": np.array(halves), "quaternions": quaternions_xyzw(np.array(rotations)),
            "from_covariance": np.array(from_covariance)}


def view_line_segments(samples, target_mm, max_lines: int = MAX_LINES_PER_TARGET,
                       overshoot: float = LINE_OVERSHOOT) -> np.ndarray:
    """(K, 2, 3) view lines of a fixation as segments, world mm: each valid eye's line from its
    centre to ``overshoot`` times the depth of ``target_mm`` (3,) along it (where it passes the
    target); lines pointing away from the target are left out; at most ``max_lines`` samples,
    evenly thinned.

    Args:
        samples: ``estimator.BinocularSamples`` (N,), world frame.
    """
    X = np.asarray(target_mm, float)
    n = len(samples.t_s)
    keep = np.unique(np.linspace(0, n - 1, min(n, max_lines)).round().astype(int)) if n else np.zeros(0, int)
    segs = []
    for o, d, v in ((samples.left_origin_mm, samples.left_direction, samples.left_valid),
                    (samples.right_origin_mm, samples.right_direction, samples.right_valid)):
        o, d = o[keep][v[keep]], d[keep][v[keep]]
        depth = np.einsum("ij,ij->i", X - o, d)
        ok = depth > 0
        segs.append(np.stack([o[ok], o[ok] + overshoot * depth[ok, None] * d[ok]], axis=1))
    return np.concatenate(segs) if segs else np.zeros((0, 2, 3))


def head_path(T_world_from_cam) -> list[np.ndarray]:
    """The head's path as line strips, world mm: the camera centres (K, 3) of each run of
    frames with a pose (the poses (N, 4, 4), NaN where there is none), split at the gaps."""
    T = np.asarray(T_world_from_cam, float).reshape(-1, 4, 4)
    ok = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    strips, start = [], None
    for i, good in enumerate(np.append(ok, False)):
        if good and start is None:
            start = i
        elif not good and start is not None:
            if i - start >= 2:
                strips.append(T[start:i, :3, 3].copy())
            start = None
    return strips


def marker_outlines(marker_map) -> tuple[list[int], np.ndarray]:
    """(ids, (M, 5, 3) closed outlines of the markers' black squares, world mm) of a
    ``tracking.MarkerMap``."""
    ids = sorted(int(i) for i in marker_map.poses)
    if not ids:
        return [], np.zeros((0, 5, 3))
    C = np.stack([marker_map.corners(i) for i in ids])
    return ids, np.concatenate([C, C[:, :1]], axis=1)


def pinhole_of(camera) -> dict:
    """rerun's Pinhole arguments for a ``CameraCalibration``: ``image_from_camera`` (3, 3) K and
    ``resolution`` [width, height] (its linear part: the distortion is not drawn)."""
    return {"image_from_camera": np.asarray(camera.camera_matrix, float),
            "resolution": [int(camera.image_size[0]), int(camera.image_size[1])]}


# --- logging: rerun imported here only -------------------------------------------------------------

def open_recording(dest: str | None, name: str = "wearable-gaze"):
    """A ``rerun.RecordingStream`` sending to ``dest`` (``parse_rerun_dest``: an .rrd file, a
    viewer's address, or None / 'spawn': a viewer spawned, or the local one if it runs), with
    the frame note and the world's axes logged.

    Raises:
        UserError: rerun-sdk missing, or a bad ``dest``.
    """
    kind, where = parse_rerun_dest(dest)
    require_rerun()
    import rerun as rr

    rec = rr.RecordingStream("wearable_gaze")
    rec.send_recording_name(name)
    if where is None:                                 # SPAWN, the one kind without a place
        _spawn(rec)
    elif kind == "file":
        rec.save(str(Path(where)))
    else:
        rec.connect_grpc(where)
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    rec.log("notes", rr.TextDocument(FRAME_NOTE, media_type="text/markdown"), static=True)
    return rec


def _spawn(rec) -> None:
    """Spawn a viewer (or connect to the local one): the ``rerun`` executable is looked up on
    PATH, and beside this Python (a venv's bin/, not on PATH when the venv is not activated).

    Raises:
        UserError: no viewer executable.
    """
    old = os.environ.get("PATH", "")
    exe_dir = Path(sys.executable).parent
    if shutil.which("rerun") is None and (exe_dir / "rerun").is_file():
        os.environ["PATH"] = os.pathsep.join([str(exe_dir), old])
    try:
        rec.spawn()
    except RuntimeError as exc:
        raise UserError(f"--rerun: cannot spawn the viewer ({exc}); save a file instead: --rerun out.rrd") from None
    finally:
        os.environ["PATH"] = old


def close_recording(rec, timeout_s: float = 15.0) -> None:
    """Send everything logged, then close (an .rrd file is complete after this).

    Raises:
        UserError: the viewer could not be reached within ``timeout_s``.
    """
    try:
        rec.flush(timeout_sec=timeout_s)
    except RuntimeError as exc:
        raise UserError(f"the rerun viewer could not be reached ({exc}); start one (`rerun`) or save a file: "
                        "--rerun out.rrd, then `rerun out.rrd`") from None
    finally:
        rec.disconnect()


def log_scene(rec, camera=None, marker_map=None, truth_targets=None, truth_head=None) -> None:
    """The static scene: the scene camera's pinhole under ``world/head`` (a ``CameraCalibration``),
    the markers' outlines (a ``tracking.MarkerMap``), and when known the truth: targets (rows of
    truth/targets.json: ``position_mm``, or a moving one's ``path_mm``) and the head's true path
    (poses (N, 4, 4))."""
    import rerun as rr

    if camera is not None:
        rec.log("world/head/camera", rr.Pinhole(**pinhole_of(camera), camera_xyz=rr.ViewCoordinates.RDF,
                                                image_plane_distance=150.0), static=True)
    if marker_map is not None:
        ids, outlines = marker_outlines(marker_map)
        if ids:
            rec.log("world/markers", rr.LineStrips3D(outlines, radii=3.0, colors=[40, 40, 40],
                                                     labels=[f"marker {i}" for i in ids]), static=True)
    fixed = [t for t in truth_targets or () if "position_mm" in t]
    if fixed:
        rec.log("world/truth/targets", rr.Points3D([t["position_mm"] for t in fixed], radii=20.0,
                                                   colors=[40, 200, 40],
                                                   labels=[f"true target {t.get('index', '')}" for t in fixed]),
                static=True)
    paths = [np.asarray(t["path_mm"], float) for t in truth_targets or () if "path_mm" in t]
    if paths:
        rec.log("world/truth/target_paths", rr.LineStrips3D(paths, radii=4.0, colors=[40, 200, 40]), static=True)
    if truth_head is not None and head_path(truth_head):
        rec.log("world/truth/head_path", rr.LineStrips3D(head_path(truth_head), radii=2.0, colors=[40, 200, 40]),
                static=True)


def log_head_pose(rec, t_s: float, T_world_from_cam) -> None:
    """The head (scene camera) at session time ``t_s``: ``world/head`` gets ``T_world_from_cam``
    (4, 4), mm (rerun's Transform3D maps the child, the camera, into its parent, the world)."""
    import rerun as rr

    T = np.asarray(T_world_from_cam, float)
    rec.set_time(TIMELINE, duration=float(t_s))
    rec.log("world/head", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))


def log_frame(rec, t_s: float, image, jpeg_quality: int = 80) -> None:
    """A scene frame (H, W) or (H, W, 3) BGR uint8 at ``t_s``, JPEG-encoded, in the camera's pinhole."""
    import cv2
    import rerun as rr

    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    if ok:
        rec.set_time(TIMELINE, duration=float(t_s))
        rec.log("world/head/camera", rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))


def log_estimate(rec, t_s: float, position_mm, fixation: int) -> None:
    """The running estimate of the current fixation at ``t_s`` (``world/gaze/estimate``)."""
    import rerun as rr

    rec.set_time(TIMELINE, duration=float(t_s))
    rec.log("world/gaze/estimate", rr.Points3D([position_mm], radii=12.0, colors=[255, 160, 0],
                                               labels=[f"fixation {fixation}"]))


def log_target(rec, target, lines=None, viewpoint_mm=None, path: str | None = None) -> None:
    """A target at its last sample's time (``t_end``): its point and 95 % ellipsoid
    (``target_ellipsoids``; from its covariance, else along the line of sight from
    ``viewpoint_mm``), and its fixation's view lines (``lines``: ``BinocularSamples``) under
    ``path``/view_lines (default path ``world/targets/<index>``)."""
    import rerun as rr

    path = path or f"world/targets/{target.index}"
    rec.set_time(TIMELINE, duration=float(target.t_end))
    ok = target.status == "ok"
    color = [220, 40, 40] if ok else [150, 150, 150]
    label = f"target {target.index}: {target.status}"
    if np.all(np.isfinite(target.position_mm)):
        rec.log(path, rr.Points3D([target.position_mm], radii=15.0, colors=color, labels=[label]))
        ell = target_ellipsoids([target], None if viewpoint_mm is None else {target.index: viewpoint_mm})
        if len(ell["index"]):
            note = "" if ell["from_covariance"][0] else " (oriented along the line of sight)"
            rec.log(f"{path}/ellipsoid95", rr.Ellipsoids3D(
                centers=ell["centers"], half_sizes=ell["half_sizes"], quaternions=ell["quaternions"],
                colors=[*color, 90], fill_mode="transparentfillmajorwireframe", labels=[f"95 %{note}"]))
    if lines is not None and np.all(np.isfinite(target.position_mm)):
        segs = view_line_segments(lines, target.position_mm)
        if len(segs):
            rec.log(f"{path}/view_lines", rr.LineStrips3D(segs, radii=1.0, colors=[80, 140, 255, 120]))
    if target.trajectory is not None:                          # a moving target's smoothed path
        rec.log(f"{path}/path", rr.LineStrips3D([target.trajectory.positions_mm], radii=4.0, colors=color))


# --- a processed session ------------------------------------------------------------------------------

def view_processed(dest: str | None, out, targets=None, camera=None, markers=None, truth_targets=None,
                   truth_head=None, video=None, frame_stamps=None, frames_every: int = 0, truth_frame=None) -> str:
    """Log what ``process`` wrote into ``out`` to rerun (``open_recording(dest)``): the scene
    (camera, markers, truth), the head's pose per tracked frame and its path, the running
    estimates, each target with its ellipsoid and view lines; with ``frames_every`` > 0 one scene
    frame in that many (``video``, times from ``frame_stamps`` or the video's rate).

    Args:
        out: the output folder of ``process`` (poses.csv, viewlines.csv, estimates.csv,
            targets.json; each used when present).
        targets: this run's ``Target`` list (with covariances); None: read targets.json.
        camera, markers, truth_targets, truth_head: the files (camera.json, markers.json,
            truth/targets.json, truth/head_poses.csv), each None when there is none;
            ``truth_frame``: the ``truth_match.TruthFrame`` that moves the truth into the world of
            the map the run used (None: the truth's own; without a fit the truth is not shown).

    Returns:
        what was written to: the file, the address, or 'a spawned viewer'.
    """
    from ...formats.camera import load_camera
    from ...formats.markermap import load_marker_map
    from ...formats.poses import read_poses_csv
    from ...formats.truth import read_truth_targets

    out = Path(out)
    rec = open_recording(dest, f"wearable-gaze process {out}")
    try:
        cam = load_camera(camera) if camera is not None and Path(camera).is_file() else None
        mm = load_marker_map(markers) if markers is not None and Path(markers).is_file() else None
        truth_t = read_truth_targets(truth_targets) if truth_targets is not None else None
        truth_T = read_poses_csv(truth_head)[2] if truth_head is not None else None
        if truth_frame is not None:             # the truth moved into the world of the map used (or none)
            moved = truth_frame.T_map_from_truth is not None
            truth_t = truth_frame.targets(truth_t) if moved and truth_t is not None else None
            truth_T = truth_frame.poses(truth_T) if moved and truth_T is not None else None
        log_scene(rec, cam, mm, truth_t, truth_T)
        poses = read_poses_csv(out / "poses.csv") if (out / "poses.csv").is_file() else None
        if poses is not None:
            _log_head(rec, poses[0], poses[2])
            if frames_every > 0 and video is not None:
                _log_frames(rec, video, frame_stamps, frames_every)
        _log_estimates(rec, out / "estimates.csv")
        _log_targets(rec, out, targets)
    finally:
        close_recording(rec)
    _, where = parse_rerun_dest(dest)
    return "a spawned viewer" if where is None else where


def _log_head(rec, t, T_world_from_cam) -> None:
    import rerun as rr

    strips = head_path(T_world_from_cam)
    if strips:
        rec.log("world/head_path", rr.LineStrips3D(strips, radii=2.0, colors=[120, 120, 255]), static=True)
    for ts, T in zip(t, T_world_from_cam, strict=True):
        if np.all(np.isfinite(T)):
            log_head_pose(rec, ts, T)


def _log_frames(rec, video, frame_stamps, every: int) -> None:
    import cv2

    from ...formats.video import read_frame_times

    times = read_frame_times(frame_stamps)[1] if frame_stamps is not None else None
    cap = cv2.VideoCapture(str(video))
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    try:
        i = 0
        while cap.grab():
            if i % every == 0:
                ok, frame = cap.retrieve()
                if ok:
                    log_frame(rec, times[i] if times is not None and i < len(times) else i / fps, frame)
            i += 1
    finally:
        cap.release()


def _log_estimates(rec, path: Path) -> None:
    from ...formats.targets import read_estimates

    if not path.is_file():
        return
    est = read_estimates(path)
    for k in range(len(est["t"])):
        log_estimate(rec, est["t"][k], [est["x"][k], est["y"][k], est["z"][k]], int(est["segment"][k]))


def _log_targets(rec, out: Path, targets) -> None:
    """Each target with the view lines of its fixations (viewlines.csv's segments); a target
    read from targets.json gets its ellipsoid along the line of sight from the head's mean
    position over its samples."""
    from ...formats.targets import read_targets
    from ...formats.viewlines import read_viewlines_csv
    from ..types import Target

    if targets is None or any(t.covariance_mm2 is None for t in targets):
        if not (out / "targets.json").is_file():
            return
        targets = [Target.from_row(r) for r in read_targets(out / "targets.json")]
    segments = {s.key: s.samples for s in read_viewlines_csv(out / "viewlines.csv")} if (
        out / "viewlines.csv").is_file() else {}
    for t in targets:
        lines = [segments[f] for f in t.fixations if f in segments]
        samples = _concat(lines) if lines else None
        view = None
        if samples is not None:
            o = np.concatenate([samples.left_origin_mm, samples.right_origin_mm])
            view = np.nanmean(o, axis=0) if np.any(np.isfinite(o)) else None
        log_target(rec, t, samples, view)


def _concat(parts: list):
    from estimator import BinocularSamples

    if len(parts) == 1:
        return parts[0]
    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts])
    return BinocularSamples.from_arrays(joined("t_s"), joined("left_origin_mm"),
                                        joined("left_direction"), joined("right_origin_mm"),
                                        joined("right_direction"), joined("left_valid"),
                                        joined("right_valid"))
