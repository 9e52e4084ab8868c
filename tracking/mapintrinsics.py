"""A marker map's camera intrinsics refined from its survey (docs/tracking.md, "Building a map"):
fx, fy, cx, cy and the distortion coefficients (``PINHOLE``, ``FISHEYE``) adjusted jointly with
every view and marker pose (bundle adjustment on the corners' pixel reprojection,
``tracking.bundle`` with the intrinsics as parameters every observation shares; COLMAP refines
its cameras so), when the
survey holds enough views whose corners cover the image (``refinable``). A calibration from
few board views is rough (8 views of the simulated board: fx 1 px and the principal point 0.7 px
off), and the map absorbs what is left of it: its markers bend out of place by millimetres and
some are flagged as moved (docs/tracking.md has the figures).

World frame: the map's (the origin marker's), mm; views ``T_cam_from_world`` (4, 4); corners in
pixels, as detected (distorted).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from .bundle import BundleResult, bundle_adjust
from .mapadjust import HUBER_PX, MAX_ITER, adjustment_problem, camera_corners, pack_pose, unpack_poses

log = logging.getLogger(__name__)

PINHOLE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
FISHEYE = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")
"""The intrinsics refined: the focal lengths, the principal point and the first five distortion
coefficients of OpenCV's pinhole model (radial k1, k2, k3, tangential p1, p2; further ones, a
rational or thin-prism model's, are kept as calibrated), or the four of its fisheye model. With
k1, k2 alone refined, the 8-view calibration's p1 (2e-4 instead of 0) held the refined cy 1 px
off and the map's corners 3 times as far from the truth as with the true intrinsics."""
MIN_VIEWS = 20
"""Intrinsics are refined only from at least this many posed views..."""
GRID = 4
MIN_CELLS = 12
"""... whose marker corners fall in at least ``MIN_CELLS`` of the ``GRID`` x ``GRID`` cells of the
image (the image's corners and edges, where distortion is strongest, among them)."""
MAX_FOCAL_SD = 0.002
"""And the refined focal lengths are kept only when the survey fixes them to within this
fraction (standard deviation over the focal length; 0.2 %, 1 px at 480 px): else the views do not
pin the intrinsics down and the calibration's are kept."""


