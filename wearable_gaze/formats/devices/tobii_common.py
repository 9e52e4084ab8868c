"""What the Tobii Pro Glasses 2 and 3 importers share (``tobii_g2``, ``tobii_g3``): the glasses
frame and its mapping to our head frame, the eye-sample checks, the chunk that goes into the
session, the scene camera and video, and the writer's conversion of a simulated session.

Frames. Tobii's glasses frame (HUCS) has x to the wearer's LEFT, y UP, z FORWARD, mm, its origin at
(near) the scene camera. Our head frame is the scene camera's, OpenCV axes (x right, y down, z
forward), mm. Nominally the two differ by a 180 deg rotation about z (``T_CAM_FROM_GLASSES_NOMINAL``);
each unit carries its own scene-camera extrinsics (G2: TSLV type-300 record in ``et.tslv``; G3:
``recording.g3`` ``scenecamera.camera-calibration``: ``rotation`` 3x3 and ``position`` mm), and
``t_cam_from_glasses`` builds the mapping from them. On the G2 sample the unit's rotation is 1.07
deg away from the nominal flip and reproduces Tobii's own 2D gaze from its 3D gaze to 0.058 px;
the flip alone gives 11.8 px (docs/devices/tobii-pupil.md sections 0 and 1.4).

The position's sign convention is not documented: glassesTools applies ``R p + position``, the
glassesValidator sample's notes write ``R (p - position)``. ``choose_convention`` decides it on
the recording itself: it projects the device's 3D gaze both ways with the device's intrinsics and
keeps the one that reproduces the device's own 2D gaze (under ``REPROJECTION_OK_PX``).
"""

from __future__ import annotations

import gzip
import io
import json
import logging
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import UserError
from ..camera import load_camera

log = logging.getLogger(__name__)

T_CAM_FROM_GLASSES_NOMINAL = np.array([[-1.0, 0.0, 0.0, 0.0],
                                       [0.0, -1.0, 0.0, 0.0],
                                       [0.0, 0.0, 1.0, 0.0],
                                       [0.0, 0.0, 0.0, 1.0]])
"""(4, 4) our head frame (scene camera, OpenCV axes) from Tobii's glasses frame (x left, y up, z
forward), nominal: a 180 deg rotation about z, no offset. Used only when the recording carries no
scene-camera extrinsics (Tobii Pro Glasses 2 Developer's Guide: "3D coordinates with origo in the
scenecam"; glassesTools ``gaze_worldref``; docs/devices/tobii-pupil.md section 1.4)."""

CONVENTIONS = {"R p + position": 1.0, "R (p - position)": -1.0}
"""The two readings of the unit's ``position`` (mm): p_cam = R p + position (glassesTools) or
R (p - position); the value is the sign applied to R position in the translation."""

REPROJECTION_OK_PX = 1.0
"""The device's 3D gaze must reproduce its 2D gaze within this (median, px) for the frame
mapping to be confirmed (G2 sample: 0.058 px)."""

MAX_EYE_DISTANCE_MM = 100.0
"""A pupil centre farther than this from the glasses' origin (the scene camera) is implausible:
the eyes sit about 45 mm from it (G2 sample: median |pc| 46 mm)."""

NAN3 = (np.nan, np.nan, np.nan)
CHUNK = 2048
"""Eye samples per chunk handed to the session (memory stays flat in the recording's length)."""


@dataclass
class GlassesCamera:
    """A unit's scene camera: extrinsics in the glasses frame and intrinsics.

    Attributes:
        rotation: (3, 3) the unit's rotation, cam from glasses (re-orthonormalised).
        position_mm: (3,) the unit's position, mm.
        camera_matrix: (3, 3) K, px (None: the recording has no intrinsics).
        dist_coeffs: (5,) OpenCV k1, k2, p1, p2, k3.
        image_size: (width, height) px.
        source: where it was read.
    """

    rotation: np.ndarray
    position_mm: np.ndarray
    camera_matrix: np.ndarray | None
    dist_coeffs: np.ndarray | None
    image_size: tuple | None
    source: str


