"""The report's overlay (docs/processing.md, "The report"): the scene video with, on each
frame, the markers detected in it, each eye's gaze point (eq. 1-2) and the target being looked at
(its estimate projected at the frame's head pose, with its distance).

Two outputs, both H.264 in MP4 (``formats.video.BrowserVideoWriter``, PyAV: OpenCV 5's writer has
no codec browsers play): ``overlay.mp4``, the whole session at ``PREVIEW_FPS`` and
``PREVIEW_WIDTH`` px, which the report's video element plays, and, on request (``process
--overlay-video``), ``overlay_full.mp4``, every frame at full resolution.

What is drawn is what was seen: markers only where the detector found them in that frame (never
projected from the map, which puts markers far outside the view on lines across the frame);
points only inside the calibrated field of view (outside it the distortion polynomial folds them
back into the image); labels moved inside the frame. The colours are named once, in RGB
(``EYE_COLORS`` ...), handed to OpenCV as BGR by ``bgr`` and named in the caption (``caption``).
"""

from __future__ import annotations

import contextlib
import html
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from calibration.camera import CameraCalibration
from calibration.images import to_gray
from estimator.deprecation import module_getattr
from tracking.markermap import MarkerMap
from tracking.markers import MarkerDetector

from ...formats.atomic import atomic_path
from ...formats.eye_samples import EyeSamples
from ...formats.video import BrowserVideoWriter, open_video

PREVIEW_NAME = "overlay.mp4"
VIDEO_NAME = "overlay_full.mp4"
PREVIEW_FPS = 10.0
PREVIEW_WIDTH = 640          # px; the report shows it at this size
MIN_DEPTH_MM = 100.0         # a point nearer the camera than this is not drawn
EYE_TIME_S = 0.05            # the eye sample drawn on a frame is at most this far from its time
TARGET_TIME_S = 0.15         # the target of the view line nearest the frame, if this near

# (what, colour name in the caption, RGB): one table for the drawing and the words
EYE_COLORS = (("left eye", "orange", (255, 140, 0)), ("right eye", "magenta", (255, 0, 255)))
MAP_MARKER = ("marker of the map", "green", (0, 200, 0))
OTHER_MARKER = ("marker not in the map", "yellow", (255, 220, 0))
TARGET = ("target", "red", (230, 0, 0))
TEXT = ("text", "white", (255, 255, 255))
FONT = cv2.FONT_HERSHEY_SIMPLEX


def bgr(rgb) -> tuple[int, int, int]:
    """An RGB colour (3,) as the BGR tuple OpenCV's drawing functions take."""
    r, g, b = rgb
    return int(b), int(g), int(r)


def caption() -> str:
    """The sentence under the overlay, naming each colour as ``EYE_COLORS`` ... draw it (HTML)."""
    (l_what, l_name, _), (r_what, r_name, _) = EYE_COLORS
    return html.escape(
        f"Scene video: {MAP_MARKER[1]} outlines, the markers detected in the frame ({OTHER_MARKER[1]}: detected "
        f"but not in the map); circles, each eye's gaze point ({l_name} {l_what}, {r_name} {r_what}); "
        f"{TARGET[1]} cross, the estimated 3D target being looked at, with its distance from the scene camera.")


@dataclass(frozen=True)
class OverlayInputs:
    """What the overlay draws on the scene video besides the targets and poses.

    Attributes:
        camera: the scene camera's calibration.
        eyes: the (left, right) eye calibrations, or None (no gaze points drawn).
        eye_samples: the session's raw eye samples.
        marker_map: the session's marker map (its dictionary is detected, its ids drawn green),
            or None (no markers drawn).
        video: the scene video file.
        detections: the tracking step's own marker detections, {frame number: [``MarkerDetection``]}
            for every frame it ran the detector on (an empty list: none found;
            ``formats.marker_detections.MarkerDetections``), or None (the overlay detects them).
            Given, the preview shows only such frames and detects nothing again
            (``preview_frames``): detection was a quarter of the overlay's time.
    """

    camera: CameraCalibration
    eyes: list | None
    eye_samples: EyeSamples
    marker_map: MarkerMap | None
    video: Path
    detections: Mapping | None = None


