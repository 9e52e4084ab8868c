"""Eye calibration: the paper's second-order polynomial (eq. 1-2) from raw eye readings to the
calibration plane, the wall's pose from reference points (no perpendicular wall needed), the
eye rotation centres from two wall distances, and view lines from raw samples (eq. 1-4).

Model. For one eye with rotation centre ``e_c`` (scene-camera frame, mm), a raw reading
``r = (x, y)`` maps to the point ``q`` of the undistorted image (normalised coordinates, i.e.
``K^-1 [u, v, 1]``) by eq. 1-2,

    q = C m(r),   m(r) = (1, x, y, x^2, x y, y^2)      (C: 2 x 6)

and ``p_c = l_c (q, 1)`` (eq. 3) is the gazed point on the calibration plane ``z = l_c``; the view
line runs from ``e_c`` through ``p_c`` (eq. 4). Calibration fits ``C`` by least squares to the
targets: for a target at a known 3D position ``P`` (from the wall's measured pose), ``q`` is where
the line from ``e_c`` through ``P`` meets ``z = l_c``: a tilted wall is corrected exactly. Raw
readings are centred and scaled before fitting (conditioning only).

Units: mm, degrees in reports; directions in the scene-camera frame (OpenCV axes).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import RBFInterpolator
from scipy.optimize import least_squares

from estimator import ViewLines
from estimator._checks import check_points, check_same_rows, check_vector
from estimator.deprecation import module_getattr, renamed_kwargs

log = logging.getLogger(__name__)

MIN_TARGETS = 6
MODELS = ("quadratic", "cubic", "tps")


class CalibrationError(ValueError):
    """A calibration that cannot be made: the message says what to redo."""


def _monomials(r: np.ndarray, order: int) -> np.ndarray:
    x, y = r[:, 0], r[:, 1]
    cols = [np.ones_like(x)]
    for d in range(1, order + 1):
        for k in range(d + 1):
            cols.append(x ** (d - k) * y ** k)
    return np.column_stack(cols)


@renamed_kwargs({"centre": "center"})
@dataclass
class RawMap:
    """Raw reading (N, 2) -> normalised image point q (N, 2): a polynomial (eq. 1-2 for order 2)
    or a thin-plate spline on top of the quadratic.

    Attributes:
        model: 'quadratic', 'cubic' or 'tps'.
        center, scale: raw normalisation, ``(r - centre) / scale``.
        coef: (n_terms, 2) polynomial coefficients on normalised raw.
        tps: for 'tps', (nodes (K, 2), weights (K, 2), smoothing) of the residual spline.
    """

    model: str
    center: np.ndarray
    scale: float
    coef: np.ndarray
    tps: tuple | None = None

    def __call__(self, raw: ArrayLike) -> np.ndarray:
        r = (check_points(raw, "raw", 2) - self.center) / self.scale
        order = 3 if self.model == "cubic" else 2
        q = _monomials(r, order) @ self.coef
        if self.tps is not None:
            nodes, vals, smooth = self.tps
            q = q + RBFInterpolator(nodes, vals, kernel="thin_plate_spline", smoothing=smooth)(r)
        return q

    def paper_coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """(a0..a5, b0..b5) of eq. 1-2 on raw counts, for normalised image coordinates
        (quadratic model only)."""
        if self.model != "quadratic":
            raise ValueError("only the quadratic model has the paper's coefficients")
        (cx, cy), s = self.center, self.scale
        # m((r - c) / s) = M m(r): rows are 1, x', y', x'^2, x'y', y'^2 in the monomials of r
        M = np.array([
            [1, 0, 0, 0, 0, 0],
            [-cx / s, 1 / s, 0, 0, 0, 0],
            [-cy / s, 0, 1 / s, 0, 0, 0],
            [cx * cx / s**2, -2 * cx / s**2, 0, 1 / s**2, 0, 0],
            [cx * cy / s**2, -cy / s**2, -cx / s**2, 0, 1 / s**2, 0],
            [cy * cy / s**2, 0, -2 * cy / s**2, 0, 0, 1 / s**2]])
        full = M.T @ self.coef
        return full[:, 0], full[:, 1]

    def to_dict(self) -> dict:
        d = {"model": self.model, "centre": self.center.tolist(), "scale": self.scale, "coef": self.coef.tolist()}
        if self.tps is not None:
            d["tps"] = {"nodes": self.tps[0].tolist(), "values": self.tps[1].tolist(), "smoothing": self.tps[2]}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RawMap:
        tps = None
        if d.get("tps"):
            tps = (np.asarray(d["tps"]["nodes"], float), np.asarray(d["tps"]["values"], float),
                   float(d["tps"]["smoothing"]))
        return cls(d["model"], np.asarray(d["centre"], float), float(d["scale"]), np.asarray(d["coef"], float), tps)


def fit_raw_map(raw: ArrayLike, q: ArrayLike, model: str = "quadratic", smoothing: float = 1e-3) -> RawMap:
    """Least-squares fit of raw (K, 2) -> q (K, 2).

    Raises:
        CalibrationError: too few targets for the model, or targets too close to a line.
    """
    raw = check_points(raw, "raw", 2)
    q = check_points(q, "q", 2)
    check_same_rows(raw, q, "raw", "q")
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    center = raw.mean(axis=0)
    scale = float(np.sqrt(((raw - center) ** 2).sum(axis=1).mean())) or 1.0
    r = (raw - center) / scale
    order = 3 if model == "cubic" else 2
    A = _monomials(r, order)
    if len(raw) < A.shape[1]:
        raise CalibrationError(f"{len(raw)} calibration targets, the {model} model needs at least {A.shape[1]}: "
                               "record more targets (normally a 3x3 grid)")
    sv = np.linalg.svd(A, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        raise CalibrationError("the eye's readings at the targets lie (nearly) on a line or conic: place the "
                               "targets in a grid spanning the field of view and record again")
    coef, *_ = np.linalg.lstsq(A, q, rcond=None)
    tps = None
    if model == "tps":
        resid = q - A @ coef
        tps = (r, resid, smoothing)
    return RawMap(model, center, scale, coef, tps)


def _angle_deg(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    d1 = d1 / np.linalg.norm(d1, axis=-1, keepdims=True)
    d2 = d2 / np.linalg.norm(d2, axis=-1, keepdims=True)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(d1, d2), axis=-1), (d1 * d2).sum(-1)))


@renamed_kwargs({"centre_mm": "center_mm"})
@dataclass
class EyeCalibration:
    """One eye's calibration.

    Attributes:
        eye: 'left' or 'right'.
        center_mm: (3,) rotation centre ``e_c``, scene-camera frame.
        plane_mm: ``l_c``, the calibration plane's distance along the optical axis.
        raw_map: raw -> q (normalised image coordinates).
        report: residuals and leave-one-out errors (see ``calibrate_eye``).
    """

    eye: str
    center_mm: np.ndarray
    plane_mm: float
    raw_map: RawMap
    report: dict = field(default_factory=dict)

    def image_points(self, raw: ArrayLike) -> np.ndarray:
        """(N, 2) normalised image points q of raw readings (N, 2) (eq. 1-2)."""
        return self.raw_map(raw)

    def directions(self, raw: ArrayLike) -> np.ndarray:
        """(N, 3) unit view directions, scene-camera frame (eq. 3-4)."""
        q = self.raw_map(raw)
        p = self.plane_mm * np.column_stack([q, np.ones(len(q))])
        d = p - self.center_mm
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def lines(self, raw: ArrayLike) -> ViewLines:
        """View lines (eq. 1-4) in the camera frame of raw readings (N, 2); the caller keeps
        invalid samples (blinks) out or marks them."""
        d = self.directions(raw)
        return ViewLines(np.broadcast_to(self.center_mm, d.shape).copy(), d, frame="cam")

    def to_dict(self) -> dict:
        d = {"eye": self.eye, "centre_mm": self.center_mm.tolist(), "plane_mm": self.plane_mm,
             "raw_map": self.raw_map.to_dict(), "report": self.report}
        if self.raw_map.model == "quadratic":
            a, b = self.raw_map.paper_coefficients()
            d["paper_eq1_a"] = a.tolist()
            d["paper_eq2_b"] = b.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> EyeCalibration:
        return cls(d["eye"], np.asarray(d["centre_mm"], float), float(d["plane_mm"]),
                   RawMap.from_dict(d["raw_map"]), d.get("report", {}))


@renamed_kwargs({"centre_mm": "center_mm"})
def plane_points(targets_cam_mm: ArrayLike, center_mm: ArrayLike, plane_mm: float) -> np.ndarray:
    """(K, 2) normalised image points q where the lines from the eye centre through the targets
    (K, 3) meet the calibration plane z = l_c (so that eq. 3-4 reproduce those lines)."""
    P = check_points(targets_cam_mm, "targets_cam_mm")
    e = check_vector(center_mm, "centre_mm")
    s = (plane_mm - e[2]) / (P[:, 2] - e[2])
    p = e + s[:, None] * (P - e)
    return p[:, :2] / plane_mm


@renamed_kwargs({"centre_mm": "center_mm"})
def calibrate_eye(eye: str, raw: ArrayLike, targets_cam_mm: ArrayLike, center_mm: ArrayLike,
                  plane_mm: float | None = None,
                  model: str = "quadratic", focal_px: float | None = None, outlier_deg: float = 1.0) -> EyeCalibration:
    """Fit one eye (paper eq. 1-2) to targets at known 3D positions.

    Args:
        eye: 'left' or 'right'.
        raw: (K, 2) the eye's raw reading at each target (a robust average over the fixation).
        targets_cam_mm: (K, 3) target positions, scene-camera frame, mm.
        center_mm: (3,) the eye's rotation centre.
        plane_mm: l_c; default the targets' median depth.
        model: 'quadratic' (the paper's), 'cubic' or 'tps' (for more than 9 targets).
        focal_px: to report residuals in pixels too.
        outlier_deg: a target is flagged when the fit to the others misses it by more than this
            and five times their own spread about that fit.

    Returns:
        the calibration, with ``report``: residual_deg (K,), rms_deg, residual_px (K,),
        loo_deg (K,), loo_rms_deg, outliers (indices).

    Raises:
        CalibrationError: fewer than 6 targets, collinear targets, missing readings.
    """
    raw = check_points(raw, "raw", 2)
    targets = check_points(targets_cam_mm, "targets_cam_mm")
    check_same_rows(raw, targets, "raw", "targets_cam_mm", "one row per target")
    center_mm = check_vector(center_mm, "centre_mm")
    idx = np.flatnonzero(_valid_readings(eye, raw))
    raw, targets = raw[idx], targets[idx]
    dirs = targets - np.asarray(center_mm, float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    _check_not_collinear(eye, targets, dirs)
    lc = float(np.median(targets[:, 2])) if plane_mm is None else float(plane_mm)
    center = np.asarray(center_mm, float)
    q = plane_points(targets, center, lc)
    raw_map = fit_raw_map(raw, q, model)
    cal = EyeCalibration(eye, center, lc, raw_map)
    res = _angle_deg(cal.directions(raw), dirs)
    loo, rest_rms = _leave_one_out(cal, raw, q, dirs, model)
    outliers = [int(idx[k]) for k in range(len(raw))
                if np.isfinite(loo[k]) and loo[k] > max(outlier_deg, 5 * rest_rms[k])]
    report = {"n_targets": int(len(raw)), "model": model, "residual_deg": res.tolist(),
              "rms_deg": float(np.sqrt(np.mean(res**2))), "loo_deg": loo.tolist(),
              "loo_rms_deg": float(np.sqrt(np.nanmean(loo**2))) if np.isfinite(loo).any() else None,
              "outliers": outliers, "targets_used": idx.tolist()}
    if focal_px:
        report["residual_px"] = (focal_px * np.linalg.norm(raw_map(raw) - q, axis=1)).tolist()
    cal.report = report
    loo_text = "-" if report["loo_rms_deg"] is None else f"{report['loo_rms_deg']:.3f}"
    log.info("%s eye (%s): %d targets, RMS %.3f deg, leave-one-out RMS %s deg, outliers %s",
             eye, model, len(raw), report["rms_deg"], loo_text, outliers)
    return cal


def _valid_readings(eye: str, raw: np.ndarray) -> np.ndarray:
    """(K,) bool: the targets with a finite reading; CalibrationError when fewer than
    ``MIN_TARGETS``."""
    ok = np.all(np.isfinite(raw), axis=1)
    if not ok.any():
        raise CalibrationError(f"no valid {eye}-eye readings at any target: check the {eye} eye's "
                               "sensor and record the calibration again")
    if ok.sum() < MIN_TARGETS:
        raise CalibrationError(f"{eye} eye: valid readings at {ok.sum()} targets, need at least "
                               f"{MIN_TARGETS}: record the calibration again and keep the eyes "
                               "open on each target")
    return ok


def _check_not_collinear(eye: str, targets: np.ndarray, dirs: np.ndarray) -> None:
    """CalibrationError when the targets (K, 3) mm, or their directions (K, 3) from the eye, lie
    on a line."""
    slopes = dirs[:, :2] / dirs[:, 2:3]
    sv = np.linalg.svd(slopes - slopes.mean(axis=0), compute_uv=False)
    spread = targets - targets.mean(axis=0)
    if sv[-1] < 1e-3 * max(sv[0], 1e-12) or np.linalg.svd(spread, compute_uv=False)[1] < 1e-6:
        raise CalibrationError(f"{eye} eye: the targets are collinear as seen from the eye: place "
                               "them in a grid (3x3) spanning the field of view and record again")


def _leave_one_out(cal: EyeCalibration, raw: np.ndarray, q: np.ndarray, dirs: np.ndarray,
                   model: str) -> tuple[np.ndarray, np.ndarray]:
    """Each target predicted by the fit to the others: its angular miss (K,) deg and the RMS of
    the others about their own fit (K,) deg (NaN where that fit is not possible): an outlier
    disagrees with the others, which agree without it."""
    loo = np.full(len(raw), np.nan)
    rest_rms = np.full(len(raw), np.nan)
    if len(raw) <= cal.raw_map.coef.shape[0]:
        return loo, rest_rms
    for k in range(len(raw)):
        keep = np.arange(len(raw)) != k
        try:
            fit = fit_raw_map(raw[keep], q[keep], model)
        except CalibrationError:
            continue
        sub = EyeCalibration(cal.eye, cal.center_mm, cal.plane_mm, fit)
        loo[k] = _angle_deg(sub.directions(raw[k:k + 1]), dirs[k:k + 1])[0]
        rest = _angle_deg(sub.directions(raw[keep]), dirs[keep])
        rest_rms[k] = float(np.sqrt(np.mean(rest**2)))
    return loo, rest_rms


@renamed_kwargs({"centre_mm": "center_mm"})
def compare_models(eye: str, raw: ArrayLike, targets_cam_mm: np.ndarray, center_mm: np.ndarray,
                   plane_mm: float | None = None) -> dict:
    """Leave-one-out RMS (deg) of each model the target count allows: does a richer model
    generalise better than the paper's quadratic?"""
    out = {}
    for model in MODELS:
        try:
            cal = calibrate_eye(eye, raw, targets_cam_mm, center_mm, plane_mm, model)
        except CalibrationError:
            continue
        if cal.report["loo_rms_deg"] is not None:
            out[model] = cal.report["loo_rms_deg"]
    return out


# --- the wall ----------------------------------------------------------------------------------

@dataclass
class WallPose:
    """The calibration wall measured from reference points.

    Attributes:
        T_cam_from_wall: (4, 4) wall frame (x right, y down, z into the wall) in the camera frame.
        tilt_deg: angle between the wall's normal and the optical axis.
        rms_px: reprojection RMS of the reference points (normalised coords x focal if given).
    """

    T_cam_from_wall: np.ndarray
    tilt_deg: float
    rms: float

    def to_camera(self, pts_wall_mm: ArrayLike) -> np.ndarray:
        """(N, 2) wall points -> (N, 3) camera-frame points, mm."""
        p = check_points(pts_wall_mm, "pts_wall_mm", 2)
        return p @ self.T_cam_from_wall[:3, :2].T + self.T_cam_from_wall[:3, 3]


def wall_pose(points_wall_mm: ArrayLike, points_norm: ArrayLike) -> WallPose:
    """The wall's pose from reference points on it.

    Args:
        points_wall_mm: (N, 2) N >= 4 reference points in the wall frame, mm (marker corners
            or measured marks), not all collinear.
        points_norm: (N, 2) their undistorted normalised image coordinates.

    Uses the planar homography (IPPE, ``cv2.SOLVEPNP_IPPE``) refined by Levenberg-Marquardt.
    """
    W = check_points(points_wall_mm, "points_wall_mm", 2)
    x = check_points(points_norm, "points_norm", 2)
    check_same_rows(W, x, "points_wall_mm", "points_norm")
    if len(W) < 4:
        raise CalibrationError(f"{len(W)} reference points on the wall, need 4: make the wall's markers visible")
    obj = np.column_stack([W, np.zeros(len(W))])
    ok, rvec, tvec = cv2.solvePnP(obj, x, np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError("the wall's pose could not be found from its reference points")
    rvec, tvec = cv2.solvePnPRefineLM(obj, x, np.eye(3), None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, tvec.ravel()
    proj = obj @ R.T + tvec.ravel()
    rms = float(np.sqrt(np.mean(np.sum((proj[:, :2] / proj[:, 2:3] - x) ** 2, axis=1))))
    tilt = float(np.degrees(np.arccos(min(abs(R[2, 2]), 1.0))))
    return WallPose(T, tilt, rms)


# --- eye centres from two distances ----------------------------------------------------------

def estimate_center(raw: ArrayLike, targets_cam_mm: ArrayLike, initial_mm: ArrayLike,
                    model: str = "quadratic") -> tuple[np.ndarray, np.ndarray]:
    """One eye's rotation centre from targets at two or more depths.

    Seen from the true centre, one raw reading points at targets at every depth along one line;
    with targets at a single depth any centre fits equally. The centre and the eye's map
    (raw -> direction tangent, the same family as eq. 1-4) are fitted jointly by least squares
    on angular residuals.

    Args:
        raw: (K, 2) readings at the targets.
        targets_cam_mm: (K, 3) targets, scene-camera frame, spanning >= 2 depths.
        initial_mm: (3,) starting point (a nominal headset geometry).

    Returns:
        centre (3,) mm and its (3, 3) covariance, mm^2 (from the residual spread).
    """
    raw = check_points(raw, "raw", 2)
    P = check_points(targets_cam_mm, "targets_cam_mm")
    check_same_rows(raw, P, "raw", "targets_cam_mm", "one row per target")
    check_vector(initial_mm, "initial_mm")
    z = P[:, 2]
    if np.ptp(z) < 0.2 * np.median(z):
        raise CalibrationError("the eye centres need calibration targets at two wall distances (e.g. 1 m and "
                               "2 m); these are all at one distance")
    center = raw.mean(axis=0)
    scale = float(np.sqrt(((raw - center) ** 2).sum(axis=1).mean())) or 1.0
    A = _monomials((raw - center) / scale, 3 if model == "cubic" else 2)
    n = A.shape[1]

    def tangents(e: np.ndarray) -> np.ndarray:
        d = P - e
        return d[:, :2] / d[:, 2:3]

    e0 = np.asarray(initial_mm, float)
    c0, *_ = np.linalg.lstsq(A, tangents(e0), rcond=None)

    def resid(x: np.ndarray) -> np.ndarray:
        e = x[:3]
        C = x[3:].reshape(n, 2)
        t = A @ C
        d_pred = np.column_stack([t, np.ones(len(t))])
        d_pred /= np.linalg.norm(d_pred, axis=1, keepdims=True)
        d_true = P - e
        d_true /= np.linalg.norm(d_true, axis=1, keepdims=True)
        return (d_pred - d_true)[:, :2].ravel() * 1000.0          # ~ mrad

    sol = least_squares(resid, np.concatenate([e0, c0.ravel()]), method="lm")
    J = sol.jac
    dof = max(len(sol.fun) - len(sol.x), 1)
    s2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
    except np.linalg.LinAlgError:
        cov = np.full((len(sol.x), len(sol.x)), np.inf)
    return sol.x[:3], cov[:3, :3]


def target_readings(target: ArrayLike, raw: ArrayLike, valid: ArrayLike, t: ArrayLike | None = None,
                    settle_s: float = 0.2, clip: float = 3.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One robust reading per calibration target from a recording.

    Samples of each target's run that come within ``settle_s`` of the run's start (the eye is
    still travelling from the previous dot) and invalid samples are dropped; the rest are
    averaged after discarding those more than ``clip`` robust standard deviations (MAD) from
    the median (a mean, not a median: the median wastes a third of Gaussian data).

    Args:
        target: (N,) target index shown at each sample.
        raw: (N, 2) one eye's readings.
        valid: (N,) bool.
        t: (N,) times, s (needed for ``settle_s``).

    Returns:
        ids (K,), readings (K, 2) (NaN where no sample survived), counts (K,).
    """
    target = np.asarray(target)
    if target.ndim != 1:
        raise ValueError(f"target must have shape (N,), got {target.shape}")
    target = target.astype(int)
    raw = check_points(raw, "raw", 2)
    valid = np.asarray(valid, bool)
    if len(raw) != len(target) or valid.shape != target.shape or (t is not None and np.shape(t) != target.shape):
        raise ValueError(f"target {target.shape}, raw {raw.shape}, valid {valid.shape} and t "
                         f"{None if t is None else np.shape(t)} must have one row per sample")
    ids = np.unique(target)
    out = np.full((len(ids), 2), np.nan)
    counts = np.zeros(len(ids), int)
    run_start = np.concatenate([[True], target[1:] != target[:-1]])
    start_t = np.maximum.accumulate(np.where(run_start, np.arange(len(target)), 0))
    settled = np.ones(len(target), bool) if t is None else (np.asarray(t) - np.asarray(t)[start_t] >= settle_s)
    for k, i in enumerate(ids):
        r = raw[(target == i) & valid & settled]
        if len(r) == 0:
            continue
        med = np.median(r, axis=0)
        mad = 1.4826 * np.median(np.abs(r - med), axis=0) + 1e-9
        keep = np.all(np.abs(r - med) <= clip * mad, axis=1)
        out[k] = r[keep].mean(axis=0)
        counts[k] = int(keep.sum())
    return ids, out, counts


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"estimate_centre": "estimate_center"})
