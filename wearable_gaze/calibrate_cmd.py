"""``calibrate-camera``, ``calibrate-eyes`` and ``viewlines``: files in, the ``calibration``
library in the middle, files out."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calibration.camera import (
    CameraCalibration,
    calibrate_camera,
    detect_board,
    parse_board,
    select_frames,
    undistort_image,
)
from calibration.eyes import (
    CalibrationError,
    EyeCalibration,
    calibrate_eye,
    compare_models,
    estimate_centre,
    target_readings,
    wall_pose,
)
from estimator import BinocularSamples, view_lines_to_world
from estimator.frames import invert
from tracking.markers import MarkerDetector
from tracking.timeline import interpolate_poses

from .atomic import atomic_path
from .errors import UserError
from .session import read_eye_csv, read_json, read_poses_csv, write_json
from .viewlines_csv import write_viewlines_csv

IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
NOMINAL_CENTRES_MM = np.array([[-32.0, 30.0, -20.0], [32.0, 30.0, -20.0]])
EYES_FORMAT = "wearable-gaze-eyes"


# --- camera files ------------------------------------------------------------------------------

def load_camera(path) -> CameraCalibration:
    """A camera file: our JSON, or an OpenCV FileStorage YAML/XML (``camera_matrix`` and
    ``distortion_coefficients`` / ``dist_coeffs``, ``image_width`` / ``image_height``)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such camera file; run 'wearable-gaze calibrate-camera' to make one")
    if path.suffix.lower() == ".json":
        d = read_json(path, "camera JSON")
        try:
            return CameraCalibration.from_dict(d)
        except (ValueError, TypeError) as exc:
            raise UserError(f"{path}: {exc} (see docs/formats.md, camera JSON)") from None
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise UserError(f"{path}: not a camera JSON or an OpenCV YAML/XML file")
    try:
        K = _fs_mat(fs, ("camera_matrix", "cameraMatrix", "K", "M1"))
        D = _fs_mat(fs, ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "D1"))
        w, h = (fs.getNode(k).real() for k in ("image_width", "image_height"))
        model = "fisheye" if fs.getNode("model").isString() and fs.getNode("model").string() == "fisheye" else "pinhole"
    finally:
        fs.release()
    if K is None:
        raise UserError(f"{path}: no camera_matrix in this OpenCV file")
    if not (w and h):
        w, h = 2 * K[0, 2] + 1, 2 * K[1, 2] + 1          # best guess; said in the JSON we write
    try:
        return CameraCalibration.from_dict({"camera_matrix": K.tolist(),
                                            "dist_coeffs": [] if D is None else D.ravel().tolist(),
                                            "image_size": [int(round(w)), int(round(h))], "model": model})
    except ValueError as exc:
        raise UserError(f"{path}: {exc}") from None


def _fs_mat(fs, names):
    for n in names:
        node = fs.getNode(n)
        if not node.empty():
            m = node.mat()
            if m is not None:
                return np.asarray(m, float)
    return None


# --- calibrate-camera --------------------------------------------------------------------------