@dataclass(frozen=True)
class OverlayTargets:
    """The targets and which one each view line looked at (world frame, mm; s).

    Attributes:
        targets: the ``Target``s.
        t_s: (N,) the view lines' times, increasing.
        labels: (N,) each view line's target index, -1 none.
        paths: the moving targets' paths {index: (t (K,), positions (K, 3), covariances)}.
    """

    targets: list
    t_s: np.ndarray
    labels: np.ndarray
    paths: dict = field(default_factory=dict)

    def at(self, t: float) -> list:
        """[(index, position (3,) world mm)]: the target of the view line nearest ``t`` (within
        ``TARGET_TIME_S``), a moving one where its path is at ``t``; [] none."""
        if len(self.t_s) == 0:
            return []
        j = int(np.clip(np.searchsorted(self.t_s, t), 1, len(self.t_s) - 1)) if len(self.t_s) > 1 else 0
        if len(self.t_s) > 1 and abs(self.t_s[j - 1] - t) < abs(self.t_s[j] - t):
            j -= 1
        k = int(self.labels[j])
        if k < 0 or abs(self.t_s[j] - t) > TARGET_TIME_S:
            return []
        for tg in self.targets:
            if tg.index == k:
                if k in self.paths:
                    tp, P, _ = self.paths[k]
                    return [(k, np.array([np.interp(t, tp, P[:, m]) for m in range(3)]))]
                return [(k, tg.position_mm)] if np.all(np.isfinite(tg.position_mm)) else []
        return []


@dataclass(frozen=True)
class FrameMarks:
    """What one overlay frame shows, in the full-resolution frame's pixels.

    Attributes:
        markers: [(id, corners (4, 2) px, in the map)] as detected.
        targets: [(index, px (2,), distance from the scene camera, mm)].
        gaze: [(eye 0 left / 1 right, px (2,))].
        text: the status line (time, and 'no head pose' without one).
    """

    markers: list = field(default_factory=list)
    targets: list = field(default_factory=list)
    gaze: list = field(default_factory=list)
    text: str = ""


def field_radius(camera: CameraCalibration) -> float:
    """The largest normalised radius (x/z, y/z) the image shows: its corners' and edge
    midpoints', undistorted."""
    w, h = camera.image_size
    border = np.array([[0, 0], [w / 2, 0], [w, 0], [w, h / 2], [w, h], [w / 2, h], [0, h], [0, h / 2]], float)
    return float(np.max(np.linalg.norm(camera.undistort_points(border), axis=1)))


def project_in_view(camera: CameraCalibration, pts_cam_mm, r_max: float) -> np.ndarray:
    """(N, 2) pixels of points (N, 3) in the camera frame (mm); NaN for a point behind or
    nearer than ``MIN_DEPTH_MM``, outside the calibrated field (normalised radius ``r_max``) or
    outside the image."""
    pc = np.atleast_2d(np.asarray(pts_cam_mm, float))
    px = np.full((len(pc), 2), np.nan)
    ok = pc[:, 2] > MIN_DEPTH_MM
    ok[ok] = np.linalg.norm(pc[ok, :2], axis=1) / pc[ok, 2] <= r_max
    if ok.any():
        px[ok] = camera.project(pc[ok])
    w, h = camera.image_size
    inside = np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    px[~inside] = np.nan
    return px


def frame_marks(inp: OverlayInputs, found, targets: OverlayTargets, T_world_from_cam, t: float,
                r_max: float) -> FrameMarks:
    """The marks of the frame at time ``t`` (s): the detections ``found`` (``MarkerDetection``s),
    the target looked at, projected at the head pose ``T_world_from_cam`` (4, 4; NaN none), and
    the eye sample nearest ``t``'s gaze points."""
    ids = set(inp.marker_map.poses) if inp.marker_map is not None else set()
    markers = [(d.marker_id, d.corners_px, d.marker_id in ids) for d in found]
    marks = []
    posed = bool(np.isfinite(T_world_from_cam[0, 0]))
    if posed:
        T_cam_from_world = np.linalg.inv(T_world_from_cam)
        for k, X in targets.at(t):
            pc = T_cam_from_world[:3, :3] @ X + T_cam_from_world[:3, 3]
            px = project_in_view(inp.camera, pc, r_max)[0]
            if np.all(np.isfinite(px)):
                marks.append((k, px, float(np.linalg.norm(pc))))
    gaze = []
    eye = inp.eye_samples
    if inp.eyes is not None and len(eye.t):
        j = int(np.argmin(np.abs(eye.t - t)))
        if abs(eye.t[j] - t) <= EYE_TIME_S:
            for e in (0, 1):
                if eye.valid[j, e]:
                    q = inp.eyes[e].image_points(eye.raw[j:j + 1, e])[0]
                    px = project_in_view(inp.camera, 1000.0 * np.array([q[0], q[1], 1.0]), r_max)[0]   # a ray
                    if px is not None and np.all(np.isfinite(px)):
                        gaze.append((e, px))
    return FrameMarks(markers, marks, gaze, f"t = {t:.2f} s" + ("" if posed else ", no head pose"))


