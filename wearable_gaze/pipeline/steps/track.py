"""Head poses from a scene video: the tracking step over typed values (``track_poses``, and
``track_video`` for a video in a room with a marker map or a markerless map; ``process`` calls it) and ``wearable-gaze
track``'s file-level wrapper (``track_video_files``: reads, calls the step, writes poses.csv and the
overlay)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
from pathlib import Path

import cv2
import numpy as np

from calibration.camera import CameraCalibration
from calibration.images import to_gray
from tracking.homography import PlanarTracker
from tracking.localise import FeatureLocalizer, FeatureMap
from tracking.markermap import MarkerMap
from tracking.markers import MarkerDetector, likely_dictionary
from tracking.pose import MarkerPoseEstimator
from tracking.timeline import SPIKE_DEG, SPIKE_MM, interpolate_poses, pose_spikes, smooth_poses

from ...errors import UserError
from ...formats.atomic import atomic_path
from ...formats.camera import load_camera
from ...formats.images import read_gray_image
from ...formats.marker_detections import MarkerDetections
from ...formats.markermap import load_marker_map
from ...formats.poses import write_poses_csv
from ...formats.sfmmap import load_sfm_map
from ...formats.video import open_video, open_video_writer, read_frame_times, sampled_gray_frames
from ..types import Poses

log = logging.getLogger(__name__)


def frame_times(video: Path, timestamps=None) -> dict | None:
    """{frame: time s} from ``timestamps`` (a frame-timestamp CSV), else the session's
    ``scene_timestamps.csv`` beside the video; None when there is neither (time = frame / fps)."""
    if timestamps is None:
        cand = Path(video).parent / "scene_timestamps.csv"
        timestamps = cand if cand.is_file() else None
    if timestamps is None:
        return None
    frames, t = read_frame_times(timestamps)
    return dict(zip(frames, t, strict=True))


def track_video_files(video, camera_path, out, markers=None, reference=None, reference_size_mm=None, overlay=None,
                timestamps=None, progress=None, smooth_s: float = 0.0, every: int = 1, sfm=None) -> dict:
    """Head pose for every frame of a scene video, written as poses.csv (docs/formats.md).

    One of ``markers`` (a marker map JSON), ``sfm`` (a markerless map folder, ``map
    --markerless``) or ``reference`` (an image of a flat surface) with ``reference_size_mm``
    (width, height). Frame times: ``frame_times``. ``smooth_s``,
    ``every``: see ``track_poses``; with ``overlay`` every frame is tracked. Returns counts.

    ``out`` and ``overlay`` are written under temporary names and renamed once both are
    complete: an error or an interruption leaves neither half-written, and an earlier file
    under either name untouched.
    """
    video = Path(video)
    if sum(x is not None for x in (markers, reference, sfm)) != 1:
        raise UserError("give one of --markers MAP.json, --map SFM_FOLDER or --reference IMAGE --reference-size-mm W H")
    camera = load_camera(camera_path)
    with contextlib.ExitStack() as stack:
        cap, fps, n_total = open_video(video, camera.image_size)
        stack.callback(cap.release)
        times = frame_times(video, timestamps)
        if markers is not None:
            locate = marker_locator(load_marker_map(markers), camera)
        elif sfm is not None:
            locate = room_locator(load_sfm_map(sfm)[0], camera)
        else:
            locate = _reference_locator(reference, reference_size_mm, camera)
        draw = None
        if overlay is not None:
            tmp = stack.enter_context(atomic_path(overlay))         # left last: renamed after the poses
            writer = open_video_writer(tmp, "mp4v", fps, camera.image_size, refused=(
                f"--overlay: OpenCV cannot write an MPEG-4 video named {tmp.suffix!r}; use .mp4 or .avi"))
            stack.callback(writer.release)
            draw = functools.partial(_write_overlay_frame, writer, camera)
        poses = track_poses(cap, fps, n_total, locate, times, every, smooth_s, progress, draw, video)
        if markers is not None:
            check_markers_seen(poses, video, load_marker_map(markers).dictionary, "--markers")
        write_poses_csv(out, poses.t, poses.frame, poses.T_world_from_cam, poses.columns)
    return {"frames": len(poses.t), "posed": poses.n_posed}


def track_video(video: Path, camera: CameraCalibration, room: MarkerMap | FeatureMap, times=None, every: int = 1,
                progress=None) -> Poses:
    """``track_poses`` of a video made by ``camera`` in a room with a marker map or a markerless
    map (``room_locator``); with a marker map, the poses keep the markers detected in each frame
    tracked (``Poses.detections``)."""
    cap, fps, n_total = open_video(Path(video), camera.image_size)
    try:
        poses = track_poses(cap, fps, n_total, room_locator(room, camera), times, every, progress=progress,
                            name=video)
    finally:
        cap.release()
    if not isinstance(room, MarkerMap):
        return dataclasses.replace(poses, detections=None)        # a markerless map: no markers
    check_markers_seen(poses, video, room.dictionary, "the marker map")
    return poses


def check_markers_seen(poses: Poses, video, dictionary: str, source: str) -> None:
    """Refuse a tracking in which no frame saw a marker of the map (``poses.columns['n_markers']``
    all 0): most often a map naming another dictionary than the printed markers' (``source``: the
    option or file that named it), so a few frames are tried with the common dictionaries.

    Raises:
        UserError: naming the dictionary the video's markers look like, when one is found.
    """
    if np.any(np.asarray(poses.columns.get("n_markers", [0])) > 0):
        return
    raise no_marker_error(dictionary, [g for _, g in sampled_gray_frames(video, 5)], f"{video}",
                          f"the dictionary of {source}", 'write "dictionary": "{}" in the map')


def no_marker_error(dictionary: str, images, where: str, source: str, fix: str) -> UserError:
    """The one line for frames (``images``, a few grey images) in which no marker of
    ``dictionary`` (named by ``source``) was found: the dictionary they look like instead
    (``likely_dictionary``) with ``fix`` (a format string, ``{}`` the dictionary), or that none of
    the common ones matches either."""
    guess = likely_dictionary(images, exclude=dictionary)
    if guess is None:
        hint = "nor of any common dictionary: check that the markers are in view and sharp"
    else:
        hint = f"the markers look like {guess[0]} ({guess[1]} found in {len(images)} frames): {fix.format(guess[0])}"
    return UserError(f"{where}: no marker of {dictionary} ({source}) was detected in any frame; {hint}")


def track_poses(cap, fps: float, n_total: int, locate, times=None, every: int = 1, smooth_s: float = 0.0,
                progress=None, draw=None, name="the video") -> Poses:
    """Head pose for every frame of an opened video (``cap``, ``fps``, ``n_total`` frames or 0).

    ``locate(grey)`` -> (pose result, detections). ``times``: {frame: t s} (frames without a
    time are left out), or None for frame / fps. ``smooth_s`` > 0 averages poses over a centred
    window of that length (no lag offline). ``every`` > 1 tracks one frame in ``every`` and
    fills the others by SLERP between tracked neighbours (status 'interpolated'; smooth head
    motion moves a few hundredths of a degree off the line between two poses 1/15 s apart).
    ``draw(frame, found, res)``: called on every frame tracked (all of them). ``name``: the
    video, for messages. The poses keep the markers ``locate`` detected in each frame it ran on
    (``Poses.detections``; none for a locator without markers).
    """
    rows, untimed, found = _track_frames(cap, locate, times, fps, n_total, every, progress, draw)
    if untimed and not rows["frame"]:
        raise UserError(f"{name}: none of its {untimed} frames has a time in the frame-timestamp CSV; give "
                        "--timestamps with a row (frame,t) per frame")
    if not rows["frame"]:
        raise UserError(f"{name}: no frame could be decoded (corrupt or empty video); check that it plays, or "
                        "re-encode it")
    T_all, status = _fill_poses(rows, every, fps, smooth_s)
    return Poses(np.array(rows["t"], float), np.array(rows["frame"], int), T_all,
                 {"n_markers": np.array(rows["n_markers"]), "n_points": np.array(rows["n_points"]),
                  "reproj_rms_px": np.array(rows["reproj_rms_px"]), "status": status},
                 MarkerDetections.of(found))


def room_locator(room: MarkerMap | FeatureMap, camera: CameraCalibration):
    """grey (H, W) uint8 -> (pose result, detections drawn on the overlay), from the room's
    markers (a ``MarkerMap``) or from features matched to a markerless map (a ``FeatureMap``;
    no detections)."""
    if isinstance(room, MarkerMap):
        return marker_locator(room, camera)
    localizer = FeatureLocalizer(room, camera)

    def locate(gray):
        return localizer.estimate(gray), []
    return locate


def marker_locator(marker_map: MarkerMap, camera: CameraCalibration):
    """grey (H, W) uint8 -> (pose result, detections drawn on the overlay), from the markers
    (video frames: ``MarkerDetector``'s ``small_frames``)."""
    detector = MarkerDetector(marker_map.dictionary, small_frames=True)
    estimator = MarkerPoseEstimator(marker_map, camera)

    def locate(gray):
        found = detector.detect(gray)
        return estimator.estimate(found), found
    return locate


def _reference_locator(reference, reference_size_mm, camera: CameraCalibration):
    """grey (H, W) uint8 -> (pose result, no detections), from a photo of a flat surface."""
    ref = read_gray_image(reference, "reference image", "give a PNG or JPEG photo of the surface")
    if reference_size_mm is None or min(reference_size_mm) <= 0:
        raise UserError("--reference-size-mm W H: the surface's physical width and height in mm")
    try:
        tracker = PlanarTracker(ref, reference_size_mm, camera)
    except ValueError as exc:
        raise UserError(f"{reference}: {exc}") from None

    def locate(gray):
        return tracker.estimate(gray), []
    return locate


POSE_ROW = ("t", "frame", "T", "n_markers", "n_points", "reproj_rms_px", "status")


def _track_frames(cap, step, times, fps: float, n_total: int, every: int, progress,
                  draw) -> tuple[dict, int, dict]:
    """Track the frames of ``cap``: one in ``every`` (all when ``draw``) and the last (of
    ``n_total``, when known: the frames after the last tracked one would have no pose, nor would
    the eye samples there), the others get a NaN pose marked 'interpolated'. ``draw(frame,
    found, res)`` is called on every tracked frame.
    A frame ``times`` has no time for (a recording cut short saves its video ahead of its
    timestamps) cannot be placed in time: it is left out, with a warning. Returns the columns
    ``POSE_ROW``, one entry per frame kept, the number of frames left out, and {frame: the
    detections ``step`` returned} of the frames tracked."""
    rows: dict[str, list] = {k: [] for k in POSE_ROW}
    detected: dict = {}
    i = untimed = 0
    while True:
        if times is not None and i not in times:
            if not cap.grab():
                break
            untimed += 1
            i += 1
            continue
        t = times[i] if times is not None else i / fps
        if every > 1 and i % every and draw is None and not (n_total and i >= n_total - 1):   # the last is tracked
            if not cap.grab():
                break
            values = (t, i, np.full((4, 4), np.nan), 0, 0, np.nan, "interpolated")
        else:
            ok, frame = cap.read()
            if not ok:
                break
            res, found = step(to_gray(frame))
            detected[i] = found
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
    return rows, untimed, detected


def _fill_poses(rows: dict, every: int, fps: float, smooth_s: float):
    """(T_world_from_cam (N, 4, 4), status (N,)): a tracked pose that jumps away from both its
    tracked neighbours and back is rejected (``tracking.timeline.pose_spikes``: a pose on one or
    two small markers can land hundreds of mm off); the frames passed over are SLERPed between
    tracked neighbours at most ``every`` + 0.5 frames apart; then all are smoothed over
    ``smooth_s`` if > 0."""
    T_all = np.array(rows["T"])
    status = list(rows["status"])
    t_all = np.array(rows["t"])
    spike, off_mm, off_deg = pose_spikes(t_all, T_all, max_gap_s=(2 * every + 1) / fps)
    for k in np.flatnonzero(spike):
        T_all[k] = np.nan
        status[k] = f"rejected: a spike, {off_mm[k]:.0f} mm and {off_deg[k]:.1f} deg off its neighbours"
    if spike.any():
        log.info("%d tracked poses rejected as spikes (off their neighbours by over %g mm or %g deg)",
                 int(spike.sum()), SPIKE_MM, SPIKE_DEG)
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
