"""``wearable-gaze track`` (head poses from a scene video) and ``wearable-gaze markers`` (printable
marker sheets)."""

from __future__ import annotations

import contextlib
import functools
import logging
from pathlib import Path

import cv2
import numpy as np

from calibration.camera import aruco_dictionary
from calibration.images import to_grey
from tracking.homography import PlanarTracker
from tracking.markers import MarkerDetector
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import interpolate_poses, smooth_poses

from ..errors import UserError, check_output
from ..formats.atomic import atomic_path
from ..formats.camera import load_camera
from ..formats.markermap import load_marker_map, marker_map_template, write_marker_map
from ..formats.poses import write_poses_csv
from ..formats.video import open_video, open_video_writer, read_frame_times

log = logging.getLogger(__name__)


def _frame_times(video: Path, timestamps):
    if timestamps is None:
        cand = video.parent / "scene_timestamps.csv"
        timestamps = cand if cand.is_file() else None
    if timestamps is None:
        return None
    frames, t = read_frame_times(timestamps)
    return dict(zip(frames, t, strict=True))


def track_video(video, camera_path, out, markers=None, reference=None, reference_size_mm=None, overlay=None,
                timestamps=None, progress=None, smooth_s: float = 0.0, every: int = 1) -> dict:
    """Head pose for every frame of a scene video, written as poses.csv (docs/formats.md).

    Either ``markers`` (a marker map JSON) or ``reference`` (an image of a flat surface) with
    ``reference_size_mm`` (width, height). Frame times come from ``timestamps`` (or the
    session's ``scene_timestamps.csv`` beside the video), else frame / fps. ``smooth_s`` > 0
    averages poses over a centred window of that length (no lag offline). ``every`` > 1 tracks
    one frame in ``every`` and fills the others by SLERP between tracked neighbours (status
    'interpolated'; smooth head motion moves a few hundredths of a degree off the line between
    two poses 1/15 s apart); with ``overlay`` every frame is tracked. Returns counts.

    ``out`` and ``overlay`` are written under temporary names and renamed once both are
    complete: an error or an interruption leaves neither half-written, and an earlier file
    under either name untouched.
    """
    video = Path(video)
    if (markers is None) == (reference is None):
        raise UserError("give either --markers MAP.json or --reference IMAGE --reference-size-mm W H")
    camera = load_camera(camera_path)
    with contextlib.ExitStack() as stack:
        cap, fps, n_total = open_video(video, camera.image_size)
        stack.callback(cap.release)
        times = _frame_times(video, timestamps)
        step = _pose_step(camera, markers, reference, reference_size_mm)
        draw = None
        if overlay is not None:
            tmp = stack.enter_context(atomic_path(overlay))         # left last: renamed after the poses
            writer = open_video_writer(tmp, "mp4v", fps, camera.image_size, refused=(
                f"--overlay: OpenCV cannot write an MPEG-4 video named {tmp.suffix!r}; use .mp4 or .avi"))
            stack.callback(writer.release)
            draw = functools.partial(_write_overlay_frame, writer, camera)
        rows, untimed = _track_frames(cap, step, times, fps, n_total, every, progress, draw)
        if untimed and not rows["frame"]:
            raise UserError(f"{video}: none of its {untimed} frames has a time in the frame-timestamp CSV; give "
                            "--timestamps with a row (frame,t) per frame")
        if not rows["frame"]:
            raise UserError(f"{video}: no frame could be decoded (corrupt or empty video); check that it plays, or "
                            "re-encode it")
        T_all, status = _fill_poses(rows, every, fps, smooth_s)
        write_poses_csv(out, rows["t"], rows["frame"], T_all,
                        {"n_markers": np.array(rows["n_markers"]), "n_points": np.array(rows["n_points"]),
                         "reproj_rms_px": np.array(rows["reproj_rms_px"]), "status": status})
    n_ok = sum(st in ("ok", "interpolated") for st in status)
    return {"frames": len(rows["frame"]), "posed": n_ok}