def label_origin(text_size, anchor, image_size, offset=(15, -15)) -> tuple[int, int]:
    """The origin (bottom-left, px) of a text box of ``text_size`` ((width, height), baseline
    included in height) placed at ``anchor`` + ``offset``, moved so that the whole box is inside
    an image of ``image_size`` (width, height); a box that would leave on the right or the top
    goes to the anchor's other side."""
    (tw, th), (w, h) = text_size, image_size
    x, y = anchor[0] + offset[0], anchor[1] + offset[1]
    if x + tw > w:
        x = anchor[0] - offset[0] - tw
    if y - th < 0:
        y = anchor[1] - offset[1] + th
    return int(np.clip(x, 0, max(w - tw, 0))), int(np.clip(y, th, max(h - 1, th)))


def put_label(img, text: str, anchor, rgb, scale: float, thickness: int, offset=(15, -15)) -> None:
    """``text`` near ``anchor`` (px), in ``rgb`` on a dark outline, kept inside ``img``."""
    (tw, th), base = cv2.getTextSize(text, FONT, scale, thickness + 2)
    h, w = img.shape[:2]
    x, y = label_origin((tw, th + base), anchor, (w, h), offset)
    y -= base
    cv2.putText(img, text, (x, y), FONT, scale, (0, 0, 0), thickness + 2, cv2.LINE_AA)
    cv2.putText(img, text, (x, y), FONT, scale, bgr(rgb), thickness, cv2.LINE_AA)


def draw_marks(frame, marks: FrameMarks) -> np.ndarray:
    """A copy of ``frame`` (H, W, 3) BGR with ``marks`` drawn; line widths and text scale with
    the frame's width (sized for 1280 px)."""
    img = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    s = img.shape[1] / 1280.0
    lw = max(int(round(2 * s)), 1)
    for mid, c, in_map in marks.markers:
        rgb = (MAP_MARKER if in_map else OTHER_MARKER)[2]
        cv2.polylines(img, [np.round(np.asarray(c) * 16).astype(np.int32)], True, bgr(rgb), lw, cv2.LINE_AA, shift=4)
        put_label(img, str(mid), np.asarray(c)[0], rgb, 0.5 * s, lw, offset=(0, -4))
    for e, px in marks.gaze:
        cv2.circle(img, _pt(px), max(int(round(14 * s)), 2), bgr(EYE_COLORS[e][2]), max(int(round(3 * s)), 1),
                   cv2.LINE_AA)
    for k, px, dist_mm in marks.targets:
        cv2.drawMarker(img, _pt(px), bgr(TARGET[2]), cv2.MARKER_CROSS, max(int(round(40 * s)), 4),
                       max(int(round(4 * s)), 1))
        put_label(img, f"target {k}: {dist_mm / 1000:.2f} m", px, TARGET[2], 0.9 * s, max(int(round(2 * s)), 1))
    if marks.text:
        put_label(img, marks.text, (0, 0), TEXT[2], 0.6 * s, lw, offset=(8, 8))
    return img


def preview_frames(posed, fps: float, detections=None) -> tuple[set, float]:
    """(the frame numbers the preview shows, its frame rate): of the ``posed`` frames (frame
    numbers), every k-th frame for about ``PREVIEW_FPS`` of the video's ``fps``, and at most that;
    with ``detections`` (``OverlayInputs.detections``), only frames the tracking step detected
    markers in, every k-th of those (at its every-other-frame tracking, 7.5 of 30 fps: the
    detections of a frame it did not track do not exist, and drawing a neighbour's would move the
    markers' outlines off them)."""
    posed = sorted(int(f) for f in posed)
    if detections is None:
        step = max(int(round(fps / PREVIEW_FPS)), 1)
        return {f for f in posed if f % step == 0}, fps / step
    tracked = sorted(int(f) for f in detections)
    every = int(np.median(np.diff(tracked))) if len(tracked) > 1 else 1
    k = max(int(np.ceil(fps / (PREVIEW_FPS * max(every, 1)) - 1e-9)), 1)
    shown = set(tracked[::k]) & set(posed)
    return shown, fps / (k * max(every, 1))