def orthonormal(R) -> np.ndarray:
    """The rotation nearest to R (3, 3) (the devices store it as float32)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float).reshape(3, 3))
    Q = U @ Vt
    if np.linalg.det(Q) < 0:
        raise UserError("the scene camera's stored rotation is a reflection, not a rotation; the calibration record "
                        "is damaged (give --camera and re-export the recording)")
    return Q


def t_cam_from_glasses(cam: GlassesCamera, convention: str = "R p + position") -> np.ndarray:
    """(4, 4) T_cam_from_glasses of a unit: rotation R and translation ``position`` (p_cam =
    R p + position) or -R ``position`` (p_cam = R (p - position)), as ``convention`` says (one of
    ``CONVENTIONS``)."""
    R = cam.rotation
    T = np.eye(4)
    T[:3, :3] = R
    p = np.asarray(cam.position_mm, float)
    T[:3, 3] = p if CONVENTIONS[convention] > 0 else -R @ p
    return T


def apply(T, points) -> np.ndarray:
    """Points (n, 3) mm mapped by T (4, 4)."""
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


def project_norm(points_cam, cam: GlassesCamera) -> np.ndarray:
    """Points (n, 3) mm in the camera frame -> normalised image coordinates (n, 2) (0..1, origin
    top-left, as Tobii's gp / gaze2d)."""
    import cv2

    p = np.ascontiguousarray(points_cam, float).reshape(-1, 1, 3)
    px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.camera_matrix, cam.dist_coeffs)
    return px.reshape(-1, 2) / np.asarray(cam.image_size, float)


def choose_convention(cam: GlassesCamera | None, gaze3d, gaze2d_norm, imp) -> tuple[np.ndarray, dict]:
    """Decide the position convention on the recording: the device's 3D gaze points (n, 3) mm,
    glasses frame, against its 2D gaze (n, 2) normalised. Returns (T_cam_from_glasses, report).

    Without a camera the nominal flip is used (noted); without intrinsics or pairs the
    glassesTools reading is used and the report says it was not checked; when neither reading
    reproduces the 2D gaze within ``REPROJECTION_OK_PX`` the better one is used, the report says
    ``confirmed: false`` and ``imp`` notes it.
    """
    if cam is None:
        imp.note("no scene-camera calibration in the recording: the nominal glasses -> camera flip is used")
        return T_CAM_FROM_GLASSES_NOMINAL.copy(), {"convention": "nominal flip", "confirmed": False}
    g3, g2 = np.asarray(gaze3d, float).reshape(-1, 3), np.asarray(gaze2d_norm, float).reshape(-1, 2)
    ok = np.all(np.isfinite(g3), axis=1) & np.all(np.isfinite(g2), axis=1) & (g3[:, 2] > 0)
    if cam.camera_matrix is None or ok.sum() < 3:
        why = "no intrinsics" if cam.camera_matrix is None else f"only {int(ok.sum())} samples with both"
        return t_cam_from_glasses(cam), {"convention": "R p + position", "confirmed": False,
                                         "why": f"not checked: {why} (3D and 2D gaze)"}
    size = np.asarray(cam.image_size, float)
    err = {}
    for name in CONVENTIONS:
        px = project_norm(apply(t_cam_from_glasses(cam, name), g3[ok]), cam) * size
        err[name] = float(np.median(np.linalg.norm(px - g2[ok] * size, axis=1)))
    best = min(err, key=err.get)
    report = {"convention": best, "confirmed": err[best] < REPROJECTION_OK_PX, "samples": int(ok.sum()),
              "median_reprojection_px": {k: round(v, 4) for k, v in err.items()}}
    if not np.any(cam.position_mm):
        report["convention"] = "position is zero (both readings agree)"
    if not report["confirmed"]:
        imp.note(f"the device's 3D gaze does not reproduce its 2D gaze through the scene camera (median "
                 f"{err[best]:.2f} px): the frame mapping or the intrinsics are doubtful")
    return t_cam_from_glasses(cam, best), report


def eye_checks(side: str, origin, direction, valid, drops: Counter) -> np.ndarray:
    """The eyes (n,) that are usable: ``valid`` (the device's own flag) and a finite origin within
    ``MAX_EYE_DISTANCE_MM`` of the glasses' origin and a finite unit direction pointing forward
    (glasses frame). Each eye rejected here is counted in ``drops`` with its reason."""
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    v = np.asarray(valid, bool).copy()
    checks = (("non-finite values", ~(np.all(np.isfinite(o), axis=1) & np.all(np.isfinite(d), axis=1))),
              (f"implausible eye centre (over {MAX_EYE_DISTANCE_MM:.0f} mm from the scene camera)",
               np.linalg.norm(np.nan_to_num(o), axis=1) > MAX_EYE_DISTANCE_MM),
              ("direction not a unit vector", np.abs(np.linalg.norm(np.nan_to_num(d), axis=1) - 1) > 0.05),
              ("direction points backwards", np.nan_to_num(d[:, 2]) <= 0))
    for reason, bad in checks:
        bad &= v
        drops[f"{side} eye: {reason}"] += int(bad.sum())
        v &= ~bad
    return v


