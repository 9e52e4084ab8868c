"""The error model behind every covariance of ``ml`` and ``voxel``: what the view lines' errors
are, estimated from the data where the data can tell, and how they reach the gazed point.

Sources, and where each comes from:

- Angular noise per eye (``sigma_e``) and its correlation between the eyes (``rho``) and over time
  (``rho_t``, lag one sample): estimated from the fit's own residuals. A per-eye noise replaces the
  assumed ``sigma`` only when the residuals reject it (chi-square test at ``overdispersion_p``):
  the over-dispersion check. When it fires, the covariance is inflated and ``info`` says so.
  Correlations are used when they stand out of their sampling noise (``2.5 / sqrt(n)``).
- Head-pose error from tracking (``pose_sigma_deg``): an angular error shared by both eyes of a
  sample (one head pose), added to each line's variance with correlation 1 between the eyes.
  ``pose_angular_sigma_deg`` turns a tracking pose covariance into it.
- A per-eye bias (``bias_deg`` per axis), common to all lines of an eye over a fixation: the eye
  calibration's residual and the glasses' slippage after it. It never averages down, and a fit
  cannot see it in its residuals (it moves the point instead), so it is a floor: the covariance of
  the point when each eye's lines all turn by a 2D angle of std ``bias_deg``, through the fit's
  sensitivity. ``bias_from_calibration`` takes it from the eye calibration's leave-one-out
  residuals, ``estimator.slippage`` the slippage after it from the session's own lines (how
  each eye's residuals sit off its fixations' points beyond their noise);
  ``wearable_gaze.pipeline.errorbudget`` puts them together with a device's published accuracy
  where there is no calibration. Without any, ``DEFAULT_BIAS_DEG``.

- Head-position error from tracking over a fixation (``pose_position_mm``): both eyes' origins
  move alike, and so does the point: ``t^2 I``.

The covariance is ``H^-1 M H^-1 * f_t + C_bias + t^2 I`` with ``H = sum w J^T J`` (the fit's normal
matrix), ``M`` the residuals' covariance carried through the Jacobians (per-eye variances, the
eyes' correlation), ``f_t = (1 + rho_t) / (1 - rho_t)`` (an AR(1) series' variance of the mean)
and ``C_bias`` the floor. With the model's defaults switched off (no bias, no pose, residuals that
fit) it is ``sigma^2 H^-1``, the inverse Fisher information.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, norm

from .frames import tangent_basis
from .lines import ViewLines

log = logging.getLogger(__name__)

DEFAULT_BIAS_DEG = 0.5
"""Per eye and axis std of the bias after calibration, degrees, when nothing better is known: the
accuracy head-worn trackers reach after a calibration is 0.5-1 deg (Tobii Pro Glasses 2: 0.5 deg;
Pupil Core 3D: 1.0-1.5 deg; Kassner et al. 2014, Niehorster et al. 2020), which per axis is
about 0.35-0.7 deg."""


K95 = math.sqrt(chi2.ppf(0.95, 3))
"""The 95 % ellipsoid's semi-axes over the standard deviations along them (a normal in 3D): the
square root of chi2(3)'s 95 % point (7.81), 2.80. Its one home: the error model, the reports' ellipses
and the tests use it from here."""

FAR_SIDE_K = K95
"""``ErrorModel.far_side_k``: the 95 % ellipsoid's radius in sds (``K95``), so that the 95 %
ellipsoid reaches the far end of the 95 % interval in inverse depth.
Other levels' regions are ``at_level``'s."""


@dataclass(frozen=True)
class ErrorModel:
    """The view lines' error sources beyond the estimator's angular noise ``sigma``.

    Attributes:
        bias_deg: std per eye and tangent axis of the bias common to an eye's lines, degrees.
        bias_correlation: correlation of the two eyes' biases (slippage moves both alike), 0-1.
        pose_sigma_deg: std per tangent axis of the angular error head tracking adds to each line,
            degrees (shared by the two eyes of a sample).
        overdispersion_p: significance of the chi-square test that replaces ``sigma`` by the
            residuals' own spread; 0 never does.
        correlations: estimate the eyes' and the time correlation of the residuals (and use them
            when significant).
        far_side_k: the depth sd is stretched to reach the far end of this many sds in inverse
            depth (``far_side``); 0 leaves the linearised covariance.
        pose_offset_deg: std per axis of the head pose's error over one fixation, degrees, an
            offset shared by both eyes' lines: the merge test's (``estimator.merge``); poses
            tracked in the scene video have one, a device's SLAM hardly any.
        pose_position_mm: std per axis of the head position's error over one fixation, mm,
            shared by both eyes: it moves the point by as much (``t^2 I`` added to the
            covariance); poses tracked in the scene video have one, a device's SLAM hardly any.
    """

    bias_deg: float = DEFAULT_BIAS_DEG
    bias_correlation: float = 0.0
    pose_sigma_deg: float = 0.0
    overdispersion_p: float = 0.01
    correlations: bool = True
    far_side_k: float = FAR_SIDE_K
    pose_offset_deg: float = 0.0
    pose_position_mm: float = 0.0

    def __post_init__(self):
        if not (self.bias_deg >= 0 and self.pose_sigma_deg >= 0 and self.pose_offset_deg >= 0
                and self.pose_position_mm >= 0):
            raise ValueError(f"bias_deg, pose_sigma_deg, pose_offset_deg and pose_position_mm must be non-negative, "
                             f"got {self.bias_deg}, {self.pose_sigma_deg}, {self.pose_offset_deg} and "
                             f"{self.pose_position_mm}")
        if not 0 <= self.bias_correlation <= 1:
            raise ValueError(f"bias_correlation must be in [0, 1], got {self.bias_correlation}")
        if not 0 <= self.overdispersion_p < 1:
            raise ValueError(f"overdispersion_p must be in [0, 1), got {self.overdispersion_p}")


def bias_from_calibration(loo_rms_deg, slip_deg: float = 0.0) -> float:
    """Per-axis bias std, degrees, from the eye calibration's leave-one-out RMS angular errors (one
    per eye, degrees; None or NaN where an eye has none): the calibration's own error (the RMS over
    the eyes divided by sqrt 2: an angle's RMS has two axes) and, added in quadrature, a slippage
    after it (``slip_deg`` per axis, which no calibration sees; the session's own lines size it,
    ``estimator.slippage``). 0 plus ``slip_deg`` when no eye has a figure."""
    vals = np.array([v for v in (loo_rms_deg or []) if v is not None], float)
    vals = vals[np.isfinite(vals)]
    cal2 = float(np.mean(vals**2) / 2.0) if len(vals) else 0.0
    return float(math.sqrt(cal2 + slip_deg**2))


def pose_angular_sigma_deg(pose_cov, distance_mm: float) -> float:
    """Angular std per tangent axis, degrees, that a head-pose covariance adds to a view line to a
    point ``distance_mm`` away. ``pose_cov`` (6, 6): (rotation vector rad, translation mm), as
    ``tracking.pose`` gives it. The rotation turns the line by its angle; the translation moves
    the eye, which seen from the point is an angle of translation / distance. Mean over axes."""
    C = np.asarray(pose_cov, float)
    if C.shape != (6, 6):
        raise ValueError(f"pose_cov must have shape (6, 6), got {C.shape}")
    if not distance_mm > 0:
        raise ValueError(f"distance_mm must be positive, got {distance_mm}")
    var = np.trace(C[:3, :3]) / 3.0 + np.trace(C[3:, 3:]) / 3.0 / distance_mm**2
    return float(np.rad2deg(math.sqrt(max(var, 0.0))))


def eye_labels(lines: ViewLines) -> np.ndarray:
    """(N,) 0 (left) or 1 (right) for each line: in a sample of two lines the first is the left
    (``BinocularSamples.lines`` order); a lone line takes the side whose origin it is nearer in
    the nearest two-line sample (all 0 when there is none)."""
    si = lines.sample_index
    n = len(si)
    order = np.argsort(si, kind="stable")
    s = si[order]
    start = np.r_[True, s[1:] != s[:-1]] if n else np.zeros(0, bool)
    first = np.maximum.accumulate(np.where(start, np.arange(n), 0)) if n else np.zeros(0, int)
    rank = np.arange(n) - first
    counts = np.bincount(np.cumsum(start) - 1)[np.cumsum(start) - 1] if n else np.zeros(0, int)
    label = np.zeros(n, int)
    label[order] = np.minimum(rank, 1)
    pos = np.flatnonzero(start & (counts == 2))             # positions in ``order`` of two-line samples
    lone = order[counts == 1]
    if len(pos) and len(lone):
        ps = s[pos]
        j = np.searchsorted(ps, si[lone]).clip(1, len(ps)) - 1
        j1 = np.minimum(j + 1, len(ps) - 1)
        j = np.where(np.abs(ps[j1] - si[lone]) < np.abs(ps[j] - si[lone]), j1, j)
        o = lines.origins_mm[lone]
        left, right = lines.origins_mm[order[pos[j]]], lines.origins_mm[order[pos[j] + 1]]
        label[lone] = (np.linalg.norm(o - right, axis=1) < np.linalg.norm(o - left, axis=1)).astype(int)
    return label


def _jacobians(X, lines: ViewLines):
    """Residuals (N, 2), their Jacobians (N, 2, 3) at ``X`` and the tangent bases (N, 3) x2."""
    e, d = lines.origins_mm, lines.directions
    b1, b2 = tangent_basis(d)
    w = X - e
    a = np.einsum("ij,ij->i", w, d)
    a = np.where(a > 1e-3 * np.linalg.norm(w, axis=1), a, np.inf)       # behind an eye: no pull
    r = np.column_stack([np.einsum("ij,ij->i", w, b1), np.einsum("ij,ij->i", w, b2)]) / np.where(
        np.isfinite(a), a, 1.0)[:, None]
    J = np.stack([(b1 - r[:, [0]] * d) / a[:, None], (b2 - r[:, [1]] * d) / a[:, None]], axis=1)
    return r, J, b1, b2


def _noise_terms(r, w, eye, si, sigma_rad: float, model: ErrorModel) -> dict:
    """Per-eye noise std (2,), the eyes' residual correlation and the lag-one time correlation,
    from the residuals (N, 2) with weights (N,); the over-dispersion test."""
    out = {"sigma": np.full(2, sigma_rad), "chi2_ratio": np.ones(2), "inflated": [False, False],
           "rho": 0.0, "rho_t": 0.0}
    r2 = np.einsum("ij,ij->i", r, r)
    n_eff = max(float(np.sum(w)), 1e-9)
    dof_all = max(2.0 * n_eff - 3.0, 1.0)
    for k in (0, 1):
        m = eye == k
        if not np.any(m):
            continue
        dof = dof_all * float(np.sum(w[m])) / n_eff
        c = float(np.sum(w[m] * r2[m])) / sigma_rad**2
        out["chi2_ratio"][k] = c / dof
        if model.overdispersion_p > 0 and dof >= 1 and c > chi2.ppf(1 - model.overdispersion_p, dof):
            out["sigma"][k] = sigma_rad * math.sqrt(c / dof)
            out["inflated"][k] = True
    if model.correlations:
        out["rho"], out["rho_t"] = _correlations(r, w, eye, si)
    return out


def _correlations(r, w, eye, si) -> tuple[float, float]:
    """The eyes' residual correlation within a sample and the lag-one correlation of each eye's
    residuals over consecutive samples, each 0 unless above ``2.5 / sqrt(n)``, at most 0.9."""
    order = np.lexsort((eye, si))
    rs, ws, es, ss = r[order], w[order], eye[order], si[order]
    pair = (ss[1:] == ss[:-1]) & (es[:-1] == 0) & (es[1:] == 1)
    rho = _corr(rs[:-1][pair], rs[1:][pair], np.minimum(ws[:-1], ws[1:])[pair])
    lag = []
    for k in (0, 1):
        m = es == k
        rk, wk, sk = rs[m], ws[m], ss[m]
        nxt = np.diff(sk) <= 2
        lag.append((rk[:-1][nxt], rk[1:][nxt], np.minimum(wk[:-1], wk[1:])[nxt]))
    rho_t = _corr(np.concatenate([x[0] for x in lag]), np.concatenate([x[1] for x in lag]),
                  np.concatenate([x[2] for x in lag]))
    return rho, rho_t


def _corr(a, b, w) -> float:
    """Weighted correlation of paired 2D residuals (n, 2), 0 if not significant, clipped to 0-0.9."""
    if len(a) < 8:
        return 0.0
    num = float(np.sum(w * np.einsum("ij,ij->i", a, b)))
    den = math.sqrt(float(np.sum(w * np.einsum("ij,ij->i", a, a))) * float(np.sum(w * np.einsum("ij,ij->i", b, b))))
    rho = num / den if den > 0 else 0.0
    return float(min(rho, 0.9)) if rho > 2.5 / math.sqrt(2 * len(a)) else 0.0


def model_covariance(point_mm, lines: ViewLines, sigma_rad: float, model: ErrorModel,
                     weights=None) -> tuple[np.ndarray | None, dict]:
    """Covariance (3, 3), mm^2, of a point fitted to ``lines`` under the error model, and what it
    found (``info``: per-eye noise in degrees, chi-square ratios, whether it inflated the noise,
    correlations, the bias, the floor's share of the trace, the far side's stretch and what
    ``at_level`` needs (``sight_info``), ``bias_cov``
    (3, 3) the floor itself and ``linear_cov`` (3, 3) the covariance before the stretch, a
    ``note`` for people). The covariance is stretched along the line of sight by ``far_side``.

    Args:
        point_mm: (3,) the fitted point, world, mm.
        lines: the view lines it was fitted to (``sample_index`` pairs the eyes).
        sigma_rad: the angular noise the fit assumed, per tangent axis, radians.
        model: the ``ErrorModel``.
        weights: (N,) the fit's line weights (reliability), default 1.

    Returns ``(None, info)`` when the lines do not fix the point (singular normal matrix).
    """
    X = np.asarray(point_mm, float)
    w = np.ones(len(lines)) if weights is None else np.asarray(weights, float).reshape(len(lines))
    eye, si = eye_labels(lines), lines.sample_index
    r, J, b1, b2 = _jacobians(X, lines)
    H = np.einsum("n,nki,nkj->ij", w, J, J)
    if not np.all(np.isfinite(H)) or np.linalg.cond(H) > 1e14:
        return None, {"note": "the view lines do not fix a point"}
    Hi = np.linalg.inv(H)
    nz = _noise_terms(r, w, eye, si, sigma_rad, model)
    meat = _noise_meat(J, w, eye, si, nz, np.deg2rad(model.pose_sigma_deg))
    f_t = (1 + nz["rho_t"]) / (1 - nz["rho_t"])
    C_noise = Hi @ meat @ Hi * f_t
    C_bias = _bias_floor(Hi, J, w, eye, lines.directions, b1, b2, model)
    C_lin = C_noise + C_bias + model.pose_position_mm**2 * np.eye(3)
    origin = lines.origins_mm.mean(axis=0)
    C, far = far_side(C_lin, X, origin, model.far_side_k)
    C = 0.5 * (C + C.T)
    inflated = any(nz["inflated"])
    info = {"sigma_eye_deg": np.rad2deg(nz["sigma"]).round(4).tolist(),
            "chi2_ratio": nz["chi2_ratio"].round(3).tolist(), "inflated": bool(inflated or f_t > 1),
            "eye_correlation": round(nz["rho"], 3), "time_correlation": round(nz["rho_t"], 3),
            "bias_deg": model.bias_deg, "pose_sigma_deg": model.pose_sigma_deg,
            "pose_position_mm": model.pose_position_mm,
            "bias_share": float(np.trace(C_bias) / max(np.trace(C), 1e-300)), "far_side_factor": round(far, 3),
            **sight_info(C_lin, X, origin, model.far_side_k)}
    info["note"] = _note(nz, f_t, sigma_rad)
    info["bias_cov"], info["linear_cov"] = C_bias, 0.5 * (C_lin + C_lin.T)
    return C, info


FAR_SIDE_CAP = 10.0
"""The largest depth stretch ``far_side`` applies (a point whose far side has no end is
``unresolved`` anyway)."""


def far_side(C, point_mm, origin_mm, k: float) -> tuple[np.ndarray, float]:
    """The covariance (3, 3) stretched along the line of sight so that its depth interval reaches
    the far end of the interval that is symmetric in inverse depth, and the stretch.

    Depth from vergence and parallax is Gaussian in inverse depth (angles), not in depth: a point
    estimated too near has a truth farther away than its linearised sd says (the sd, evaluated at
    the estimate, shrinks as depth squared), one estimated too far a truth nearer than it says.
    With ``r`` the relative depth sd, the interval of ``k`` sds in inverse depth ends at
    ``D / (1 - k r)`` on the far side; the depth sd is stretched by ``f = 1 / (1 - k r)`` so that
    ``k`` of its sds reach it (at most ``FAR_SIDE_CAP``). The near side is then wider than it
    needs to be. ``k`` = 0: unchanged.

    Args:
        C: (3, 3) covariance of the point, mm^2.
        point_mm, origin_mm: (3,) the point and the eyes' mean origin, world, mm.
        k: the interval's half-width in sds (``ErrorModel.far_side_k``).
    """
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    D = float(np.linalg.norm(v))
    if k <= 0 or not D > 0 or not np.all(np.isfinite(C)):
        return C, 1.0
    u = v / D
    f = _stretch(k, math.sqrt(max(float(u @ C @ u), 0.0)) / D)
    S = np.eye(3) + (f - 1.0) * np.outer(u, u)
    return S @ C @ S, float(f)


def sight_info(C_lin, point_mm, origin_mm, k: float) -> dict:
    """What an estimate's ``info["error_model"]`` keeps so that its regions at any level can be
    drawn (``at_level``, ``depth_interval``): where its lines were seen from (``sight_origin_mm``,
    the eyes' mean origin, world, mm), the far side's ``k`` its covariance was stretched with,
    and ``depth_rel_sd``, the relative sd of its distance from there in the linearised
    covariance ``C_lin`` (3, 3) mm^2 (before the stretch; NaN when undefined)."""
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    D = float(np.linalg.norm(v))
    r = math.sqrt(max(float(v @ np.asarray(C_lin, float) @ v), 0.0)) / D**2 if D > 0 else float("nan")
    return {"sight_origin_mm": [float(x) for x in np.asarray(origin_mm, float).reshape(3)], "far_side_k": float(k),
            "depth_rel_sd": float(r)}


@dataclass(frozen=True)
class Sight:
    """Where an estimate's view lines were seen from and how the error model shaped its
    covariance (``sight_info``): what its region at any level and its depth intervals are drawn
    from (``at_level``, ``depth_interval``).

    Attributes:
        origin_mm: (3,) the lines' mean origin, world frame, mm.
        far_side_k: the far side's ``k`` the covariance was stretched with (0: not stretched).
        depth_rel_sd: the linearised relative sd of the distance from ``origin_mm`` (NaN: none).
    """

    origin_mm: np.ndarray
    far_side_k: float
    depth_rel_sd: float

    @classmethod
    def from_info(cls, error_model_info: dict | None) -> Sight | None:
        """The sight kept in an estimate's ``info["error_model"]``, or None (no error model)."""
        em = error_model_info or {}
        if em.get("sight_origin_mm") is None:
            return None
        return cls(np.asarray(em["sight_origin_mm"], float), float(em["far_side_k"]), float(em["depth_rel_sd"]))

    def level_covariance(self, C, point_mm, probability: float) -> np.ndarray:
        """``at_level`` of the covariance ``C`` (3, 3) mm^2 of the point ``point_mm`` (3,) mm."""
        return at_level(C, point_mm, self.origin_mm, probability, self.far_side_k, self.depth_rel_sd)

    def depth_interval(self, point_mm, probability: float) -> tuple[float, float]:
        """``depth_interval`` of the point ``point_mm`` (3,) mm: (near, far) mm."""
        return depth_interval(point_mm, self.origin_mm, probability, self.depth_rel_sd)

    def distance_mm(self, point_mm) -> float:
        """The distance of ``point_mm`` (3,) from ``origin_mm``, mm."""
        return float(np.linalg.norm(np.asarray(point_mm, float) - self.origin_mm))


def _stretch(k: float, r: float) -> float:
    """``far_side``'s stretch ``1 / (1 - k r)``, at most ``FAR_SIDE_CAP``."""
    return FAR_SIDE_CAP if k * r >= 1.0 - 1.0 / FAR_SIDE_CAP else 1.0 / (1.0 - k * r)


def at_level(C, point_mm, origin_mm, probability: float, k: float, rel_sd: float, dof: int = 3) -> np.ndarray:
    """The covariance (3, 3) mm^2 whose ``probability`` ellipsoid (chi2 with ``dof``) is the
    region of that level, from ``C``, the error model's covariance stretched by ``far_side``
    with ``k`` (the 95 % level's). The stretch that makes the 95 % region reach the far end of
    the 95 % interval in inverse depth makes a 68 % region too long (on the real Aria walk's
    0.5 s windows, a median 3.4 times): each level gets its own, with ``k_p = sqrt(chi2.ppf(p,
    dof))``. ``C`` unchanged when it was not stretched (``k`` 0) or nothing is defined.

    Args:
        C: (3, 3) covariance, mm^2 (``GazeEstimate.covariance_mm2``).
        point_mm, origin_mm: (3,) the point and where it was seen from, mm.
        probability: the region's level, in (0, 1).
        k, rel_sd: the far side's ``k`` and the linearised relative depth sd (``sight_info``).
        dof: 3 for a 3D region; 1 for an interval along the line of sight.
    """
    C = np.asarray(C, float)
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    D = float(np.linalg.norm(v))
    if k <= 0 or not D > 0 or not math.isfinite(rel_sd):
        return C
    u = v / D
    g = _stretch(math.sqrt(chi2.ppf(probability, dof)), rel_sd) / _stretch(k, rel_sd)
    S = np.eye(3) + (g - 1.0) * np.outer(u, u)
    return S @ C @ S


def depth_interval(point_mm, origin_mm, probability: float, rel_sd: float) -> tuple[float, float]:
    """The ``probability`` interval (near, far) of the distance of ``point_mm`` from
    ``origin_mm``, mm, symmetric in inverse depth (where vergence and parallax are Gaussian):
    ``D / (1 +- z r)`` with ``r = rel_sd`` the linearised relative depth sd (``sight_info``);
    far is ``inf`` when the interval has no far end; (NaN, NaN) when ``r`` is undefined."""
    D = float(np.linalg.norm(np.asarray(point_mm, float) - np.asarray(origin_mm, float)))
    if not (D > 0 and math.isfinite(rel_sd)):
        return float("nan"), float("nan")
    z = float(norm.ppf(0.5 + probability / 2.0))
    return D / (1.0 + z * rel_sd), (D / (1.0 - z * rel_sd) if z * rel_sd < 1.0 else float("inf"))


def _noise_meat(J, w, eye, si, nz: dict, pose_rad: float) -> np.ndarray:
    """``sum J^T Cov(r) J`` over samples: per-eye variance (noise plus pose) on each line, and the
    covariance between the two lines of a sample (the eyes' correlation, and the shared pose)."""
    sig = nz["sigma"][eye]
    var = sig**2 + pose_rad**2
    M = np.einsum("n,nki,nkj->ij", w * w * var, J, J)
    order = np.lexsort((eye, si))
    pair = (si[order][1:] == si[order][:-1]) & (eye[order][:-1] == 0) & (eye[order][1:] == 1)
    iL, iR = order[:-1][pair], order[1:][pair]
    if len(iL):
        cov = nz["rho"] * sig[iL] * sig[iR] + pose_rad**2
        cross = np.einsum("n,nki,nkj->ij", w[iL] * w[iR] * cov, J[iL], J[iR])
        M = M + cross + cross.T
    return M


def bias_floor(Hi, J, lines: ViewLines, model: ErrorModel, weights=None) -> np.ndarray:
    """The bias floor (P, P) of any fit with P parameters to ``lines`` (N): its covariance when
    every line of an eye turns by one 2D angle of std ``model.bias_deg`` per axis.

    Args:
        Hi: (P, P) the inverse of the fit's normal matrix ``sum w J^T J`` (in the units of ``J``).
        J: (N, 2, P) each line's gnomonic residuals' Jacobian with respect to the parameters,
            radians per parameter unit (a path's knots: the point's Jacobian times the line's
            interpolation weights).
        lines: the view lines (``sample_index`` pairs the eyes).
        model: the ``ErrorModel``.
        weights: (N,) line weights, default 1.
    """
    w = np.ones(len(lines)) if weights is None else np.asarray(weights, float).reshape(len(lines))
    b1, b2 = tangent_basis(lines.directions)
    return _bias_floor(np.asarray(Hi, float), np.asarray(J, float), w, eye_labels(lines), lines.directions, b1, b2,
                       model)


def _bias_floor(Hi, J, w, eye, d, b1, b2, model: ErrorModel) -> np.ndarray:
    """Covariance (3, 3) of the point when every line of an eye turns by one 2D angle of std
    ``bias_deg`` per axis (in a basis fixed to that eye's mean direction), the eyes' angles
    correlated by ``bias_correlation``: ``sum G_e G_f^T`` with ``G_e = H^-1 sum_(i in e) w J_i^T
    (B_i^T C_e)`` the point's sensitivity to eye ``e``'s angle."""
    b = np.deg2rad(model.bias_deg)
    if b == 0:
        return np.zeros((3, 3))
    G = []
    for k in (0, 1):
        m = eye == k
        if not np.any(m):
            continue
        mean_d = d[m].mean(axis=0)
        c1, c2 = tangent_basis((mean_d / np.linalg.norm(mean_d))[None])
        Mi = np.stack([np.stack([b1[m] @ c1[0], b1[m] @ c2[0]], 1), np.stack([b2[m] @ c1[0], b2[m] @ c2[0]], 1)],
                      axis=1)                                           # (n, 2 residual, 2 angle)
        G.append(Hi @ np.einsum("n,nki,nka->ia", w[m], J[m], Mi))    # (3, 2)
    C = sum(g @ g.T for g in G)
    if len(G) == 2 and model.bias_correlation > 0:
        C = C + model.bias_correlation * (G[0] @ G[1].T + G[1] @ G[0].T)
    return b * b * C


def _note(nz: dict, f_t: float, sigma_rad: float) -> str:
    """A sentence for people on what the residuals said."""
    parts = []
    for k, side in ((0, "left"), (1, "right")):
        if nz["inflated"][k]:
            parts.append(f"the {side} eye's residuals are {math.sqrt(nz['chi2_ratio'][k]):.2f}x the assumed "
                         f"{np.rad2deg(sigma_rad):.2g} deg")
    if f_t > 1:
        parts.append(f"the residuals are correlated in time (lag one {nz['rho_t']:.2f})")
    if not parts:
        return ""
    return "; ".join(parts) + ": the uncertainty is inflated to match"