def _pose_step(camera, markers, reference, reference_size_mm):
    """grey (H, W) uint8 -> (pose result, detections drawn on the overlay)."""
    if markers is not None:
        mm = load_marker_map(markers)
        detector = MarkerDetector(mm.dictionary)
        estimator = MarkerPoseEstimator(mm, camera)

        def step(grey):
            found = detector.detect(grey)
            return estimator.estimate(found), found
        return step
    ref = cv2.imread(str(reference), cv2.IMREAD_GRAYSCALE)
    if ref is None:
        raise UserError(f"{reference}: missing or unreadable reference image; give a PNG or JPEG photo of the "
                        "surface")
    if reference_size_mm is None or min(reference_size_mm) <= 0:
        raise UserError("--reference-size-mm W H: the surface's physical width and height in mm")
    try:
        tracker = PlanarTracker(ref, reference_size_mm, camera)
    except ValueError as exc:
        raise UserError(f"{reference}: {exc}") from None

    def step(grey):
        return tracker.estimate(grey), []
    return step


POSE_ROW = ("t", "frame", "T", "n_markers", "n_points", "reproj_rms_px", "status")


def _track_frames(cap, step, times, fps: float, n_total: int, every: int, progress, draw) -> tuple[dict, int]:
    """Track the frames of ``cap``: one in ``every`` (all when ``draw``), the others get a NaN
    pose marked 'interpolated'. ``draw(frame, found, res)`` is called on every tracked frame.
    A frame ``times`` has no time for (a recording cut short saves its video ahead of its
    timestamps) cannot be placed in time: it is left out, with a warning. Returns the columns
    ``POSE_ROW``, one entry per frame kept, and the number of frames left out."""
    rows = {k: [] for k in POSE_ROW}
    i = untimed = 0
    while True:
        if times is not None and i not in times:
            if not cap.grab():
                break
            untimed += 1
            i += 1
            continue
        t = times[i] if times is not None else i / fps
        if every > 1 and i % every and draw is None:
            if not cap.grab():
                break
            values = (t, i, np.full((4, 4), np.nan), 0, 0, np.nan, "interpolated")
        else:
            ok, frame = cap.read()
            if not ok:
                break
            res, found = step(to_grey(frame))
            values = (t, i, res.T_world_from_cam if res.ok else np.full((4, 4), np.nan), len(res.markers),
                      res.n_points, res.reproj_rms_px, res.status if res.ok else f"{res.status}: {res.reason}")
            if draw is not None:
                draw(frame, found, res)
            if progress:
                progress(i + 1, max(n_total, i + 1))
        for k, v in zip(POSE_ROW, values, strict=True):
            rows[k].append(v)
        i += 1
    if untimed and rows["frame"]:
        log.warning("%d of %d video frames have no time in the frame-timestamp CSV; they get no pose", untimed, i)
    return rows, untimed


def _fill_poses(rows: dict, every: int, fps: float, smooth_s: float):
    """(T_world_from_cam (N, 4, 4), status (N,)): the frames passed over SLERPed between tracked
    neighbours at most ``every`` + 0.5 frames apart, then smoothed over ``smooth_s`` if > 0."""
    T_all = np.array(rows["T"])
    status = list(rows["status"])
    t_all = np.array(rows["t"])
    if every > 1:
        fill = np.array([st == "interpolated" for st in status])
        T_i, ok_i = interpolate_poses(t_all[~fill], T_all[~fill], t_all[fill], max_gap_s=(every + 0.5) / fps)
        T_all[fill] = T_i
        for k, good in zip(np.flatnonzero(fill), ok_i, strict=True):
            if not good:
                status[k] = "no_pose: no tracked frame on both sides"
    if smooth_s > 0:
        T_all = smooth_poses(t_all, T_all, smooth_s)
    return T_all, status


def _write_overlay_frame(writer, camera, frame, found, res) -> None:
    writer.write(_draw_overlay(frame, found, res, camera))


AXIS_MM = 300.0          # length of the world axes drawn on the overlay
AXIS_SAMPLES = 16        # points per axis: an axis leaving the view is cut where it leaves
MIN_DEPTH_MM = 50.0
MAX_PX = 1e5             # beyond this a drawing coordinate is an error, not a point off screen


def _draw_overlay(frame, found, res, camera) -> np.ndarray:
    """A copy of ``frame`` (BGR) with the detections ``found`` ((id, corners (4, 2) px) each),
    the world axes when ``res`` has a pose, and the pose status."""
    img = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    for mid, c in found:                 # every detection, repeated ids included
        cv2.polylines(img, [np.round(c * 16).astype(np.int32)], True, (0, 255, 0), 2, cv2.LINE_AA, shift=4)
        cv2.putText(img, str(mid), tuple(int(v) for v in c[0]), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 255, 0), 2)
    if res.ok:
        _draw_world_axes(img, np.linalg.inv(res.T_world_from_cam), camera)
    txt = "pose ok" if res.ok else f"no pose: {res.reason}"
    cv2.putText(img, txt, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 255, 255), 2)
    return img


