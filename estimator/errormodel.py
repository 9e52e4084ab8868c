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
- A per-eye bias (``bias_deg`` per axis), common to all lines of an eye over a fixation: the eye
  calibration's residual and the glasses' slippage after it. It never averages down, and a fit
  cannot see it in its residuals (it moves the point instead), so it is a floor: the covariance of
  the point when each eye's lines all turn by a 2D angle of std ``bias_deg``, through the fit's
  sensitivity. ``bias_from_calibration`` takes it from the eye calibration's leave-one-out
  residuals, ``estimator.slippage`` the slippage after it from the session's own lines (how
  each eye's residuals sit off its fixations' points beyond their noise);
  ``wearable_gaze.pipeline.steps.errorbudget`` puts them together with a device's published accuracy
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
from typing import Any

import numpy as np
from scipy.stats import chi2

from .errormodel_regions import far_side, sight_info
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
        slip_deg: the part of ``bias_deg`` (per axis, degrees, in quadrature) that the session's
            own lines sized (``estimator.slippage``), beyond what was known before them.
        slip_dof: how many combinations of the eyes' angles ``slip_deg`` rests on (``SeenBias.seen``):
            its degrees of freedom; the others (the eyes' common turn, which no point's lines
            show) are taken alike, so a bias sized from two of them is known to two degrees of
            freedom, and the regions are Student's (``scale_dof``, ``errormodel_regions``).
    """

    bias_deg: float = DEFAULT_BIAS_DEG
    bias_correlation: float = 0.0
    pose_sigma_deg: float = 0.0
    overdispersion_p: float = 0.01
    correlations: bool = True
    far_side_k: float = FAR_SIDE_K
    pose_offset_deg: float = 0.0
    pose_position_mm: float = 0.0
    slip_deg: float = 0.0
    slip_dof: float = math.inf

    def __post_init__(self):
        if not (self.bias_deg >= 0 and self.pose_sigma_deg >= 0 and self.pose_offset_deg >= 0
                and self.pose_position_mm >= 0):
            raise ValueError(f"bias_deg, pose_sigma_deg, pose_offset_deg and pose_position_mm must be non-negative, "
                             f"got {self.bias_deg}, {self.pose_sigma_deg}, {self.pose_offset_deg} and "
                             f"{self.pose_position_mm}")
        if not 0 <= self.bias_correlation <= 1:
            raise ValueError(f"bias_correlation must be in [0, 1], got {self.bias_correlation}")
        if not (0 <= self.slip_deg <= self.bias_deg and self.slip_dof > 0):
            raise ValueError(f"slip_deg must be in [0, bias_deg] and slip_dof positive, got {self.slip_deg} and "
                             f"{self.slip_dof}")
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


def eye_labels(lines: ViewLines) -> np.ndarray:
    """(N,) 0 (left) or 1 (right) for each line: in a sample of two lines the first is the left
    (``BinocularSamples.lines`` order); a lone line takes the side whose origin it is nearer in
    the nearest two-line sample (all 0 when there is none)."""
    si = lines.sample_index
    assert si is not None                          # ViewLines fills it in
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
    out: dict[str, Any] = {"sigma": np.full(2, sigma_rad), "chi2_ratio": np.ones(2),
                           "inflated": [False, False], "rho": 0.0, "rho_t": 0.0}
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
    C_common = _common_floor(Hi, J, w, eye, lines.directions, b1, b2, model) if model.slip_deg > 0 else None
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
    if C_common is not None:
        info.update({k: (v if math.isfinite(v) else None) for k, v in region_dofs(C_lin, C_common, X, origin,
                                                                                    model).items()})
    info["note"] = _note(nz, f_t, sigma_rad)
    info["bias_cov"], info["linear_cov"] = C_bias, 0.5 * (C_lin + C_lin.T)
    return C, info


def region_dofs(C_lin, C_common, point_mm, origin_mm, model: ErrorModel) -> dict:
    """The degrees of freedom of a covariance ``C_lin`` (3, 3) whose bias rests in part
    (``slip_deg`` of ``bias_deg``) on a size drawn from ``slip_dof`` combinations of the eyes'
    angles, for the part no line shows, the eyes' common turn (``C_common`` (3, 3), its floor
    at ``bias_deg``; the rest is known): Welch-Satterthwaite, ``slip_dof / s^2`` with ``s`` the
    share of ``C_unseen = C_common slip^2 / bias^2`` in the variance. ``scale_dof``: in the
    direction where that share is largest (the 3D regions'); ``depth_dof``: along the line of
    sight from ``origin_mm`` (3,) to ``point_mm`` (3,) (the depth intervals'). Each ``inf`` when
    no part was sized so. (``errormodel_regions``: the regions are Student's.)"""
    out = {"scale_dof": math.inf, "depth_dof": math.inf}
    if not (model.slip_deg > 0 and math.isfinite(model.slip_dof)):
        return out
    C = np.asarray(C_lin, float)
    U = np.asarray(C_common, float) * (model.slip_deg / model.bias_deg) ** 2
    try:
        share = float(np.max(np.real(np.linalg.eigvals(np.linalg.solve(C, U)))))
    except np.linalg.LinAlgError:
        return out
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    depth_share = float(v @ U @ v) / float(v @ C @ v) if float(v @ C @ v) > 0 else 0.0
    for key, s in (("scale_dof", share), ("depth_dof", depth_share)):
        if s > 0:
            out[key] = model.slip_dof / min(s, 1.0) ** 2
    return out


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
    (B_i^T C_e)`` the point's sensitivity to eye ``e``'s angle (``_bias_gains``)."""
    b = np.deg2rad(model.bias_deg)
    if b == 0:
        return np.zeros((3, 3))
    G = _bias_gains(Hi, J, w, eye, d, b1, b2)
    C = sum(g @ g.T for g in G)
    if len(G) == 2 and model.bias_correlation > 0:
        C = C + model.bias_correlation * (G[0] @ G[1].T + G[1] @ G[0].T)
    return b * b * C


def _common_floor(Hi, J, w, eye, d, b1, b2, model: ErrorModel) -> np.ndarray:
    """The part (3, 3) of ``_bias_floor`` that the eyes' common turn ``(beta_L + beta_R) / 2``
    makes (per axis variance ``bias^2 (1 + rho) / 2``): ``(G_L + G_R)(G_L + G_R)^T`` times that;
    zeros without both eyes. No point's lines show this turn (it moves the point sideways)."""
    G = _bias_gains(Hi, J, w, eye, d, b1, b2)
    if len(G) < 2 or model.bias_deg == 0:
        return np.zeros((3, 3))
    g = G[0] + G[1]
    return np.deg2rad(model.bias_deg) ** 2 * (1 + model.bias_correlation) / 2 * (g @ g.T)


def _bias_gains(Hi, J, w, eye, d, b1, b2) -> list:
    """Each eye's ``G_e`` (3, 2): the point's change, mm, per radian of that eye's 2D angle."""
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
    return G


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
