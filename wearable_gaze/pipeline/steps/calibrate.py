"""The calibration and view-line steps over typed values (``calibrate_camera_views``,
``calibrate_eyes``, ``view_lines``: contents in, results out; ``process`` calls them), and the
``calibrate-camera``, ``calibrate-eyes`` and ``viewlines`` commands' file-level wrappers that
read, call the step and write (``*_files``)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from calibration.camera import (
    BoardSpec,
    CameraCalibration,
    calibrate_camera,
    detect_board,
    parse_board,
    select_frames,
    undistort_image,
)
from calibration.eyes import (
    CalibrationError,
    calibrate_eye,
    compare_models,
    estimate_center,
    target_readings,
    wall_pose,
)
from calibration.kappa import apply_kappa
from estimator import BinocularSamples
from estimator.deprecation import module_getattr, renamed_kwargs
from estimator.frames import rotate_directions, transform_points
from tracking.markers import MarkerDetector
from tracking.timeline import MAX_POSE_GAP_S, interpolate_poses

from ...errors import UserError, check_output
from ...formats.camera import calibration_dict, is_preview, load_camera, preview_path, write_camera
from ...formats.eye_samples import EyeSamples, read_eye_csv
from ...formats.eyes import eyes_dict, load_eyes
from ...formats.images import IMAGE_EXT, image_files, read_gray_image, write_image
from ...formats.person import person_correction_deg, read_person
from ...formats.poses import read_poses_csv
from ...formats.video import sampled_gray_frames
from ...formats.walls import Wall, WallsRecording, read_walls
from ..types import CameraResult, Poses, ViewLinesResult

NOMINAL_CENTERS_MM = np.array([[-32.0, 30.0, -20.0], [32.0, 30.0, -20.0]])

log = logging.getLogger(__name__)


# --- calibrate-camera --------------------------------------------------------------------------

def input_files(inputs) -> list:
    """The image and video files of the inputs (folders: their images, sorted, but not the
    undistortion preview ``calibrate-camera -o`` wrote beside its camera JSON there)."""
    files = []
    for p in inputs:
        p = Path(p)
        if p.is_dir():
            images = image_files(p)
            own = [f for f in images if is_preview(f)]
            if own:
                log.info("left out, a preview calibrate-camera wrote: %s", ", ".join(f.name for f in own))
            files += [f for f in images if f not in own]
        elif p.is_file():
            files.append(p)
        else:
            raise UserError(f"{p}: no such file or folder; pass images, a folder of images or a video")
    if not files:
        raise UserError("no images found in the inputs; pass images, a folder of images or a video")
    return files


def read_frames(files, max_video_frames: int, what: str = "the board"):
    """(name, grey image) for image files, and evenly spaced frames (at most
    ``max_video_frames``) of video files; ``what`` the images show, for messages."""
    for f in files:
        if f.suffix.lower() in IMAGE_EXT:
            yield f.name, read_gray_image(f, fix=f"pass PNG, JPEG, BMP or TIFF images of {what}")
            continue
        refused = f"{f}: neither an image nor a video OpenCV can open; pass images or a video of {what}"
        for i, gray in sampled_gray_frames(f, max_video_frames, refused):
            yield f"{f.name}#{i}", gray


@renamed_kwargs({"grey": "gray"})
def check_frame_size(name: str, gray, cam) -> None:
    """Refuse a frame (H, W) of another size than the camera calibration's (``name``: which).

    Raises:
        UserError: naming the two sizes and the fix.
    """
    if (gray.shape[1], gray.shape[0]) != tuple(cam.image_size):
        raise UserError(f"{name} is {gray.shape[1]}x{gray.shape[0]} but the camera calibration is for "
                        f"{cam.image_size[0]}x{cam.image_size[1]}; use this camera's calibration at this size")


def board_spec(board) -> BoardSpec:
    """The board of a ``--board`` text (``chessboard:9x6:25``, ``charuco:...``); a BoardSpec
    passes through."""
    if isinstance(board, BoardSpec):
        return board
    try:
        return parse_board(board)
    except ValueError as exc:
        raise UserError(f"--board {ascii(board)}: {exc}; e.g. chessboard:9x6:25 (inner corners, square mm)") from None


def _camera_outputs(out, files) -> tuple[Path, Path]:
    """The camera JSON and its preview image, checked not to overwrite an input."""
    out = Path(out)
    preview = preview_path(out)
    check_output(out, files, "-o")
    check_output(preview, files, "-o (its preview image)")
    return out, preview


def calibrate_camera_views(frames, spec, model: str = "pinhole", max_views: int = 40, progress=None) -> CameraResult:
    """Detect the board in views (name, grey image) of one camera, pick views for coverage and
    calibrate. Returns the calibration, why it cannot be trusted, and an undistortion preview."""
    views, size, first = [], None, None
    for k, (name, img) in enumerate(frames):
        h, w = img.shape[:2]
        if size is None:
            size, first = (w, h), img
        elif (w, h) != size:
            raise UserError(f"{name}: {w}x{h}, but the first image is {size[0]}x{size[1]}; calibrate one camera "
                            "at one resolution")
        views.append(detect_board(img, spec, name))
        if progress:
            progress(k + 1, k + 2)
    found = [v for v in views if v.ok]
    if len(found) > max_views:
        chosen = {v.name for v in select_frames(found, size, max_views)}
        for v in views:
            if v.ok and v.name not in chosen:
                v.reason = "not needed for coverage (frame selection)"
    try:
        cal = calibrate_camera(views, size, spec, model)
    except ValueError as exc:
        raise UserError(f"camera calibration: {exc}") from None
    assert size is not None and first is not None       # calibrate_camera needs views: one was read
    und, _ = undistort_image(first, cal, alpha=0.0)
    side = np.hstack([cv2.cvtColor(first, cv2.COLOR_GRAY2BGR), cv2.cvtColor(und, cv2.COLOR_GRAY2BGR)])
    cv2.putText(side, "original", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 1, (0, 0, 255), 2)
    cv2.putText(side, "undistorted", (size[0] + 10, 30), cv2.FONT_HERSHEY_SIMPLEX, 1, (0, 0, 255), 2)
    return CameraResult(cal, plausibility_warnings(cal, spec), side)


def _write_camera_result(out: Path, preview: Path, result: CameraResult) -> None:
    """The camera JSON (with ``trusted`` and the warnings, each also logged) and the preview PNG."""
    for w in result.warnings:
        log.warning("%s: camera calibration cannot be trusted: %s", out, w)
    write_camera(out, camera_json(result.calibration, result.warnings))
    write_image(preview, result.preview)


def calibrate_camera_files(inputs, board, out, model: str = "pinhole", max_views: int = 40,
                           progress=None) -> tuple[CameraCalibration, list]:
    """Detect the board (``--board`` text or BoardSpec) in images or videos, pick views for
    coverage, calibrate, write the camera JSON and an undistortion preview PNG beside it.
    Returns the calibration and the written paths."""
    spec = board_spec(board)
    files = input_files(inputs)
    out, preview = _camera_outputs(out, files)
    result = calibrate_camera_views(read_frames(files, 4 * max_views), spec, model, max_views, progress)
    _write_camera_result(out, preview, result)
    return result.calibration, [out, preview]


MAX_TRUSTED_RMS_PX = 1.0
MAX_ASPECT = 1.15


def plausibility_warnings(cal: CameraCalibration, spec=None) -> list[str]:
    """Why a calibration that OpenCV returned is plainly wrong, or [] when nothing is.

    A real camera has nearly square pixels (fx close to fy) and a well-detected board
    reprojects within a pixel; a --board size that does not match the printed board (corners
    matched to the wrong board points) breaks both.
    """
    K = cal.camera_matrix
    w, h = cal.image_size
    out = []
    fx, fy = float(K[0, 0]), float(K[1, 1])
    ratio = max(fx, fy) / min(fx, fy)
    if ratio > MAX_ASPECT:
        out.append(f"fx {fx:.0f} and fy {fy:.0f} px differ by a factor {ratio:.2f} (a real camera's pixels are "
                   "nearly square); check that --board matches the printed board")
    if cal.rms_px is not None and cal.rms_px > MAX_TRUSTED_RMS_PX:
        out.append(f"reprojection RMS {cal.rms_px:.2f} px exceeds {MAX_TRUSTED_RMS_PX:g} px; check --board "
                   "(COLSxROWS inner corners and the square size) and use sharp, still views")
    if not 0.1 * w < fx < 20 * w:
        out.append(f"fx {fx:.0f} px is implausible for a {w} px wide image (field of view beyond 3-157 deg)")
    if not (0.2 * w < K[0, 2] < 0.8 * w and 0.2 * h < K[1, 2] < 0.8 * h):
        out.append(f"principal point ({K[0, 2]:.0f}, {K[1, 2]:.0f}) is far from the image centre")
    return out


def camera_json(cal: CameraCalibration, warnings=None) -> dict:
    """The camera JSON of a calibration, with ``trusted`` and the ``warnings`` that make it
    untrusted (docs/formats.md)."""
    warnings = plausibility_warnings(cal) if warnings is None else list(warnings)
    return calibration_dict(cal, trusted=not warnings, warnings=warnings)


def format_camera_report(cal: CameraCalibration) -> str:
    K = cal.camera_matrix
    warnings = plausibility_warnings(cal)
    lines = [f"NOT TRUSTED: {w}" for w in warnings] + ([""] if warnings else [])
    lines += [f"camera ({cal.model}, {cal.image_size[0]}x{cal.image_size[1]}): RMS {cal.rms_px:.3f} px, "
              f"fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f}",
              "dist " + " ".join(f"{v:.5g}" for v in cal.dist_coeffs)]
    if cal.std:
        lines.append("standard deviations: " + " ".join(f"{k} {cal.std[k]:.2f}" for k in ("fx", "fy", "cx", "cy"))
                     + " px")
    lines += ["",
              f"{'view':<28} {'points':>6} {'rms px':>8}  status"]
    for v in cal.views:
        rms = "" if v["rms_px"] is None else f"{v['rms_px']:.3f}"
        lines.append(f"{v['view'][:28]:<28} {v['n_points']:>6} {rms:>8}  {'used' if v['used'] else v['reason']}")
    return "\n".join(lines)


# --- calibrate-eyes ----------------------------------------------------------------------------

@dataclass(frozen=True)
class EyeRecordings:
    """An eye calibration's contents: its files (walls.json read, docs/session.md), the samples
    (``extra``: the recording and target columns) and each wall image, grey, or the one-line
    error why it is missing or unreadable (raised when the wall is used)."""

    files: WallsRecording
    eye: EyeSamples
    extra: dict
    images: list[np.ndarray | UserError]


def read_eye_recordings(files: WallsRecording) -> EyeRecordings:
    eye, extra = read_eye_csv(files.csv_path, ["recording", "target"])
    images: list[np.ndarray | UserError] = []
    for w in files.walls:
        try:
            images.append(read_gray_image(w.image, "wall image",
                                          f"record the wall again or fix 'image' in {files.walls_path}"))
        except UserError as exc:
            images.append(exc)
    return EyeRecordings(files, eye, extra, images)


@renamed_kwargs({"centres": "centers"})
def calibrate_eyes_files(src, camera_path, out, model: str = "quadratic", centers=None, progress=None) -> dict:
    """``calibrate_eyes`` from files: writes eyes.json and returns its content. The eyes step
    ``process`` runs (``session_steps.run_eyes``)."""
    from ..process.session_steps import EyesInputs, run_eyes  # the steps' module imports this one
    from ..process.stepconf import EyesConfig
    files = read_walls(src)
    check_output(out, [camera_path, files.csv_path, files.walls_path, *files.images], "-o")
    camera = load_camera(camera_path)
    inputs = EyesInputs(camera, read_eye_recordings(files), Path(out))
    return run_eyes(EyesConfig(model, centers), inputs, progress)


@renamed_kwargs({"centres": "centers"})
def calibrate_eyes(rec: EyeRecordings, camera: CameraCalibration, model: str = "quadratic", centers=None,
                   progress=None) -> dict:
    """The eye calibration of a session's recordings (docs/session.md): wall poses from their
    reference markers, per-target readings, eye centres from two or more wall distances (or
    ``centers``, or a nominal headset geometry), and eq. 1-2 per eye. Returns the content of
    eyes.json."""
    n = len(rec.files.walls)
    P, readings, wall_report = _wall_readings(rec, camera, progress)
    depths = np.array([w["measured_distance_mm"] for w in wall_report])
    eyes_out = []
    for e, name in enumerate(("left", "right")):
        raw = np.vstack(readings[e])
        if not np.isfinite(raw).any():
            raise UserError(f"no valid {name}-eye samples in {rec.files.csv_path}: check the {name} eye's sensor and "
                            "record the calibration again")
        if centers is not None:
            c, cov, how = np.asarray(centers[e], float), None, "given"
        elif np.ptp(depths) > 0.2 * np.median(depths):
            ok = np.all(np.isfinite(raw), axis=1)
            c, cov = estimate_center(raw[ok], P[ok], NOMINAL_CENTERS_MM[e])
            how = "two-distance"
        else:
            c, cov, how = NOMINAL_CENTERS_MM[e], None, "nominal (one wall distance: record a second to estimate it)"
        try:
            cal = calibrate_eye(name, raw, P, c, plane_mm=float(depths[0]), model=model,
                                focal_px=float(camera.camera_matrix[0, 0]))
        except CalibrationError as exc:
            raise UserError(str(exc)) from None
        cal.report["centre_method"] = how
        cal.report["centre_sd_mm"] = None if cov is None else np.sqrt(np.diag(cov)).tolist()
        if len(raw) > 9:
            cal.report["model_loo_rms_deg"] = compare_models(name, raw, P, c, float(depths[0]))
        eyes_out.append(cal)
    if progress:
        progress(n + 2, n + 2)
    return eyes_dict(calibration_dict(camera), wall_report, eyes_out)


def _wall_readings(rec: EyeRecordings, camera: CameraCalibration, progress):
    """The targets (K, 3) in the camera frame, each eye's readings of them (per recording) and
    the report of each wall recording."""
    csv_path, recs, extra, eye = rec.files.csv_path, rec.files.walls, rec.extra, rec.eye
    targets_cam: list[np.ndarray] = []
    readings: list[list[np.ndarray]] = [[], []]         # per eye, per recording: (K, 2)
    wall_report: list[dict] = []
    for r, wall in enumerate(recs):
        P, wp = _wall_targets(rec.images[r], rec.files.walls_path, wall, camera)
        sel = extra["recording"].astype(int) == wall.recording
        if not sel.any():
            raise UserError(f"{csv_path}: no samples of recording {wall.recording}; record it again")
        per_eye = [target_readings(extra["target"][sel], eye.raw[sel, e], eye.valid[sel, e],
                                   eye.t[sel]) for e in range(2)]
        ids = per_eye[0][0]                             # the targets shown: the same for both eyes
        for e in range(2):
            readings[e].append(per_eye[e][1])
        if ids.min() < 0 or ids.max() >= len(P):
            bad = ids.min() if ids.min() < 0 else ids.max()
            raise UserError(f"{csv_path}: target {bad} in recording {r}, but walls.json lists {len(P)} dots (0-"
                            f"{len(P) - 1}); fix the target column")
        targets_cam.append(P[ids])
        wall_report.append({"recording": r, "image": wall.image_name, "nominal_distance_mm": wall.distance_mm,
                            "measured_distance_mm": float(wp.T_cam_from_wall[2, 3]), "tilt_deg": wp.tilt_deg,
                            "reference_rms_px": wp.rms * camera.camera_matrix[0, 0]})
        if progress:
            progress(r + 1, len(recs) + 2)
    return np.vstack(targets_cam), readings, wall_report


def _wall_targets(img, walls_path: Path, wall: Wall, camera: CameraCalibration):
    """Targets (K, 3) in the camera frame from the wall image's reference markers (``img``: the
    grey image, or the error why it is missing or unreadable)."""
    if isinstance(img, UserError):
        raise img
    check_frame_size(str(wall.image), img, camera)
    try:
        det = MarkerDetector(wall.dictionary)
    except ValueError as exc:
        raise UserError(f"{walls_path}: {exc}") from None
    found = det.detect_unique(img)       # {id: corners}; a repeated id is ambiguous and left out
    s = wall.marker_size_mm / 2
    wall_pts, img_pts = [], []
    for mid, c in wall.markers_wall_mm.items():
        if mid in found:
            wall_pts.append(c + np.array([[-s, -s], [s, -s], [s, s], [-s, s]]))
            img_pts.append(found[mid])
    if len(wall_pts) < 2:
        raise UserError(f"{wall.image}: {len(wall_pts)} of the wall's {len(wall.markers_wall_mm)} reference markers "
                        "found, need 2: make them visible and record again")
    try:
        wp = wall_pose(np.vstack(wall_pts), camera.undistort_points(np.vstack(img_pts)))
    except CalibrationError as exc:
        raise UserError(f"{wall.image}: {exc}") from None
    return wp.to_camera(wall.targets_wall_mm), wp


def format_eyes_report(result: dict) -> str:
    lines = ["wall recordings:"]
    for w in result["walls"]:
        lines.append(f"  {w['image']}: measured distance {w['measured_distance_mm']:.0f} mm, "
                     f"tilt {w['tilt_deg']:.1f} deg, reference points {w['reference_rms_px']:.2f} px RMS")
    lines.append("")
    lines.append(f"{'eye':<6} {'centre (mm)':<26} {'sd (mm)':<18} {'targets':>7} {'rms deg':>8} {'LOO deg':>8}"
                 "  outliers")
    for e in result["eyes"]:
        r = e["report"]
        c = "(" + ", ".join(f"{v:.1f}" for v in e["centre_mm"]) + ")"
        sd = "-" if r.get("centre_sd_mm") is None else "(" + ", ".join(f"{v:.1f}" for v in r["centre_sd_mm"]) + ")"
        loo = "-" if r["loo_rms_deg"] is None else f"{r['loo_rms_deg']:.3f}"
        lines.append(f"{e['eye']:<6} {c:<26} {sd:<18} {r['n_targets']:>7} {r['rms_deg']:>8.3f} {loo:>8}  "
                     f"{r['outliers'] or 'none'}")
        if r.get("model_loo_rms_deg"):
            lines.append("       leave-one-out RMS by model: " + ", ".join(
                f"{k} {v:.3f} deg" for k, v in r["model_loo_rms_deg"].items()))
    lines.append(f"centres: {result['eyes'][0]['report']['centre_method']}")
    return "\n".join(lines)


# --- viewlines ---------------------------------------------------------------------------------

def viewlines_files(eye_csv, eyes_json, poses_csv, out, max_gap_s: float = MAX_POSE_GAP_S, person=None) -> dict:
    """``view_lines`` from files: writes the view-line CSV and returns the counts. ``person``: a
    person.json whose per-eye correction is applied (docs/calibration.md, per-person bias). The
    view-lines step ``process`` runs (``session_steps.run_viewlines``)."""
    from ..process.session_steps import ViewlinesInputs, run_viewlines  # the steps' module imports this one
    from ..process.stepconf import ViewlinesConfig
    check_output(out, [eye_csv, eyes_json, poses_csv] + ([person] if person else []), "-o")
    correction = person_correction_deg(read_person(person)) if person else None
    eye, _ = read_eye_csv(eye_csv)
    cals = load_eyes(eyes_json)
    inputs = ViewlinesInputs(Poses(*read_poses_csv(poses_csv)), poses_csv, Path(out), eye, cals)
    return run_viewlines(ViewlinesConfig(max_gap_s, correction), inputs).counts


def view_lines(eye: EyeSamples, eyes: list, poses: Poses, max_gap_s: float = MAX_POSE_GAP_S, source="the poses",
               correction_deg=None) -> ViewLinesResult:
    """Raw eye samples -> world view lines (eq. 1-8) with the head poses interpolated to each
    sample; samples without a pose within ``max_gap_s`` are dropped and counted, invalid eyes
    stay empty (monocular samples are kept). ``eyes``: the (left, right) calibrations;
    ``source``: where the poses come from, for the message when none is near a sample;
    ``correction_deg``: a per-person correction (``head_lines_to_world``)."""
    return head_lines_to_world(head_view_lines(eye, eyes), poses, max_gap_s, source, correction_deg)


def head_view_lines(eye: EyeSamples, eyes: list) -> BinocularSamples:
    """Raw eye samples -> view lines in the head frame (eq. 1-6; invalid eyes NaN)."""
    arrays = []
    for e, cal in enumerate(eyes[:2]):
        lines = cal.lines(eye.raw[:, e])
        arrays += [lines.origins_mm, np.where(eye.valid[:, e][:, None], lines.directions, np.nan)]
    left_origin, left_direction, right_origin, right_direction = arrays
    return BinocularSamples.from_arrays(eye.t, left_origin, left_direction, right_origin,
                                        right_direction, frame="head")


def correct_head_lines(head: BinocularSamples, correction_deg) -> BinocularSamples:
    """Each eye's head-frame directions with a per-person correction ``correction_deg`` (2, 2)
    [eye (left, right), (horizontal, vertical)] degrees added to their Fick angles
    (``calibration.kappa.apply_kappa``; docs/calibration.md, per-person bias)."""
    c = np.asarray(correction_deg, float).reshape(2, 2)
    return BinocularSamples.from_arrays(head.t_s, head.left_origin_mm, apply_kappa(head.left_direction, c[0]),
                                        head.right_origin_mm, apply_kappa(head.right_direction, c[1]),
                                        head.left_valid, head.right_valid, frame=head.frame)


def head_lines_to_world(head: BinocularSamples, poses: Poses, max_gap_s: float = MAX_POSE_GAP_S, source="the poses",
                        correction_deg=None) -> ViewLinesResult:
    """View lines in the head frame (``frame="head"``: calibrated eye samples, or a device's
    eye rays) -> world view lines, with the head poses ``T_world_from_cam`` interpolated to each
    sample. Samples without a pose within ``max_gap_s`` are dropped and counted, as are those
    with neither eye valid; monocular samples are kept. ``correction_deg``: None, or a
    per-person correction (2, 2) applied in the head frame first (``correct_head_lines``).

    Raises:
        UserError: no valid sample has a pose (naming ``source``).
    """
    if correction_deg is not None:
        head = correct_head_lines(head, correction_deg)
    T_wc, ok = interpolate_poses(poses.t, poses.T_world_from_cam, head.t_s, max_gap_s)
    valid = head.left_valid | head.right_valid
    keep = ok & valid
    if not keep.any():
        raise UserError(f"{source}: no head pose within {max_gap_s} s of any valid eye sample; check that the eye "
                        "samples and the poses share one clock (or raise --max-gap)")
    idx = np.flatnonzero(keep)
    arrays = []
    for o, d in ((head.left_origin_mm, head.left_direction), (head.right_origin_mm, head.right_direction)):
        arrays += [transform_points(T_wc[idx], o[idx]), rotate_directions(T_wc[idx], d[idx])]   # eq. 7-8
    left_origin, left_direction, right_origin, right_direction = arrays
    samples = BinocularSamples.from_arrays(head.t_s[idx], left_origin, left_direction, right_origin,
                                           right_direction)
    return ViewLinesResult(samples, {"samples": int(len(head)), "written": int(len(idx)), "no_pose": int((~ok).sum()),
                                     "both_eyes_invalid": int((ok & ~valid).sum())})


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"NOMINAL_CENTRES_MM": "NOMINAL_CENTERS_MM"})