@dataclass
class IntrinsicsRefinement:
    """The camera intrinsics a map was built with.

    Attributes:
        camera_matrix, dist_coeffs: (3, 3), (k,) the intrinsics the map used (refined, or the
            given ones when ``refined`` is False).
        given_camera_matrix, given_dist_coeffs: the calibration's, as given.
        refined: whether the survey refined them. reason: why not ('' when refined).
        n_views: posed views. cells: image cells (of ``GRID`` x ``GRID``) their corners cover.
        sd: {name (``refined_names``): standard deviation (px for fx, fy, cx, cy)} of the
            refined values, or {} when not refined.
        model: the lens model, 'pinhole' or 'fisheye'.
        start: where the intrinsics the refinement started from came from ('calibration', or
            the caller's word: 'extended map').
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    given_camera_matrix: np.ndarray
    given_dist_coeffs: np.ndarray
    refined: bool
    reason: str
    n_views: int
    cells: int
    sd: dict
    model: str = "pinhole"
    start: str = "calibration"

    def values(self, given: bool = False) -> dict:
        """{name (``refined_names``): value} of the intrinsics used (``given``: the calibration's)."""
        return intrinsics_values(self.given_camera_matrix if given else self.camera_matrix,
                                 self.given_dist_coeffs if given else self.dist_coeffs, self.model)

    def change(self) -> dict:
        """{name (``refined_names``): refined minus given} (all 0 when not refined)."""
        a, b = self.values(True), self.values()
        return {k: b[k] - a[k] for k in a}


def refined_names(model: str) -> tuple:
    """The names of the intrinsics refined for a lens model ('pinhole': ``PINHOLE``, 'fisheye':
    ``FISHEYE``), in the order of the adjustment's parameters."""
    return FISHEYE if model == "fisheye" else PINHOLE


def intrinsics_values(K: np.ndarray, dist, model: str = "pinhole") -> dict:
    """{fx, fy, cx, cy (px), then the distortion coefficients by name} (``refined_names``) of a
    camera matrix (3, 3) and distortion coefficients (missing ones 0)."""
    names = refined_names(model)
    d = np.concatenate([np.ravel(dist), np.zeros(len(names))])
    return dict(zip(names, [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                            *map(float, d[:len(names) - 4])], strict=True))


def coverage(views_px, keys, image_size) -> int:
    """How many cells of a ``GRID`` x ``GRID`` partition of the image (width, height) px hold a
    marker corner of the views ``keys`` of ``views_px`` ({id: (4, 2) px} per view)."""
    w, h = image_size
    pts = [np.asarray(c, float).reshape(-1, 2) for k in keys for c in views_px[k].values()]
    if not pts:
        return 0
    ij = np.clip((np.concatenate(pts) / [w, h] * GRID).astype(int), 0, GRID - 1)
    return len(set(map(tuple, ij)))


def refinable(n_views: int, cells: int) -> str:
    """Why a survey of ``n_views`` posed views covering ``cells`` image cells cannot refine the
    intrinsics, or '' when it can (``MIN_VIEWS``, ``MIN_CELLS``)."""
    if n_views < MIN_VIEWS:
        return f"{n_views} posed views (the intrinsics are refined from {MIN_VIEWS} or more)"
    if cells < MIN_CELLS:
        return (f"the markers' corners cover {cells} of the image's {GRID * GRID} cells (the intrinsics are "
                f"refined when they cover {MIN_CELLS} or more: survey with markers near the image's edges too)")
    return ""


def _camera(g, K0, dist0, scale: float):
    """(K (3, 3), dist) of the shared parameters ``g`` (fx, fy, cx, cy over ``scale``, then the
    first distortion coefficients; the others as ``dist0``)."""
    K = np.array([[g[0] * scale, 0.0, g[2] * scale], [0.0, g[1] * scale, g[3] * scale], [0.0, 0.0, 1.0]])
    K[0, 1] = K0[0, 1]
    d = np.array(dist0, float).copy()
    d[:len(g) - 4] = g[4:]
    return K, d


def _pixels(Xc, K, dist, model: str) -> np.ndarray:
    """(n, 4, 2) pixels of camera-frame points ``Xc`` (n, 4, 3), mm (OpenCV's projection)."""
    p = np.ascontiguousarray(Xc.reshape(-1, 1, 3))
    if model == "fisheye":
        px, _ = cv2.fisheye.projectPoints(p, np.zeros((3, 1)), np.zeros((3, 1)), K, dist)
    else:
        px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, dist)
    return px.reshape(Xc.shape[:-1] + (2,))