def _draw_world_axes(img, T_cam_from_world, camera) -> None:
    """Draw the world's x (red), y (green) and z (blue) axes, ``AXIS_MM`` long, on ``img``.

    Each axis is a polyline through points sampled along it; only the pieces in front of the
    camera and inside the calibrated field of view are drawn. Outside that field the distortion
    polynomial sends points to huge or non-finite pixels (or folds them back into the image),
    which OpenCV cannot draw ("Can't parse 'pt2'") and which would be wrong if it could.
    """
    r_max = _field_radius(camera)
    s = np.linspace(0.0, AXIS_MM, AXIS_SAMPLES)
    for k, col in ((0, (0, 0, 255)), (1, (0, 255, 0)), (2, (255, 0, 0))):
        pts_world = np.zeros((AXIS_SAMPLES, 3))
        pts_world[:, k] = s
        pc = pts_world @ T_cam_from_world[:3, :3].T + T_cam_from_world[:3, 3]
        vis = pc[:, 2] > MIN_DEPTH_MM
        vis[vis] = np.linalg.norm(pc[vis, :2], axis=1) / pc[vis, 2] <= r_max
        px = np.full((AXIS_SAMPLES, 2), np.nan)
        if vis.any():
            px[vis] = camera.project(pc[vis])
        vis &= np.all(np.isfinite(px), axis=1) & np.all(np.abs(np.nan_to_num(px)) < MAX_PX, axis=1)
        for run in _runs(vis):
            if len(run) > 1:
                cv2.polylines(img, [np.round(px[run] * 16).astype(np.int32)], False, col, 3, cv2.LINE_AA, shift=4)


def _field_radius(camera) -> float:
    """The largest normalised radius (x/z, y/z) the image shows: that of its corners and edge
    midpoints, undistorted."""
    w, h = camera.image_size
    border = np.array([[0, 0], [w / 2, 0], [w, 0], [w, h / 2], [w, h], [w / 2, h], [0, h], [0, h / 2]], float)
    xy = camera.undistort_points(border)
    return float(np.max(np.linalg.norm(xy, axis=1)))


def _runs(mask) -> list:
    """Index arrays of the runs of consecutive True values in a (N,) bool mask."""
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return []
    return np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)


# --- printable markers -------------------------------------------------------------------------

MAX_IDS = 10000


def parse_ids(text: str) -> list[int]:
    """'0-11', '3,5,7-9' -> ids (each once, in the order given).

    Raises:
        UserError: not ids, a range written backwards (5-3), a negative id, or more than
            ``MAX_IDS`` ids.
    """
    ids = []
    safe = ascii(text)
    for part in text.split(","):
        try:
            if "-" in part.strip()[1:]:
                a, b = (int(v) for v in part.split("-"))
                if b < a:
                    raise UserError(f"--ids {safe}: the range {a}-{b} runs backwards; write {b}-{a}")
                if b - a >= MAX_IDS:
                    raise UserError(f"--ids {safe}: more than {MAX_IDS} ids; print fewer at a time")
                ids += list(range(a, b + 1))
            else:
                ids.append(int(part))
        except ValueError:
            raise UserError(f"--ids {safe}: give ids like 0-11 or 3,5,7-9") from None
    neg = [i for i in ids if i < 0]
    if neg:
        raise UserError(f"--ids {safe}: id {neg[0]} is negative; give ids of 0 or more")
    if not ids:
        raise UserError(f"--ids {safe}: no ids; give ids like 0-11 or 3,5,7-9")
    if len(ids) > MAX_IDS:
        raise UserError(f"--ids {safe}: more than {MAX_IDS} ids; print fewer at a time")
    return list(dict.fromkeys(ids))


PAGE_MM = {"a4": (210.0, 297.0), "letter": (215.9, 279.4), "a3": (297.0, 420.0)}
MAX_DPI = 1200          # an A3 page at 1200 dpi is 14000 x 19800 pixels; more exhausts memory


