"""Markerless head pose from one flat, textured thing in view (a poster, a screen, a whiteboard):
features of a reference image of it matched in each frame, a USAC homography to reject wrong
matches, and the pose from the inliers and the camera model.

The plane's frame (the "world" unless the caller places it): origin at the reference image's
top-left corner, x along its width, y down its height, z into the surface; mm.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
from numpy.typing import ArrayLike

from calibration.camera import CameraCalibration
from calibration.images import to_gray
from estimator._checks import check_transform, check_vector
from estimator.frames import invert

from .pnp import pose_covariance, pose_fault, reprojection_residuals, rms_px, transform_from_rvec_tvec
from .pose import OK, REJECTED, TOO_FEW, PoseResult

log = logging.getLogger(__name__)


class PlanarTracker:
    """Args:
        reference: (h, w) grey image of the surface, seen straight on and cropped to it.
        size_mm: (width, height) of the surface, mm.
        camera: the scene camera.
        T_world_from_plane: where the surface is in the world (default: the world is the plane).
        features: 'sift' (default, accurate) or 'orb' (faster).
        min_inliers: fewest homography inliers accepted.
        max_reproj_px: inlier RMS above which a pose is rejected.
    """

    def __init__(self, reference: ArrayLike, size_mm: ArrayLike, camera: CameraCalibration,
                 T_world_from_plane: ArrayLike | None = None, features: str = "sift", min_inliers: int = 15,
                 max_reproj_px: float = 2.0, n_features: int = 4000) -> None:
        ref = np.asarray(reference)
        size_mm = check_vector(size_mm, "size_mm", 2)
        if not np.all(size_mm > 0):
            raise ValueError(f"size_mm must be a positive (width, height), got {size_mm.tolist()}")
        if ref.ndim not in (2, 3):
            raise ValueError(f"reference must have shape (H, W) or (H, W, 3), got {ref.shape}")
        ref = to_gray(ref)
        self.det: cv2.Feature2D
        if features == "sift":
            self.det = cv2.SIFT.create(nfeatures=n_features)
            self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        elif features == "orb":
            self.det = cv2.ORB.create(nfeatures=n_features)
            self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        else:
            raise ValueError(f"features must be sift or orb, got {features!r}")
        self.kp_ref, self.des_ref = self.det.detectAndCompute(ref, None)
        if self.des_ref is None or len(self.kp_ref) < min_inliers:
            raise ValueError(f"the reference image has {len(self.kp_ref)} features: it needs texture")
        h, w = ref.shape[:2]
        log.info("planar tracker: %d %s features in the %dx%d reference (%g x %g mm)", len(self.kp_ref), features, w, h,
                 *size_mm)
        sx, sy = size_mm[0] / w, size_mm[1] / h
        pts = np.array([k.pt for k in self.kp_ref])
        # keypoint (pixel centre convention) -> plane mm
        self.obj_ref = np.column_stack([(pts[:, 0] + 0.5) * sx, (pts[:, 1] + 0.5) * sy, np.zeros(len(pts))])
        self.camera = camera
        self.f = float(camera.camera_matrix[0, 0])
        self.T_world_from_plane = (np.eye(4) if T_world_from_plane is None
                                   else check_transform(T_world_from_plane, "T_world_from_plane"))
        self.min_inliers = min_inliers
        self.max_reproj_px = max_reproj_px

    def estimate(self, image: ArrayLike) -> PoseResult:
        img = to_gray(image)
        kp, des = self.det.detectAndCompute(img, None)
        if des is None or len(kp) < self.min_inliers:
            return PoseResult(None, TOO_FEW, f"{0 if des is None else len(kp)} features in the frame")
        pairs = self.matcher.knnMatch(des, self.des_ref, k=2)
        good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < 0.75 * m[1].distance]
        if len(good) < self.min_inliers:
            return PoseResult(None, TOO_FEW, f"{len(good)} distinctive matches with the reference")
        px = np.array([kp[m.queryIdx].pt for m in good])
        obj = self.obj_ref[[m.trainIdx for m in good]]
        x = self.camera.undistort_points(px)
        H, mask = cv2.findHomography(obj[:, :2], x, cv2.USAC_MAGSAC, 3.0 / self.f, maxIters=5000, confidence=0.999)
        if H is None or mask is None or mask.sum() < self.min_inliers:
            return PoseResult(None, REJECTED, "no consistent homography")
        inl = mask.ravel().astype(bool)
        obj_i, x_i = obj[inl], x[inl]
        ok, rvec, tvec = cv2.solvePnP(obj_i, x_i, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return PoseResult(None, REJECTED, "no pose from the homography's inliers")
        rvec, tvec = cv2.solvePnPRefineLM(obj_i, x_i, np.eye(3), None, rvec, tvec)
        r = reprojection_residuals(obj_i, x_i, rvec, tvec)
        # a second pass: drop matches beyond 3 sigma of the fitted pose, refine again
        e = np.linalg.norm(r, axis=1)
        keep = e < max(3 * np.sqrt(np.mean(e**2)), 0.5 / self.f)
        if keep.sum() >= self.min_inliers and not keep.all():
            obj_i, x_i = obj_i[keep], x_i[keep]
            rvec, tvec = cv2.solvePnPRefineLM(obj_i, x_i, np.eye(3), None, rvec, tvec)
            r = reprojection_residuals(obj_i, x_i, rvec, tvec)
        rms = rms_px(r, self.f)
        T_cp = transform_from_rvec_tvec(rvec, tvec)
        log.debug("planar tracker: %d of %d matches inliers, RMS %.2f px", len(x_i), len(good), rms)
        why = pose_fault(T_cp, np.zeros((1, 3)), rms, self.max_reproj_px, "the surface")   # its origin in front
        if why:
            return PoseResult(None, REJECTED, why)
        cov = pose_covariance(obj_i, rvec, tvec, r, self.f, self.T_world_from_plane)
        T_wc = self.T_world_from_plane @ invert(T_cp)
        return PoseResult(T_wc, OK, "", [], int(len(x_i)), rms, cov)