def _pt(px) -> tuple[int, int]:
    return int(round(float(px[0]))), int(round(float(px[1])))


def write_overlays(out: Path, inp: OverlayInputs, targets: OverlayTargets, t_p, frame_p, T_p, video: bool = False,
                   progress=None) -> tuple[str | None, str | None]:
    """The report's video (``PREVIEW_NAME``: the whole session at ``PREVIEW_FPS``, ``PREVIEW_WIDTH``
    px) and, with ``video``, the full-resolution one (``VIDEO_NAME``, every frame) in ``out``.
    ``t_p``, ``frame_p``, ``T_p``: poses.csv's times (N,) s, frame numbers (N,) and
    T_world_from_cam (N, 4, 4) (a frame without a row is written undrawn to the full video).
    ``progress(done, total)``: called after each frame read. Returns the names written (None:
    not written)."""
    cap, fps, n_total = open_video(Path(inp.video), inp.camera.image_size)
    row = {int(f): k for k, f in enumerate(frame_p)}
    shown, preview_fps = preview_frames(row, fps, inp.detections if inp.marker_map is not None else None)
    w, h = inp.camera.image_size
    size = (PREVIEW_WIDTH, int(round(h * PREVIEW_WIDTH / w)))
    # the markers are drawn where found; at the preview's 640 px the corners' sub-pixel refinement
    # (a third of the detection's cost) shows nothing: only the full-resolution video gets it
    detector = MarkerDetector(inp.marker_map.dictionary, refine="edges" if video else "none") \
        if inp.marker_map is not None else None
    r_max = field_radius(inp.camera)
    try:
        _write_videos(out, cap, (fps, preview_fps), row, shown, size, (w, h), video,
                      (inp, detector, targets, r_max, t_p, T_p), progress, n_total)
    except _NoFrames:
        return None, None
    return PREVIEW_NAME, VIDEO_NAME if video else None


def _write_videos(out, cap, rates, row, shown, size, full_size, video, drawing, progress, n_total) -> None:
    """Both videos (``rates``: the full one's and the preview's frames per second; ``shown``: the
    preview's frames), each written to a temporary name and moved into place when whole (none
    when no frame had a pose: ``_NoFrames``)."""
    fps, preview_fps = rates
    with contextlib.ExitStack() as stack:
        small = BrowserVideoWriter(stack.enter_context(atomic_path(out / PREVIEW_NAME)), preview_fps, size)
        full = BrowserVideoWriter(stack.enter_context(atomic_path(out / VIDEO_NAME)), fps, full_size) if video \
            else None
        try:
            n_shown = _write_frames(cap, row, shown, (small, full, size), drawing, progress, n_total)
        finally:
            cap.release()
            small.close()
            if full is not None:
                full.close()
        if not n_shown:
            raise _NoFrames


class _NoFrames(Exception):
    """No frame of the video had a pose: nothing to show (the files are not kept)."""


def _write_frames(cap, row: dict, shown: set, writers, drawing, progress, n_total: int) -> int:
    """Read the video once: the frames ``shown`` drawn into the small video, every frame (drawn
    where posed) into the full one; the number of frames in the small one. A frame's markers are
    the tracking step's detections when it has them (``OverlayInputs.detections``), else found
    here."""
    small, full, size = writers
    inp, detector, targets, r_max, t_p, T_p = drawing
    known = inp.detections or {}
    i = n_shown = 0
    while True:
        k = row.get(i)
        preview = k is not None and i in shown
        if full is None and not preview:
            if not cap.grab():
                break
            i += 1
            continue
        ok, frame = cap.read()
        if not ok:
            break
        if k is not None:
            found = [] if detector is None else known[i] if i in known else detector.detect(to_gray(frame))
            frame = draw_marks(frame, frame_marks(inp, found, targets, T_p[k], float(t_p[k]), r_max))
        if full is not None:
            full.write(frame)
        if preview:
            small.write(cv2.resize(frame, size, interpolation=cv2.INTER_AREA))
            n_shown += 1
        if progress:
            progress(i + 1, max(n_total, i + 1))
        i += 1
    return n_shown


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"EYE_COLOURS": "EYE_COLORS"})
