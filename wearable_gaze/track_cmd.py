"""``wearable-gaze track`` (head poses from a scene video) and ``wearable-gaze markers`` (printable
marker sheets)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calibration.camera import aruco_dictionary
from tracking.homography import PlanarTracker
from tracking.markermap import MarkerMap, MarkerMapError
from tracking.markers import MarkerDetector
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import interpolate_poses, smooth_poses

from .atomic import atomic_path
from .calibrate_cmd import load_camera
from .errors import UserError, check_output
from .jsonio import load_json
from .session import write_json, write_poses_csv
from .tables import read_table


def load_marker_map(path) -> MarkerMap:
    """A marker map JSON, checked against its schema, then loaded (rigid poses, square corners)."""
    try:
        return MarkerMap.from_dict(load_json(path, "marker-map"))
    except MarkerMapError as exc:
        raise UserError(f"{path}: {exc} (docs/formats.md, marker map)") from None


def _frame_times(video: Path, timestamps, n_hint: int, fps: float):
    if timestamps is None:
        cand = video.parent / "scene_timestamps.csv"
        timestamps = cand if cand.is_file() else None
    if timestamps is None:
        return None
    tab = read_table(timestamps, ["frame", "t"], what="frame-timestamp CSV")
    return dict(zip(tab["frame"].astype(int), tab["t"], strict=True))


def track_video(video, camera_path, out, markers=None, reference=None, reference_size_mm=None, overlay=None,
                timestamps=None, progress=None, smooth_s: float = 0.0, every: int = 1) -> dict:
    """Head pose for every frame of a scene video, written as poses.csv (docs/formats.md).

    Either ``markers`` (a marker map JSON) or ``reference`` (an image of a flat surface) with
    ``reference_size_mm`` (width, height). Frame times come from ``timestamps`` (or the
    session's ``scene_timestamps.csv`` beside the video), else frame / fps. ``smooth_s`` > 0
    averages poses over a centred window of that length (no lag offline). ``every`` > 1 tracks
    one frame in ``every`` and fills the others by SLERP between tracked neighbours (status
    'interpolated'; smooth head motion moves a few hundredths of a degree off the line between
    two poses 1/15 s apart). Returns counts.
    """
    video = Path(video)
    if (markers is None) == (reference is None):
        raise UserError("give either --markers MAP.json or --reference IMAGE --reference-size-mm W H")
    camera = load_camera(camera_path)
    if not video.is_file():
        raise UserError(f"{video}: no such video")
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise UserError(f"{video}: OpenCV cannot open this video (corrupt, or a codec FFMPEG lacks)")
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    if (w, h) != tuple(camera.image_size):
        raise UserError(f"{video} is {w}x{h} but the camera calibration is for {camera.image_size[0]}x"
                        f"{camera.image_size[1]}: calibrate this camera at this resolution")
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    n_total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or 0
    times = _frame_times(video, timestamps, n_total, fps)
    if markers is not None:
        mm = load_marker_map(markers)
        detector = MarkerDetector(mm.dictionary)
        estimator = MarkerPoseEstimator(mm, camera)

        def step(grey):
            found = detector.detect(grey)
            return estimator.estimate(found), found
    else:
        ref = cv2.imread(str(reference), cv2.IMREAD_GRAYSCALE)
        if ref is None:
            raise UserError(f"{reference}: missing or unreadable reference image")
        if reference_size_mm is None or min(reference_size_mm) <= 0:
            raise UserError("--reference-size-mm W H: the surface's physical width and height in mm")
        try:
            tracker = PlanarTracker(ref, reference_size_mm, camera)
        except ValueError as exc:
            raise UserError(f"{reference}: {exc}") from None

        def step(grey):
            return tracker.estimate(grey), {}
    writer = None
    if overlay is not None:
        ov_tmp = atomic_path(overlay)
        ov_path = ov_tmp.__enter__()
        writer = cv2.VideoWriter(str(ov_path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    rows = {"t": [], "frame": [], "T": [], "n_markers": [], "n_points": [], "reproj_rms_px": [], "status": []}
    i = 0
    try:
        while True:
            if every > 1 and i % every and writer is None:
                if not cap.grab():
                    break
                rows["t"].append(times.get(i, np.nan) if times is not None else i / fps)
                rows["frame"].append(i)
                rows["T"].append(np.full((4, 4), np.nan))
                rows["n_markers"].append(0)
                rows["n_points"].append(0)
                rows["reproj_rms_px"].append(np.nan)
                rows["status"].append("interpolated")
                i += 1
                continue
            ok, frame = cap.read()
            if not ok:
                break
            grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
            res, found = step(grey)
            rows["t"].append(times.get(i, np.nan) if times is not None else i / fps)
            rows["frame"].append(i)
            rows["T"].append(res.T_world_from_cam if res.ok else np.full((4, 4), np.nan))
            rows["n_markers"].append(len(res.markers))
            rows["n_points"].append(res.n_points)
            rows["reproj_rms_px"].append(res.reproj_rms_px)
            rows["status"].append(res.status if res.ok else f"{res.status}: {res.reason}")
            if writer is not None:
                writer.write(_draw_overlay(frame, found, res, camera))
            i += 1
            if progress:
                progress(i, max(n_total, i))
    finally:
        cap.release()
        if writer is not None:
            writer.release()
            ov_tmp.__exit__(None, None, None)
    if i == 0:
        raise UserError(f"{video}: no frame could be decoded (corrupt or empty video)")
    T_all = np.array(rows["T"])
    status = rows["status"]
    if every > 1:
        t_all = np.array(rows["t"])
        fill = np.array([st == "interpolated" for st in status])
        T_i, ok_i = interpolate_poses(t_all[~fill], T_all[~fill], t_all[fill], max_gap_s=(every + 0.5) / fps)
        T_all[fill] = T_i
        for k, good in zip(np.flatnonzero(fill), ok_i, strict=True):
            if not good:
                status[k] = "no_pose: no tracked frame on both sides"
    if smooth_s > 0:
        T_all = smooth_poses(np.array(rows["t"]), T_all, smooth_s)
    write_poses_csv(out, rows["t"], rows["frame"], T_all,
                    {"n_markers": np.array(rows["n_markers"]), "n_points": np.array(rows["n_points"]),
                     "reproj_rms_px": np.array(rows["reproj_rms_px"]),
                     "status": rows["status"]})
    n_ok = sum(st in ("ok", "interpolated") for st in status)
    return {"frames": i, "posed": n_ok}


def _draw_overlay(frame, found, res, camera) -> np.ndarray:
    img = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    for mid, c in found:                 # every detection, repeated ids included
        cv2.polylines(img, [np.round(c * 16).astype(np.int32)], True, (0, 255, 0), 2, cv2.LINE_AA, shift=4)
        cv2.putText(img, str(mid), tuple(int(v) for v in c[0]), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 255, 0), 2)
    if res.ok:
        T_cw = np.linalg.inv(res.T_world_from_cam)
        axes = np.array([[0, 0, 0], [300, 0, 0], [0, 300, 0], [0, 0, 300.0]])
        pc = axes @ T_cw[:3, :3].T + T_cw[:3, 3]
        if np.all(pc[:, 2] > 50):
            px = camera.project(pc)
            for k, col in ((1, (0, 0, 255)), (2, (0, 255, 0)), (3, (255, 0, 0))):
                cv2.line(img, tuple(int(v) for v in px[0]), tuple(int(v) for v in px[k]), col, 3, cv2.LINE_AA)
    txt = "pose ok" if res.ok else f"no pose: {res.reason}"
    cv2.putText(img, txt, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 255, 255), 2)
    return img


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
            raise UserError(f"--ids {safe}: expected ids like 0-11 or 3,5,7-9") from None
    neg = [i for i in ids if i < 0]
    if neg:
        raise UserError(f"--ids {safe}: id {neg[0]} is negative; marker ids start at 0")
    if not ids:
        raise UserError(f"--ids {safe}: no ids; expected ids like 0-11 or 3,5,7-9")
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
        raise UserError(f"ids {bad[:5]} are not in {dictionary} (0-{n_ids - 1})")
    if not 5 <= size_mm <= 1000:
        raise UserError(f"--size-mm {size_mm}: marker side in millimetres, 5-1000")
    if not 50 <= dpi <= MAX_DPI:
        raise UserError(f"--dpi {dpi}: give a resolution of 50-{MAX_DPI} dots per inch (default 300)")
    if not ids:
        raise UserError("--ids: no ids to print; expected ids like 0-11 or 3,5,7-9")
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
    write_json(template, {"format": "wearable-gaze-marker-map", "version": 1, "dictionary": dictionary,
                          "marker_size_mm": size_mm,
                          "_help": "Measure each marker's four corners (top-left, top-right, bottom-right, "
                                   "bottom-left of the printed square) in the room's frame, in mm, or give "
                                   "T_world_from_marker; see docs/formats.md.",
                          "markers": [{"id": int(i), "label": "", "corners_mm": [[0, 0, 0]] * 4} for i in ids]})
    written.append(template)
    return written
