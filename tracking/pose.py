"""Head pose from the scene camera: all visible markers jointly (SQPnP, RANSAC, Levenberg-
Marquardt), the single-marker ambiguity resolved over time, sanity checks, covariance; and
``pycolmap``'s LO-RANSAC + refinement as an alternative backend.

Frames: ``T_world_from_cam`` (4, 4), mm; image points are undistorted first with the camera
model from ``calibration``, so every solver works on normalised coordinates (K = I).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np

from calibration.camera import CameraCalibration
from estimator._checks import check_transform
from estimator.frames import invert

from .markermap import MarkerMap, square_corners
from .markers import MarkerDetection, detection, split_repeated
from .pnp import pose_covariance, pose_fault, reprojection_residuals, rms_px, transform_from_rvec_tvec

log = logging.getLogger(__name__)



class PoseStatus(str, Enum):
    """Why a frame has (or has not) a pose. The values are the text written to pose files and
    shown in messages (``str()`` and f-strings give the value)."""

    OK = "ok"
    NO_MARKERS = "no_markers"          # no marker of the map (or no reference feature) in view
    TOO_FEW = "too_few_points"         # too few corners or matches to fix a pose
    REJECTED = "rejected"              # a pose was found but failed a sanity check

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


OK, NO_MARKERS, TOO_FEW, REJECTED = PoseStatus.OK, PoseStatus.NO_MARKERS, PoseStatus.TOO_FEW, PoseStatus.REJECTED


@dataclass
class PoseResult:
    """One frame's pose.

    Attributes:
        T_world_from_cam: (4, 4), or None when there is no pose.
        status: a ``PoseStatus`` (``ok``, ``no_markers``, ``too_few_points`` or ``rejected``).
        reason: why there is no pose ('' when ok).
        markers: ids used.
        n_points: corners used (inliers).
        reproj_rms_px: reprojection RMS of the inliers, pixels.
        covariance: (6, 6) of (rotation vector rad, translation mm) of ``T_world_from_cam``, the
            pose beside it: its translation block is the camera position's covariance in the world,
            mm^2 (``pnp.pose_covariance``, from the residuals); None when not computed.
        ambiguous: a single-marker pose chosen between two IPPE solutions.
        repeated_ids: ids of the map detected more than once in the frame; every detection of such
            an id was left out (the map has one marker of each id, so at most one of them is it).
        n_repeated_dropped: detections left out for that reason.
    """

    T_world_from_cam: np.ndarray | None
    status: PoseStatus
    reason: str = ""
    markers: list = field(default_factory=list)
    n_points: int = 0
    reproj_rms_px: float = float("nan")
    covariance: np.ndarray | None = None
    ambiguous: bool = False
    repeated_ids: list = field(default_factory=list)
    n_repeated_dropped: int = 0

    @property
    def ok(self) -> bool:
        return self.status == OK


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle of the rotation between two (3, 3) rotations, degrees."""
    c = (np.trace(Ra.T @ Rb) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


class MarkerPoseEstimator:
    """Pose from detected marker corners.

    Args:
        marker_map: the room.
        camera: intrinsics and distortion.
        max_reproj_px: a pose whose inlier RMS exceeds this is rejected.
        ransac_px: RANSAC inlier threshold, pixels.
        min_points: fewest corners accepted (4 = one marker).
        backend: 'opencv' (SQPnP + RANSAC + LM) or 'pycolmap'.
    """

    def __init__(self, marker_map: MarkerMap, camera: CameraCalibration, max_reproj_px: float = 3.0,
                 ransac_px: float = 4.0, min_points: int = 4, backend: str = "opencv"):
        if backend not in ("opencv", "pycolmap"):
            raise ValueError(f"backend must be opencv or pycolmap, got {backend!r}")
        self.map = marker_map
        self.camera = camera
        self.f = float(camera.camera_matrix[0, 0])
        self.max_reproj_px = max_reproj_px
        self.ransac_px = ransac_px
        self.min_points = min_points
        self.backend = backend
        self.previous: np.ndarray | None = None          # last T_world_from_cam, for continuity
        self._before: np.ndarray | None = None           # the one before it (for the velocity)

    def estimate(self, detections: Iterable[MarkerDetection] | Mapping, previous: np.ndarray | None = None
                 ) -> PoseResult:
        """Pose of one frame from its detections: ``MarkerDetector.detect``'s list of
        ``MarkerDetection`` (or (id, (4, 2) corners) pairs), or a mapping {id: (4, 2) corners};
        corners in distorted pixels. Markers not in the map are ignored. An id of the map detected
        more than once is ambiguous: all its detections are left out, counted in
        ``repeated_ids`` / ``n_repeated_dropped`` and logged. ``previous`` (default: this
        estimator's last good pose) resolves the single-marker ambiguity."""
        prev = self._predicted() if previous is None else check_transform(previous, "previous")
        items = detections.items() if isinstance(detections, Mapping) else detections
        dets = [detection(i, c) for i, c in items]
        by_id, repeated, n_dropped = split_repeated(d for d in dets if d.marker_id in self.map.poses)
        if repeated:
            log.debug("marker ids %s detected more than once: %d detections left out", repeated, n_dropped)
        res = self._estimate(by_id, prev)
        res.repeated_ids, res.n_repeated_dropped = repeated, n_dropped
        if repeated and not res.ok and not by_id:
            res.reason = f"marker ids {repeated} each detected more than once (ambiguous), no other marker in view"
        return res

    def _estimate(self, corners_px: dict, prev: np.ndarray | None) -> PoseResult:
        ids = sorted(corners_px)
        if not ids:
            return PoseResult(None, NO_MARKERS, "no marker of the map in view")
        obj = np.vstack([self.map.corners(i) for i in ids])
        x = self.camera.undistort_points(np.vstack([corners_px[i] for i in ids]))
        if len(obj) < self.min_points:
            return PoseResult(None, TOO_FEW, f"{len(obj)} corners, need {self.min_points}", ids, len(obj))
        if len(ids) == 1:
            res = self._single(ids[0], x, prev)
        elif self.backend == "pycolmap":
            res = self._pycolmap(ids, obj, x)
        else:
            res = self._multi(ids, obj, x)
        if res.ok:
            self._before, self.previous = self.previous, res.T_world_from_cam
        else:
            self._before = self.previous = None if res.status == NO_MARKERS else self.previous
        return res

    def _predicted(self) -> np.ndarray | None:
        """The pose the next frame is compared with: the last good one. (A constant-velocity
        extrapolation doubles the noise of single-marker poses, which is what it would have to
        beat; the last pose is the steadier reference.)"""
        return self.previous

    # -- solvers ---------------------------------------------------------------------------

    def _finish(self, ids: list[int], obj: np.ndarray, x: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                inliers: np.ndarray, ambiguous: bool = False, refine: bool = True) -> PoseResult:
        obj_i, x_i = obj[inliers], x[inliers]
        rvec = np.asarray(rvec, float).reshape(3, 1).copy()     # OpenCV's LM wants (3, 1) columns
        tvec = np.asarray(tvec, float).reshape(3, 1).copy()
        if refine:
            rvec, tvec = cv2.solvePnPRefineLM(obj_i, x_i, np.eye(3), None, rvec, tvec,
                                              (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-12))
        T_cw = transform_from_rvec_tvec(rvec, tvec)
        r = reprojection_residuals(obj_i, x_i, rvec, tvec)
        rms = rms_px(r, self.f)
        used = sorted({ids[k // 4] for k in np.flatnonzero(inliers)})
        why = pose_fault(T_cw, obj, rms, self.max_reproj_px, "a marker")
        if why:
            log.debug("pose from markers %s rejected: %s", used, why)
            return PoseResult(None, REJECTED, why, used, int(inliers.sum()), rms)
        cov = pose_covariance(obj_i, rvec, tvec, r, self.f)
        return PoseResult(invert(T_cw), OK, "", used, int(inliers.sum()), rms, cov, ambiguous)

    def _multi(self, ids: list[int], obj: np.ndarray, x: np.ndarray) -> PoseResult:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, x, np.eye(3), None, iterationsCount=100,
                                                 reprojectionError=self.ransac_px / self.f, confidence=0.999,
                                                 flags=cv2.SOLVEPNP_SQPNP)
        if not ok or inl is None or len(inl) < self.min_points:
            return PoseResult(None, REJECTED, "no consistent pose (RANSAC)", ids, 0)
        mask = np.zeros(len(obj), bool)
        mask[inl.ravel()] = True
        return self._finish(ids, obj, x, rvec, tvec, mask)

    def _single(self, marker_id: int, x: np.ndarray, prev: np.ndarray | None) -> PoseResult:
        """IPPE's two solutions for a square; the better by reprojection unless the two are
        close, then the one nearer the previous pose (a flip is a jump of tens of degrees)."""
        # IPPE_SQUARE wants the corners (-s, s), (s, s), (s, -s), (-s, -s): a y-up marker frame,
        # ours turned half a turn about x (y down, z into the wall)
        flip = np.diag([1.0, -1.0, -1.0, 1.0])
        obj_m = square_corners(self.map.size_of(marker_id)) @ flip[:3, :3]
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj_m, x, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        if n == 0:
            return PoseResult(None, REJECTED, "IPPE found no pose", [marker_id], 4)
        T_wm = self.map.poses[marker_id]
        cands = []
        for rv, tv, e in zip(rvecs, tvecs, np.ravel(errs), strict=True):
            T_cm = transform_from_rvec_tvec(rv, tv) @ flip
            cands.append((float(e), T_wm @ invert(T_cm), rv, tv))
        cands.sort(key=lambda c: c[0])
        choice = cands[0]
        # IPPE's second solution is the mirror of the first about the line of sight; when both
        # explain the corners nearly as well, only continuity can tell them apart
        tol = max(4 * cands[0][0], cands[0][0] + 1.0 / self.f)
        ambiguous = len(cands) > 1 and cands[1][0] < tol
        if ambiguous and prev is not None:
            # the two solutions put the camera at mirror positions about the line of sight,
            # tens of centimetres apart at room distances, while their orientations differ by a
            # few degrees, comparable to a single marker's noise: compare positions
            choice = min(cands, key=lambda c: np.linalg.norm(c[1][:3, 3] - prev[:3, 3]))
        # refine in world coordinates so the result is comparable with the multi-marker path
        T_cw = invert(choice[1])
        obj = self.map.corners(marker_id)
        rvec, _ = cv2.Rodrigues(T_cw[:3, :3])
        return self._finish([marker_id], obj, x, rvec, T_cw[:3, 3].copy(), np.ones(4, bool), ambiguous)

    def _pycolmap(self, ids: list[int], obj: np.ndarray, x: np.ndarray) -> PoseResult:
        import pycolmap

        f = self.f
        cam = pycolmap.Camera(model="PINHOLE", width=int(self.camera.image_size[0]),
                              height=int(self.camera.image_size[1]), params=[f, f, 0.0, 0.0])
        opts = pycolmap.AbsolutePoseEstimationOptions()
        opts.ransac.max_error = self.ransac_px
        opts.ransac.random_seed = 0
        r = pycolmap.estimate_and_refine_absolute_pose(x * f, obj, cam, opts)
        if r is None:
            return PoseResult(None, REJECTED, "no consistent pose (pycolmap)", ids, 0)
        M = r["cam_from_world"].matrix()
        T_cw = np.eye(4)
        T_cw[:3] = M
        mask = np.asarray(r["inlier_mask"], bool)
        # the covariance is ours (_finish), in the same parameters as the OpenCV path's: pycolmap's
        # own describes cam_from_world in its tangent space
        return self._finish(ids, obj, x, cv2.Rodrigues(T_cw[:3, :3])[0], T_cw[:3, 3].copy(), mask, refine=False)