def write_marker_sheets(dictionary: str, ids, size_mm: float, out, page: str = "a4", dpi: int = 300,
                        margin_mm: float = 12.0) -> list:
    """Exact-scale marker sheets: each marker with a white quiet zone of one module, a dashed
    cut line, its id, dictionary and size printed under it. PDF (vector page, raster markers at
    ``dpi``) or PNG at ``dpi``. Also writes ``<out>_map_template.json`` to fill in."""
    try:
        dic = aruco_dictionary(dictionary)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    n_ids = dic.bytesList.shape[0]
    bad = [i for i in ids if not 0 <= i < n_ids]
    if bad:
        raise UserError(f"--ids: ids {bad[:5]} are not in {dictionary}; use ids 0-{n_ids - 1} or a larger --dict")
    if not 5 <= size_mm <= 1000:
        raise UserError(f"--size-mm {size_mm:g}: give the marker side in millimetres, 5-1000")
    if not 50 <= dpi <= MAX_DPI:
        raise UserError(f"--dpi {dpi}: give a resolution of 50-{MAX_DPI} dots per inch (default 300)")
    if not ids:
        raise UserError("--ids: no ids to print; give ids like 0-11 or 3,5,7-9")
    out = Path(out)
    if out.suffix.lower() not in (".pdf", ".png"):
        raise UserError(f"-o {out}: write .pdf or .png")
    check_output(out, (), "-o")
    check_output(out.with_name(out.stem + "_map_template.json"), (), "-o (its map template)")
    pw, ph = PAGE_MM[page]
    module = size_mm / (dic.markerSize + 2)
    cell = size_mm + 2 * module + 12.0                      # quiet zone both sides + label room
    cols = max(int((pw - 2 * margin_mm) // cell), 1)
    rows = max(int((ph - 2 * margin_mm) // cell), 1)
    if size_mm + 2 * module > min(pw, ph) - 2 * margin_mm:
        raise UserError(f"a {size_mm:g} mm marker does not fit on a {page} page with margins; use --page a3")
    per_page = cols * rows
    pages = [ids[k:k + per_page] for k in range(0, len(ids), per_page)]

    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.backends.backend_pdf import PdfPages  # noqa: PLC0415

    written = []

    def draw(page_ids):
        fig = plt.figure(figsize=(pw / 25.4, ph / 25.4), dpi=dpi)
        ax = fig.add_axes([0, 0, 1, 1])
        ax.set_xlim(0, pw)
        ax.set_ylim(ph, 0)
        ax.axis("off")
        px = max(int(round(size_mm / 25.4 * dpi)), 8 * (dic.markerSize + 2))
        for k, mid in enumerate(page_ids):
            r, c = divmod(k, cols)
            x0 = margin_mm + c * cell + module
            y0 = margin_mm + r * cell + module
            img = cv2.aruco.generateImageMarker(dic, int(mid), px, borderBits=1)
            ax.imshow(img, cmap="gray", vmin=0, vmax=255, extent=(x0, x0 + size_mm, y0 + size_mm, y0),
                      interpolation="nearest")
            ax.add_patch(plt.Rectangle((x0 - module, y0 - module), size_mm + 2 * module, size_mm + 2 * module,
                                       fill=False, ls=(0, (4, 4)), lw=0.4, ec="0.5"))
            ax.text(x0, y0 + size_mm + module + 3.5, f"id {mid}  {dictionary}  {size_mm:g} mm (black square)",
                    fontsize=6, va="top")
        ax.text(margin_mm, ph - 5, f"wearable-gaze markers: print at 100 % (no scaling); check the {size_mm:g} mm side "
                "with a ruler", fontsize=6)
        return fig

    if out.suffix.lower() == ".pdf":
        with atomic_path(out) as tmp, PdfPages(tmp) as pdf:
            for p in pages:
                fig = draw(p)
                pdf.savefig(fig)
                plt.close(fig)
        written.append(out)
    else:
        for n, p in enumerate(pages):
            path = out if len(pages) == 1 else out.with_name(f"{out.stem}_{n + 1}{out.suffix}")
            fig = draw(p)
            with atomic_path(path) as tmp:
                fig.savefig(tmp, dpi=dpi)
            plt.close(fig)
            written.append(path)
    template = out.with_name(out.stem + "_map_template.json")
    write_marker_map(template, marker_map_template(dictionary, size_mm, ids))
    written.append(template)
    return written