def _frames(inputs, max_video_frames: int, progress=None):
    """(name, grey image) for image files, and every k-th frame of video files."""
    files = []
    for p in inputs:
        p = Path(p)
        if p.is_dir():
            files += sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_EXT)
        elif p.is_file():
            files.append(p)
        else:
            raise UserError(f"{p}: no such file or folder; pass images, a folder of images or a video")
    if not files:
        raise UserError("no images found in the inputs")
    for f in files:
        if f.suffix.lower() in IMAGE_EXT:
            img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise UserError(f"{f}: not a readable image")
            yield f.name, img
            continue
        cap = cv2.VideoCapture(str(f))
        if not cap.isOpened():
            raise UserError(f"{f}: neither an image nor a video OpenCV can open")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or 1
        step = max(n // max_video_frames, 1)
        i = 0
        while True:
            ok = cap.grab()
            if not ok:
                break
            if i % step == 0:
                ok, frame = cap.retrieve()
                if ok:
                    yield f"{f.name}#{i}", cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
            i += 1
        cap.release()


def calibrate_camera_files(inputs, board: str, out, model: str = "pinhole", max_views: int = 40,
                           progress=None) -> tuple[CameraCalibration, list]:
    """Detect the board in images or videos, pick views for coverage, calibrate, write the
    camera JSON and an undistortion preview PNG beside it. Returns the calibration and the
    written paths."""
    try:
        spec = parse_board(board)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    views, size, first = [], None, None
    for k, (name, img) in enumerate(_frames(inputs, 4 * max_views)):
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
    out = Path(out)
    write_json(out, cal.to_dict())
    preview = out.with_name(out.stem + "_undistorted.png")
    und, _ = undistort_image(first, cal, alpha=0.0)
    side = np.hstack([cv2.cvtColor(first, cv2.COLOR_GRAY2BGR), cv2.cvtColor(und, cv2.COLOR_GRAY2BGR)])
    cv2.putText(side, "original", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 1, (0, 0, 255), 2)
    cv2.putText(side, "undistorted", (size[0] + 10, 30), cv2.FONT_HERSHEY_SIMPLEX, 1, (0, 0, 255), 2)
    with atomic_path(preview) as tmp:
        cv2.imwrite(str(tmp), side)
    return cal, [out, preview]


def format_camera_report(cal: CameraCalibration) -> str:
    K = cal.camera_matrix
    lines = [f"camera ({cal.model}, {cal.image_size[0]}x{cal.image_size[1]}): RMS {cal.rms_px:.3f} px, "
             f"fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f}",
             "dist " + " ".join(f"{v:.5g}" for v in cal.dist_coeffs)]
    if cal.std:
        lines.append("standard deviations: " + " ".join(f"{k} {cal.std[k]:.2f}" for k in ("fx", "fy", "cx", "cy")) + " px")
    lines += ["",
              f"{'view':<28} {'points':>6} {'rms px':>8}  status"]
    for v in cal.views:
        rms = "" if v["rms_px"] is None else f"{v['rms_px']:.3f}"
        lines.append(f"{v['view'][:28]:<28} {v['n_points']:>6} {rms:>8}  {'used' if v['used'] else v['reason']}")
    return "\n".join(lines)


# --- calibrate-eyes ----------------------------------------------------------------------------

def _eye_folder(src) -> tuple[Path, Path]:
    src = Path(src)
    if src.is_file() and src.suffix.lower() == ".csv":
        return src.parent, src
    for cand in (src / "calibration" / "eye", src):
        if (cand / "eye_calibration.csv").is_file():
            return cand, cand / "eye_calibration.csv"
    raise UserError(f"{src}: no eye_calibration.csv here or in calibration/eye/; pass a session folder, its "
                    "calibration/eye folder or the CSV (docs/session.md)")


def calibrate_eyes_files(src, camera_path, out, model: str = "quadratic", centres=None, progress=None) -> dict:
    """The eye calibration of a session's recordings (docs/session.md): wall poses from their
    reference markers, per-target readings, eye centres from two or more wall distances (or
    ``centres``, or a nominal headset geometry), and eq. 1-2 per eye. Writes eyes.json and
    returns its content."""
    folder, csv_path = _eye_folder(src)
    camera = load_camera(camera_path)
    walls = read_json(folder / "walls.json", "wall description (walls.json)")
    recs = walls.get("recordings")
    if not isinstance(recs, list) or not recs:
        raise UserError(f"{folder / 'walls.json'}: no 'recordings' list (docs/session.md)")
    eye, extra = read_eye_csv(csv_path, ["recording", "target"])
    targets_cam, readings, wall_report = [], [[], []], []
    for r, rec in enumerate(recs):
        try:
            P, wp = _wall_targets(folder, rec, camera)
        except KeyError as exc:
            raise UserError(f"{folder / 'walls.json'} recording {r}: missing {exc}") from None
        sel = extra["recording"].astype(int) == int(rec.get("recording", r))
        if not sel.any():
            raise UserError(f"{csv_path}: no samples of recording {rec.get('recording', r)}; record it again")
        ids = None
        for e in range(2):
            ids, vals, _ = target_readings(extra["target"][sel], eye.raw[sel, e], eye.valid[sel, e], eye.t[sel])
            readings[e].append(vals)
        if ids.max() >= len(P):
            raise UserError(f"{csv_path}: target {ids.max()} in recording {r}, but walls.json lists {len(P)} dots")
        targets_cam.append(P[ids])
        wall_report.append({"recording": r, "image": rec.get("image"), "nominal_distance_mm": rec.get("distance_mm"),
                            "measured_distance_mm": float(wp.T_cam_from_wall[2, 3]), "tilt_deg": wp.tilt_deg,
                            "reference_rms_px": wp.rms * camera.camera_matrix[0, 0]})
        if progress:
            progress(r + 1, len(recs) + 2)
    P = np.vstack(targets_cam)
    depths = np.array([w["measured_distance_mm"] for w in wall_report])
    result = {"format": EYES_FORMAT, "version": 1, "camera": camera.to_dict(), "walls": wall_report, "eyes": []}
    eyes_out = []
    for e, name in enumerate(("left", "right")):
        raw = np.vstack(readings[e])
        if not np.isfinite(raw).any():
            raise UserError(f"no valid {name}-eye samples in {csv_path}: check the {name} eye's sensor and record "
                            "the calibration again")
        if centres is not None:
            c, cov, how = np.asarray(centres[e], float), None, "given"
        elif np.ptp(depths) > 0.2 * np.median(depths):
            ok = np.all(np.isfinite(raw), axis=1)
            c, cov = estimate_centre(raw[ok], P[ok], NOMINAL_CENTRES_MM[e])
            how = "two-distance"
        else:
            c, cov, how = NOMINAL_CENTRES_MM[e], None, "nominal (one wall distance: record a second to estimate it)"
        try:
            cal = calibrate_eye(name, raw, P, c, plane_mm=float(depths[0]), model=model,
                                focal_px=float(camera.camera_matrix[0, 0]))
        except CalibrationError as exc:
            raise UserError(str(exc)) from None
        cal.report["centre_method"] = how
        cal.report["centre_sd_mm"] = None if cov is None else np.sqrt(np.diag(cov)).tolist()
        if len(raw) > 9:
            cal.report["model_loo_rms_deg"] = compare_models(name, raw, P, c, float(depths[0]))
        eyes_out.append(cal.to_dict())
    result["eyes"] = eyes_out
    write_json(out, result)
    if progress:
        progress(len(recs) + 2, len(recs) + 2)
    return result


def _wall_targets(folder: Path, rec: dict, camera: CameraCalibration):
    """Targets (K, 3) in the camera frame from the wall image's reference markers."""
    img_path = folder / rec["image"]
    img = cv2.imread(str(img_path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise UserError(f"{img_path}: missing or unreadable wall image")
    try:
        det = MarkerDetector(rec["dictionary"])
    except ValueError as exc:
        raise UserError(f"{folder / 'walls.json'}: {exc}") from None
    found = det.detect_unique(img)       # {id: corners}; a repeated id is ambiguous and left out
    s = float(rec["marker_size_mm"]) / 2
    wall_pts, img_pts = [], []
    for mid, c in rec["markers_wall_mm"].items():
        if int(mid) in found:
            wall_pts.append(np.asarray(c, float) + np.array([[-s, -s], [s, -s], [s, s], [-s, s]]))
            img_pts.append(found[int(mid)])
    if len(wall_pts) < 2:
        raise UserError(f"{img_path}: {len(wall_pts)} of the wall's {len(rec['markers_wall_mm'])} reference markers "
                        "found, need 2: make them visible and record again")
    try:
        wp = wall_pose(np.vstack(wall_pts), camera.undistort_points(np.vstack(img_pts)))
    except CalibrationError as exc:
        raise UserError(f"{img_path}: {exc}") from None
    return wp.to_camera(np.asarray(rec["targets_wall_mm"], float)), wp


def load_eyes(path) -> list[EyeCalibration]:
    d = read_json(path, "eye calibration (eyes.json)")
    if d.get("format") != EYES_FORMAT:
        raise UserError(f"{path}: not an eye calibration ('format' is {d.get('format')!r}); run "
                        "'wearable-gaze calibrate-eyes'")
    try:
        return [EyeCalibration.from_dict(e) for e in d["eyes"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{path}: malformed eye calibration ({exc})") from None


def format_eyes_report(result: dict) -> str:
    lines = ["wall recordings:"]
    for w in result["walls"]:
        lines.append(f"  {w['image']}: measured distance {w['measured_distance_mm']:.0f} mm, tilt {w['tilt_deg']:.1f} deg, "
                     f"reference points {w['reference_rms_px']:.2f} px RMS")
    lines.append("")
    lines.append(f"{'eye':<6} {'centre (mm)':<26} {'sd (mm)':<18} {'targets':>7} {'rms deg':>8} {'LOO deg':>8}  outliers")
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

def viewlines_files(eye_csv, eyes_json, poses_csv, out, max_gap_s: float = 0.1) -> dict:
    """Raw eye samples -> world view lines (eq. 1-8) with the head poses interpolated to each
    sample; samples without a pose within ``max_gap_s`` are dropped and counted, invalid eyes
    stay empty (monocular samples are kept)."""
    eye, _ = read_eye_csv(eye_csv)
    cals = load_eyes(eyes_json)
    t_p, _, T_p, _ = read_poses_csv(poses_csv)
    T_wc, ok = interpolate_poses(t_p, T_p, eye.t, max_gap_s)
    keep = ok & eye.valid.any(axis=1)
    if not keep.any():
        raise UserError(f"{poses_csv}: no head pose within {max_gap_s} s of any valid eye sample; are the eye "
                        "samples and the poses on the same clock?")
    idx = np.flatnonzero(keep)
    T_cw = np.stack([invert(T) for T in T_wc[idx]])
    arrays = []
    for e, cal in enumerate(cals[:2]):
        lw = view_lines_to_world(cal.lines(eye.raw[idx, e]), T_cw)
        d = np.where(eye.valid[idx, e][:, None], lw.directions, np.nan)     # blinks stay marked: empty
        arrays += [lw.origins_mm, d]
    samples = BinocularSamples.from_arrays(eye.t[idx], *arrays)
    write_viewlines_csv(out, samples)
    return {"samples": int(len(eye)), "written": int(len(idx)), "no_pose": int((~ok).sum()),
            "both_eyes_invalid": int((ok & ~eye.valid.any(axis=1)).sum())}


def study_table(trials: int, seed: int, progress=None):
    from .calstudy import run_calibration_study  # noqa: PLC0415

    return run_calibration_study(trials=trials, seed=seed, progress=progress)