def refine_intrinsics(views_px, size, origin, markers, cams, K, dist, model: str, image_size=None,
                      T_origin=None) -> tuple[IntrinsicsRefinement, dict, dict]:
    """The intrinsics (``refined_names``) adjusted with every posed view and placed marker but the
    origin (which stays at ``T_origin``, default its pose in ``markers``), when the survey can
    (``refinable``, then ``MAX_FOCAL_SD``).

    Args:
        views_px: per view {marker id: (4, 2) corners, px, as detected}.
        size: {id: printed side, mm}. markers: {id: T_world_from_marker (4, 4)}; cams: {view:
            T_cam_from_world (4, 4)}: the starting poses (from the given intrinsics).
        K, dist, model: the calibration's camera matrix (3, 3), distortion coefficients and lens
            model ('pinhole' or 'fisheye').
        image_size: (width, height) px; default (2 cx + 1, 2 cy + 1).

    Returns:
        (the ``IntrinsicsRefinement``, markers, cams): the adjusted poses when refined, else
        those given.
    """
    K, dist = np.asarray(K, float), np.asarray(dist, float).ravel()
    names = refined_names(model)
    d0 = np.concatenate([dist, np.zeros(max(len(names) - 4 - len(dist), 0))])
    image_size = image_size or (2 * K[0, 2] + 1, 2 * K[1, 2] + 1)
    n_cells = coverage(views_px, list(cams), image_size)
    why = refinable(len(cams), n_cells)

    def kept(reason: str) -> tuple[IntrinsicsRefinement, dict, dict]:
        log.info("camera intrinsics not refined: %s", reason)
        return IntrinsicsRefinement(K, dist, K, dist, False, reason, len(cams), n_cells, {}, model=model), \
            markers, cams
    if why:
        return kept(why)
    T_origin = markers[origin] if T_origin is None else T_origin
    prob = adjustment_problem(views_px, size, origin, markers, cams, T_origin)
    scale = float(K[0, 0])
    fit = _adjust(prob, markers, cams, K, d0, model, len(names) - 4)
    sd = _shared_sd(fit, scale, names)
    K1, d1 = _camera(fit.shared, K, d0, scale)
    d1 = d1[:len(dist)] if len(dist) >= len(names) - 4 else d1
    worst = max(sd["fx"] / K1[0, 0], sd["fy"] / K1[1, 1])
    if not worst <= MAX_FOCAL_SD:
        return kept(f"the survey fixes the focal length to {100 * worst:.2f} % (sd), not to "
                    f"{100 * MAX_FOCAL_SD:g} %")
    cams1, markers1 = unpack_poses(np.concatenate([fit.views.ravel(), fit.objects.ravel()]), prob["cam_keys"],
                                   prob["marker_keys"])
    markers1[origin] = T_origin
    markers1.update({i: T for i, T in markers.items() if i not in markers1})
    log.info("camera intrinsics refined from %d views: fx %.2f -> %.2f, fy %.2f -> %.2f, cx %.2f -> %.2f, "
             "cy %.2f -> %.2f px", len(cams), K[0, 0], K1[0, 0], K[1, 1], K1[1, 1], K[0, 2], K1[0, 2], K[1, 2],
             K1[1, 2])
    return (IntrinsicsRefinement(K1, d1, K, dist, True, "", len(cams), n_cells, sd, model),
            markers1, cams1)


def _adjust(prob: dict, markers: dict, cams: dict, K: np.ndarray, d0: np.ndarray, model: str,
            n_dist: int) -> BundleResult:
    """The bundle adjustment of ``refine_intrinsics``: the views and markers of ``prob``
    (``mapadjust.adjustment_problem``) with the intrinsics shared by all views (fx, fy, cx, cy
    in units of the start's fx, then the first ``n_dist`` distortion coefficients), from
    ``cams``, ``markers``, ``K`` and ``d0``."""
    prob["seen"] = prob["seen"].astype(float)
    scale = float(K[0, 0])

    def fun(v, o, g):
        Kg, dg = _camera(g, K, d0, scale)
        Xc = camera_corners(v, o, prob)
        r = (_pixels(Xc, Kg, dg, model) - prob["seen"]).reshape(-1, 8)
        in_front = np.logical_and.reduce(Xc[..., 2] > 0, axis=1)
        return np.where(in_front[:, None], r, np.inf)
    g0 = np.concatenate([[K[0, 0] / scale, K[1, 1] / scale, K[0, 2] / scale, K[1, 2] / scale],
                         d0[:n_dist]])
    views0 = np.array([pack_pose(cams[k]) for k in prob["cam_keys"]])
    objs0 = np.array([pack_pose(markers[i]) for i in prob["marker_keys"]]).reshape(-1, 6)
    return bundle_adjust(fun, views0, objs0, prob["cam"], prob["marker"], HUBER_PX, MAX_ITER,
                         shared=g0)


def _shared_sd(fit, scale: float, names) -> dict:
    """{name (``names``): sd} of the shared parameters of a ``BundleResult``: the inverse of
    their information (views marginalised, markers too) times the residuals' mean square per
    degree of freedom; fx, fy, cx, cy in px."""
    n_par = fit.views.size + fit.objects.size + fit.shared.size
    dof = max(fit.residuals.size - n_par, 1)
    C = np.linalg.pinv(fit.information) * float(np.sum(fit.residuals ** 2)) / dof
    v = np.sqrt(np.clip(np.diag(C)[-len(names):], 0, None)) * np.array([scale] * 4 + [1.0] * (len(names) - 4))
    return dict(zip(names, v.tolist(), strict=True))