class JsonLines:
    """The JSON objects of a gzip JSON-lines file, one at a time (unparsable lines counted; a
    truncated gzip ends the stream with a note), with the compressed bytes read for progress."""

    def __init__(self, path: Path, drops: Counter, progress=None):
        self.path, self.drops, self.progress = path, drops, progress
        self.size = path.stat().st_size
        self.n_lines = 0
        self.truncated = None

    def __iter__(self):
        with open(self.path, "rb") as raw, io.TextIOWrapper(gzip.GzipFile(fileobj=raw), encoding="utf-8",
                                                            errors="replace") as fh:
            try:
                for line in fh:
                    self.n_lines += 1
                    if self.progress is not None and self.n_lines % 20000 == 0:
                        self.progress(raw.tell(), self.size)
                    try:
                        obj = json.loads(line)
                    except ValueError:
                        obj = None
                    if isinstance(obj, dict):
                        yield obj
                    elif line.strip():
                        self.drops["line: unparsable JSON"] += 1
                        if not line.endswith("\n"):        # the last line, cut: the file was cut short
                            self.truncated = (f"{self.path.name} ends in a partial line (line {self.n_lines}: the "
                                              "file was cut short); read up to there")
            except gzip.BadGzipFile as exc:
                raise UserError(f"{self.path}: not a gzip file ({exc}); copy it again from the recording") from None
            except (EOFError, zlib.error) as exc:
                self.truncated = f"{self.path.name} is truncated after {self.n_lines} lines ({exc}); read up to there"


def vec(v, n=3):
    """``v`` if it is a list of n numbers, else n NaN (a malformed field is a non-finite value)."""
    if isinstance(v, list) and len(v) == n and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                   for x in v):
        return v
    return NAN3[:n] if n <= 3 else (np.nan,) * n


class GapCounter:
    """Counts the samples missing from the device's stream: a step between consecutive device
    times over 1.5 sample periods lost round(step * rate) - 1 samples."""

    def __init__(self, rate_hz: float):
        self.rate = rate_hz
        self.last = None
        self.largest_s = 0.0

    def feed(self, t_sorted, drops: Counter) -> None:
        """Device times (n,) s, in order."""
        t = np.asarray(t_sorted, float)
        if not len(t):
            return
        steps = np.diff(t if self.last is None else np.concatenate([[self.last], t]))
        big = steps[steps > 1.5 / self.rate]
        drops["gap: samples missing from the device's stream"] += int(np.sum(np.round(big * self.rate) - 1))
        if len(steps):
            self.largest_s = max(self.largest_s, float(steps.max()))
        self.last = float(t[-1])


class RayChunks:
    """Takes chunks of device samples (glasses frame), checks them, maps them to our head frame and
    hands them to the session: ``add_rays`` and ``add_device_gaze``. Keeps the drop counts."""

    def __init__(self, imp, T_cam_from_glasses):
        self.imp = imp
        self.T = T_cam_from_glasses
        self.drops = Counter()
        self.t_last = -np.inf

    def emit(self, t, eyes, gaze3d) -> None:
        """t (n,) s on the session clock; eyes: per side ('left', 'right') a tuple (origin (n, 3) mm,
        direction (n, 3), valid (n,) bool), glasses frame; gaze3d (n, 3) mm, glasses frame (NaN:
        none)."""
        t = np.asarray(t, float)
        order = np.argsort(t, kind="stable")
        t = t[order]
        keep = np.ones(len(t), bool)
        if len(t):
            keep[1:] = np.diff(t) > 0
            keep &= t > self.t_last
        self.drops["sample: time not increasing"] += int((~keep).sum())
        out = []
        for side in ("left", "right"):
            o, d, v = (np.asarray(a)[order] for a in eyes[side])
            v = eye_checks(side, o, d, v, self.drops)
            out.append((apply(self.T, np.nan_to_num(o)), np.nan_to_num(d) @ self.T[:3, :3].T, v))
        any_eye = out[0][2] | out[1][2]
        self.drops["sample: no valid eye"] += int((keep & ~any_eye).sum())
        keep &= any_eye
        if not keep.any():
            return
        (ol, dl, vl), (orr, dr, vr) = out
        self.imp.add_rays(t[keep], ol[keep], dl[keep], vl[keep], orr[keep], dr[keep], vr[keep])
        self.imp.add_device_gaze(t[keep], apply(self.T, np.asarray(gaze3d, float)[order][keep]))
        self.t_last = float(t[keep][-1])

    def flush_drops(self) -> None:
        for reason, n in self.drops.items():
            self.imp.drop(reason, n)
        self.drops.clear()


