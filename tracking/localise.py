"""Head pose without markers (issue 16; docs/tracking.md, "A map without markers"): a scene
frame's SIFT features matched to the 3D points of a structure-from-motion map of the room, then
the camera's pose from those 2D-3D matches (pycolmap's LO-RANSAC absolute pose and refinement).

The same features serve the map and the frames (``image_features``): SIFT on the frame at half
size (OpenCV's SIFT doubles its input first, so half size is full detail without the doubling's
fourfold cost), RootSIFT-normalised. The map is built from them by pycolmap
(``wearable_gaze.pipeline.maps.sfm``) and carries, for each of its 3D points, the descriptor of every
view that saw it (``FeatureMap``).

Frames: the map's points are in the world frame (mm) that the map was scaled and placed in; the
pose returned is ``T_world_from_cam`` with the covariance of (rotation vector rad, translation mm)
beside it, in the parameters the marker solver uses (``tracking.pnp.pose_covariance``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import ArrayLike

from calibration.camera import CameraCalibration
from estimator.deprecation import module_getattr, renamed_kwargs
from estimator.frames import invert

from .pnp import pose_covariance, pose_fault, reprojection_residuals, rms_px
from .pose import OK, REJECTED, TOO_FEW, PoseResult

log = logging.getLogger(__name__)

FEATURE_SCALE = 0.5
"""Frames are reduced to this scale before SIFT (see the module's docstring)."""
MAX_FEATURES = 2000
"""SIFT keeps at most this many features a frame (the strongest)."""
QUERY_SCALE = 0.25
"""Frames to localise are reduced to this scale first (a quarter the SIFT time of
``FEATURE_SCALE``, matching the map's features across the scale change; measured on the
simulated walkabout: 0.07 deg and 5 mm median against 0.04 deg and 4 mm, benchmarks/bench_sfm.py);
a frame that fails at it is tried again at ``FEATURE_SCALE``."""
QUERY_FEATURES = 1000
"""SIFT keeps at most this many features of a frame to localise."""
RATIO = 0.8
"""Lowe's ratio test: a match is kept when its distance is below this times the distance to the
nearest descriptor of another 3D point."""


@renamed_kwargs({"grey": "gray"})
def image_features(gray: ArrayLike, max_features: int = MAX_FEATURES, scale: float = FEATURE_SCALE
                   ) -> tuple[np.ndarray, np.ndarray]:
    """SIFT features of one frame: positions (N, 2) in the frame's own pixels (OpenCV's
    convention, the first pixel's centre at 0, 0) and RootSIFT descriptors (N, 128) float32 of unit
    length. ``gray``: (H, W) uint8."""
    g = np.asarray(gray)
    if g.ndim != 2 or g.dtype != np.uint8:
        raise ValueError(f"grey must be an (H, W) uint8 image, got {g.shape} {g.dtype}")
    small = g if scale == 1 else cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    kps, desc = cv2.SIFT.create(nfeatures=max_features).detectAndCompute(small, None)
    if desc is None or not kps:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    xy = (np.array([k.pt for k in kps], float) + 0.5) / scale - 0.5
    return xy, root_sift(desc)


def root_sift(desc: ArrayLike) -> np.ndarray:
    """RootSIFT (Arandjelovic and Zisserman 2012): the square root of the L1-normalised SIFT
    descriptors (N, 128), float32 of unit L2 length; compared by Euclidean distance it is the
    Hellinger kernel, which matches better than SIFT's own."""
    d = np.asarray(desc, np.float32)
    d = d / np.maximum(d.sum(axis=1, keepdims=True), 1e-12)
    return np.sqrt(d)


def colmap_descriptors(desc: ArrayLike) -> np.ndarray:
    """Unit descriptors (N, 128) as COLMAP stores them: uint8 of 512 times each element."""
    return np.clip(np.round(np.asarray(desc, np.float32) * 512), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class FeatureMap:
    """A room's 3D points and the descriptors they were seen with.

    Attributes:
        points_world: (P, 3) the points, world frame, mm.
        descriptors: (M, 128) float32 unit RootSIFT descriptors, one per view of a point.
        point_of: (M,) int the point (row of ``points_world``) each descriptor belongs to.
    """

    points_world: np.ndarray
    descriptors: np.ndarray
    point_of: np.ndarray

    def __post_init__(self) -> None:
        P, D, idx = (np.asarray(self.points_world, float), np.asarray(self.descriptors, np.float32),
                     np.asarray(self.point_of, np.int64))
        if P.ndim != 2 or P.shape[1] != 3:
            raise ValueError(f"points_world must be (P, 3), got {P.shape}")
        if D.ndim != 2 or D.shape[1] != 128 or idx.shape != (len(D),):
            raise ValueError(f"descriptors must be (M, 128) with point_of (M,), got {D.shape} and {idx.shape}")
        if len(idx) and (idx.min() < 0 or idx.max() >= len(P)):
            raise ValueError(f"point_of must index the {len(P)} points")
        object.__setattr__(self, "points_world", P)
        object.__setattr__(self, "descriptors", np.ascontiguousarray(D))
        object.__setattr__(self, "point_of", idx)


class FeatureLocalizer:
    """The pose of a frame from its features matched to a ``FeatureMap``.

    Args:
        feature_map: the room.
        camera: the scene camera's intrinsics and distortion.
        ransac_px: the absolute pose's RANSAC inlier threshold, pixels.
        min_inliers: fewest inlier matches accepted.
        max_reproj_px: a pose whose inlier RMS exceeds this is rejected.
        checks: FLANN's leaves searched per query (more: slower, more matches found).
        scale: frames are reduced to this scale for their features (``QUERY_SCALE``); one that
            fails is tried again at ``FEATURE_SCALE``, the map's own.
    """

    def __init__(self, feature_map: FeatureMap, camera: CameraCalibration, ransac_px: float = 3.0,
                 min_inliers: int = 30, max_reproj_px: float = 2.0, checks: int = 24, scale: float = QUERY_SCALE):
        if len(feature_map.descriptors) < min_inliers:
            raise ValueError(f"the map has {len(feature_map.descriptors)} descriptors, fewer than the "
                             f"{min_inliers} matches a pose needs")
        self.map = feature_map
        self.camera = camera
        self.f = float(camera.camera_matrix[0, 0])
        self.ransac_px, self.min_inliers, self.max_reproj_px = ransac_px, min_inliers, max_reproj_px
        self._index = cv2.flann.Index(feature_map.descriptors, {"algorithm": 1, "trees": 4})
        self._checks = checks
        self.scales = (scale,) if scale == FEATURE_SCALE else (scale, FEATURE_SCALE)
        import pycolmap  # made once: pose() runs on every frame

        w, h = (int(v) for v in camera.image_size)
        self._pinhole = pycolmap.Camera(model="PINHOLE", width=w, height=h, params=[self.f, self.f, 0.0, 0.0])
        self._options = pycolmap.AbsolutePoseEstimationOptions()
        self._options.ransac.max_error = ransac_px
        self._options.ransac.random_seed = 0

    def matches(self, desc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(query rows (K,), map points (K,)) of descriptors (N, 128) that pass the ratio test
        against the nearest descriptor of another point; each map point kept once (its best)."""
        d = np.ascontiguousarray(desc, np.float32)
        if len(d) == 0:
            return np.zeros(0, int), np.zeros(0, int)
        k = min(4, len(self.map.descriptors))
        nn, dist2 = self._index.knnSearch(d, k, params={"checks": self._checks})
        pts = self.map.point_of[nn]
        other = pts != pts[:, :1]                       # neighbours of another point than the nearest's
        has = other.any(axis=1)
        second = np.where(has, dist2[np.arange(len(d)), np.argmax(other, axis=1)], np.inf)
        keep = dist2[:, 0] < RATIO**2 * second
        q, p, score = np.flatnonzero(keep), pts[keep, 0], dist2[keep, 0]
        order = np.lexsort((score, p))                  # by point, best first
        first = np.ones(len(p), bool)
        first[1:] = p[order][1:] != p[order][:-1]
        return q[order][first], p[order][first]

    @renamed_kwargs({"grey": "gray"})
    def estimate(self, gray: ArrayLike) -> PoseResult:
        """The pose of one frame, (H, W) uint8, distorted as the camera takes it: from its
        features at ``scales[0]``, or, when that fails, at ``scales[1]``."""
        for scale in self.scales:
            xy, desc = image_features(gray, QUERY_FEATURES if scale == self.scales[0] else MAX_FEATURES, scale)
            q, p = self.matches(desc)
            if len(q) < self.min_inliers:
                res = PoseResult(None, TOO_FEW, f"{len(q)} features matched to the map, need {self.min_inliers}",
                                 n_points=len(q))
                continue
            res = self.pose(xy[q], self.map.points_world[p])
            if res.ok:
                break
        return res

    def pose(self, px: np.ndarray, pts_world: np.ndarray) -> PoseResult:
        """Pose from matched distorted pixels (K, 2) and world points (K, 3) mm."""
        import pycolmap

        x = self.camera.undistort_points(px)
        r = pycolmap.estimate_and_refine_absolute_pose(x * self.f, pts_world, self._pinhole, self._options)
        if r is None:
            return PoseResult(None, REJECTED, "no consistent pose from the matched features", n_points=len(x))
        T_cw = np.eye(4)
        T_cw[:3] = r["cam_from_world"].matrix()
        inl = np.asarray(r["inlier_mask"], bool)
        n = int(inl.sum())
        rvec, tvec = cv2.Rodrigues(T_cw[:3, :3])[0], T_cw[:3, 3].copy()
        res = reprojection_residuals(pts_world[inl], x[inl], rvec, tvec)
        rms = rms_px(res, self.f) if n else float("inf")
        why = (f"{n} inlier matches, need {self.min_inliers}" if n < self.min_inliers else
               pose_fault(T_cw, pts_world[inl], rms, self.max_reproj_px, "a matched point"))
        if why:
            log.debug("feature pose rejected: %s", why)
            return PoseResult(None, REJECTED, why, n_points=n, reproj_rms_px=rms)
        cov = pose_covariance(pts_world[inl], rvec, tvec, res, self.f)
        return PoseResult(invert(T_cw), OK, "", n_points=n, reproj_rms_px=rms, covariance=cov)


def triangulate(T_cam_from_world: ArrayLike, x_norm: ArrayLike) -> np.ndarray:
    """The point (3,) whose projections best fit its undistorted normalised observations
    ``x_norm`` (V, 2) in V >= 2 views posed by ``T_cam_from_world`` (V, 4, 4) (linear DLT, each
    row scaled by the view's depth estimate once, so every view weighs as its image error)."""
    T = np.asarray(T_cam_from_world, float).reshape(-1, 4, 4)
    x = np.asarray(x_norm, float).reshape(-1, 2)
    if len(T) < 2 or len(T) != len(x):
        raise ValueError(f"need the same number (>= 2) of views and observations, got {len(T)} and {len(x)}")
    P = T[:, :3, :]
    w = np.ones(len(T))
    for _ in range(2):
        A = np.concatenate([(x[:, :1] * P[:, 2] - P[:, 0]) / w[:, None],
                            (x[:, 1:] * P[:, 2] - P[:, 1]) / w[:, None]])
        X = np.linalg.svd(A)[2][-1]
        X = X[:3] / X[3]
        w = np.maximum(P[:, 2, :3] @ X + P[:, 2, 3], 1e-9)
    return X


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"FeatureLocaliser": "FeatureLocalizer"})
