"""Shared PnP pieces for the pose solvers (``tracking.pose``, ``tracking.homography``): the pose
of (rvec, tvec), reprojection residuals, the reprojection RMS and the pose covariance.

Every solver here works on undistorted normalised image coordinates (K = I) and OpenCV's
(rvec, tvec), which map object (world or plane) points into the camera: ``T_cam_from_obj``.
The covariance a pose result carries is propagated to the pose it sits beside,
``T_obj_from_cam`` (for the marker solver, ``T_world_from_cam``).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike

SIGMA_FLOOR_PX = 0.05   # the noise assumed at least, pixels: a perfect fit must not claim zero covariance


def transform_from_rvec_tvec(rvec: ArrayLike, tvec: ArrayLike) -> np.ndarray:
    """``T_cam_from_obj`` (4, 4) of OpenCV's rotation vector (3,) and translation (3,), mm."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, float))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.asarray(tvec, float).ravel()
    return T


def reprojection_residuals(obj_pts: ArrayLike, x_norm: ArrayLike, rvec: ArrayLike, tvec: ArrayLike) -> np.ndarray:
    """Residuals (N, 2), normalised image coordinates, of object points (N, 3) mm projected with
    (rvec, tvec) minus their observations ``x_norm`` (N, 2) (undistorted, K = I)."""
    proj, _ = cv2.projectPoints(obj_pts, rvec, tvec, np.eye(3), None)
    return proj.reshape(-1, 2) - x_norm


def rms_px(residuals: np.ndarray, focal_px: float) -> float:
    """RMS length, pixels, of normalised residuals (N, 2) on a camera of focal length ``focal_px``."""
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1)))) * focal_px


def pose_fault(T_cam_from_obj: ArrayLike, pts_obj: ArrayLike, rms: float, max_reproj_px: float, what: str) -> str:
    """Why a solved pose fails the sanity checks every solver applies, or '' when it passes: a
    point of ``pts_obj`` (N, 3), object frame, behind the camera (``what`` names the points in
    the message), or the inliers' reprojection RMS ``rms`` over ``max_reproj_px`` pixels."""
    T = np.asarray(T_cam_from_obj, float)
    depth = np.asarray(pts_obj, float).reshape(-1, 3) @ T[2, :3] + T[2, 3]
    if np.any(depth <= 0):
        return f"{what} would be behind the camera"
    return f"reprojection RMS {rms:.1f} px > {max_reproj_px} px" if rms > max_reproj_px else ""


def covariance_cam_from_obj(obj_pts: ArrayLike, rvec: ArrayLike, tvec: ArrayLike, residuals: ArrayLike,
                            focal_px: float) -> np.ndarray:
    """(6, 6) covariance of OpenCV's (rvec rad, tvec mm) of ``T_cam_from_obj`` from a least-squares
    fit: ``sigma^2 (J^T J)^-1`` with ``J`` the projection Jacobian at the inliers ``obj_pts`` (N, 3)
    and ``sigma`` the residuals' (N, 2) standard deviation (``2N - 6`` degrees of freedom), at least
    ``SIGMA_FLOOR_PX``. Infinite when the points do not fix the pose."""
    r = np.asarray(residuals, float)
    sigma = max(np.sqrt(np.sum(r**2) / max(2 * len(r) - 6, 1)), SIGMA_FLOOR_PX / focal_px)
    _, J = cv2.projectPoints(np.asarray(obj_pts, float), rvec, tvec, np.eye(3), None)
    J = J[:, :6]
    try:
        return np.linalg.inv(J.T @ J) * sigma**2
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)


def world_pose_jacobian(rvec: ArrayLike, tvec: ArrayLike, T_world_from_obj: ArrayLike | None = None) -> np.ndarray:
    """(6, 6) Jacobian of (rotation vector, translation mm) of ``T_world_from_cam =
    T_world_from_obj @ inv(T_cam_from_obj)`` with respect to (rvec, tvec) of ``T_cam_from_obj``.

    With ``R = R(r)``: ``R_wc = R_wo R^T`` and ``t_wc = -R_wo R^T t + t_wo``; the rotation part goes
    through OpenCV's Rodrigues Jacobians (of ``R(r)`` and of the rotation vector of ``R_wc``).
    ``T_world_from_obj`` defaults to the identity (the object frame is the world).
    """
    T_wo = np.eye(4) if T_world_from_obj is None else np.asarray(T_world_from_obj, float)
    R_wo = T_wo[:3, :3]
    R, dR = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))
    dR = dR.reshape(3, 3, 3)                                     # [k, j, i] = dR[j, i] / dr_k
    t = np.asarray(tvec, float).ravel()
    R_wc = R_wo @ R.T
    _, dlog = cv2.Rodrigues(R_wc)                                # (9, 3): d rvec_wc[m] / d R_wc (row-major)
    dRwc = np.einsum("ac,kbc->abk", R_wo, dR).reshape(9, 3)      # d R_wc[a, b] / dr_k
    A = np.zeros((6, 6))
    A[:3, :3] = dlog.T @ dRwc
    A[3:, :3] = -R_wo @ np.einsum("kji,j->ik", dR, t)           # -R_wo (dR/dr_k)^T t
    A[3:, 3:] = -R_wc
    return A


def covariance_world_from_cam(cov_cam_from_obj: ArrayLike, rvec: ArrayLike, tvec: ArrayLike,
                              T_world_from_obj: ArrayLike | None = None) -> np.ndarray:
    """The (6, 6) covariance of (rvec, tvec) of ``T_cam_from_obj`` propagated (first order) to
    (rotation vector rad, translation mm) of ``T_world_from_cam = T_world_from_obj @
    inv(T_cam_from_obj)``, the pose a result carries: the translation block is the covariance of the
    camera's position in the world, mm^2. Infinite stays infinite (a pose the points do not fix)."""
    C = np.asarray(cov_cam_from_obj, float)
    if not np.all(np.isfinite(C)):
        return np.full((6, 6), np.inf)
    A = world_pose_jacobian(rvec, tvec, T_world_from_obj)
    return A @ C @ A.T


def pose_covariance(obj_pts: ArrayLike, rvec: ArrayLike, tvec: ArrayLike, residuals: ArrayLike, focal_px: float,
                    T_world_from_obj: ArrayLike | None = None) -> np.ndarray:
    """The covariance a ``PoseResult`` carries: ``covariance_cam_from_obj`` of the fit (inliers
    ``obj_pts`` (N, 3) mm, ``residuals`` (N, 2) normalised) propagated to ``T_world_from_cam`` by
    ``covariance_world_from_cam``; (6, 6), (rotation vector rad, camera position mm)."""
    return covariance_world_from_cam(covariance_cam_from_obj(obj_pts, rvec, tvec, residuals, focal_px), rvec, tvec,
                                     T_world_from_obj)