def video_frame_times(video: Path) -> tuple[np.ndarray, tuple]:
    """(frame times (N,) s from the video's own clock (frame i at i / fps), (width, height))."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise UserError(f"{video}: OpenCV cannot open the scene video (corrupt or truncated); re-copy it from the "
                        "recording, or remove it to import without head poses")
    try:
        n, fps = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), cap.get(cv2.CAP_PROP_FPS)
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    finally:
        cap.release()
    if n <= 0 or not fps > 0:
        raise UserError(f"{video}: the scene video reports no frames or no frame rate; re-copy it from the recording")
    return np.arange(n) / fps, size


def finish_import(imp, options, cam: GlassesCamera | None, video: Path | None, frame_times, rate_hz: float,
                  clock_offset_s: float, frames: dict, **extra) -> dict:
    """The scene camera (the device's intrinsics, or ``options.camera``), the scene video, the
    marker map, the pose source, then ``imp.finish``. ``frame_times`` (N,) s on the session clock
    (None: the video cannot be placed on it)."""
    K = dist = size = None
    if options.camera is not None:
        user = load_camera(options.camera)
        K, dist, size = user.camera_matrix, user.dist_coeffs, user.image_size
        imp.note(f"scene-camera intrinsics from {options.camera} (--camera), not the device's calibration")
    elif cam is not None and cam.camera_matrix is not None:
        K, dist, size = cam.camera_matrix, cam.dist_coeffs, cam.image_size
    if K is not None:
        imp.set_camera(K, dist, size)
    if video is not None and frame_times is not None:
        imp.add_scene_video(video, frame_times)
    if options.markers is not None:
        imp.set_marker_map(options.markers)
    missing = [what for what, have in (("a scene video", video is not None and frame_times is not None),
                                       ("the scene camera's calibration", K is not None),
                                       ("a marker map (--markers)", options.markers is not None)) if not have]
    if missing:
        pose_source = "still_head"
        imp.note(f"no head poses: {', '.join(missing)} missing; the head frame is the world (a still head), so the "
                 "estimates are vergence only")
    else:
        pose_source = "scene_video"
    return imp.finish(rate_hz, clock_offset_s, pose_source, frames, image_size=size, **extra)


def frames_report(T: np.ndarray, cam: GlassesCamera | None, convention: dict) -> dict:
    """The ``frames`` entry of the import report: the glasses -> head mapping in words and matrix."""
    return {"glasses": "Tobii glasses frame (HUCS): x to the wearer's left, y up, z forward, mm",
            "head": "scene camera, OpenCV axes (x right, y down, z forward), mm",
            "T_cam_from_glasses": np.round(T, 9).tolist(),
            "extrinsics_source": cam.source if cam is not None else "nominal 180 deg flip about z (no calibration)",
            "position_convention": convention}


# --- the writers' side ----------------------------------------------------------------------------

def sim_in_glasses(sim, T_cam_from_glasses) -> dict:
    """A simulated session's rays and gaze in the glasses frame: {'left'/'right': (origin (N, 3),
    direction (N, 3), valid (N,)), 'gaze3d': (N, 3)} (the inverse of the importer's mapping)."""
    T_inv = np.linalg.inv(T_cam_from_glasses)
    out = {}
    r = sim.rays
    for side, (o, d) in (("left", (r.left_origin_mm, r.left_direction)),
                         ("right", (r.right_origin_mm, r.right_direction))):
        o, d = np.asarray(o, float), np.asarray(d, float)
        v = np.all(np.isfinite(o), axis=1) & np.all(np.isfinite(d), axis=1)
        with np.errstate(invalid="ignore"):
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
        out[side] = (apply(T_inv, np.nan_to_num(o)), np.nan_to_num(d) @ T_inv[:3, :3].T, v)
    out["gaze3d"] = apply(T_inv, sim.gaze_head_mm)
    return out


def writer_camera(sim, position_mm) -> GlassesCamera:
    """The simulated unit's scene camera: the G2 sample's own rotation (1.07 deg from the nominal
    flip), ``position_mm`` and the simulation's true intrinsics (5 OpenCV coefficients)."""
    R = orthonormal([[-0.9998840093612671, 0.013891199603676796, -0.006228810176253319],
                     [-0.013957999646663666, -0.9998440146446228, 0.010816000401973724],
                     [-0.006077589932829142, 0.010901699773967266, 0.999921977519989]])
    dist = np.zeros(5)
    d = np.asarray(sim.camera.dist_coeffs, float).ravel()[:5]
    dist[:len(d)] = d
    return GlassesCamera(R, np.asarray(position_mm, float), np.asarray(sim.camera.camera_matrix, float), dist,
                         tuple(sim.image_size), "simulation")
