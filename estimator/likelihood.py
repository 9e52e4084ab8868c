"""Maximum likelihood on angular residuals, the Cramér-Rao bound, and per-sample reliability.

Noise model: each measured view direction is the true direction to the gazed point ``X``
rotated by two independent Gaussian angles of standard deviation ``sigma`` about the two axes
perpendicular to it. The residual of line ``(e, d)`` at ``X`` is the gnomonic projection of
``u = X - e`` on the tangent plane of ``d``:

    r = (b1 . u, b2 . u) / (d . u)        |r| = tan(angle between u and d)

with ``(b1, b2, d)`` an orthonormal frame. For small angles ``r`` is the two angular errors, so
the negative log-likelihood is ``sum |r_i|^2 / (2 sigma^2)`` and the Fisher information is
``sum_i (I - u_i u_i^T) / (sigma^2 |X - e_i|^2)``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ._checks import check_points, check_same_rows, check_vector
from .errormodel import ErrorModel, model_covariance
from .frames import tangent_basis
from .lines import ViewLines
from .result import GazeEstimate, Status, failed
from .triangulation import _n_samples, _point_result, lse_point, nearest_point_to_lines

LOSSES = ("gaussian", "mixture", "huber")

log = logging.getLogger(__name__)


def fisher_information(point_mm: ArrayLike, origins_mm: ArrayLike, sigma_rad: float,
                       weights: ArrayLike | None = None) -> np.ndarray:
    """Fisher information (3, 3), mm^-2, about a point from view lines with angular noise.

    Args:
        point_mm: (3,) the point, mm.
        origins_mm: (N, 3) line origins, mm.
        sigma_rad: angular noise standard deviation per tangent axis, radians.
        weights: optional (N,) line weights.
    """
    X = check_vector(point_mm, "point_mm")
    e = check_points(origins_mm, "origins_mm")
    v = X - e
    r2 = np.einsum("ij,ij->i", v, v)
    u = v / np.sqrt(r2)[:, None]
    w = np.ones(len(e)) if weights is None else np.asarray(weights, float)
    P = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    return np.einsum("n,nij->ij", w / (sigma_rad**2 * r2), P)


def cramer_rao_bound(origins_mm: ArrayLike, point_mm: ArrayLike, sigma_deg: float) -> np.ndarray:
    """Cramér-Rao lower bound (3, 3), mm^2, on the covariance of any unbiased estimate of the
    gazed point, for lines from ``origins_mm`` (N, 3) toward ``point_mm`` (3,) with angular
    noise ``sigma_deg`` per tangent axis. Raises ``ValueError`` if the lines cannot fix the point."""
    F = fisher_information(point_mm, origins_mm, np.deg2rad(sigma_deg))
    if np.linalg.cond(F) > 1e15:
        raise ValueError("the lines' origins cannot fix the point (all lines are parallel)")
    return np.linalg.inv(F)


MAX_TAN2 = 1e6
"""Bound on tan^2 of the angle between a view line and the ray to a point (about 89.94 degrees):
a point behind a line's origin, or nearly perpendicular to it, counts as this far off; never inf or
NaN. The one bound for the residuals, the grids and the log-likelihood."""

_BEHIND_RESIDUAL = math.sqrt(MAX_TAN2)   # |r| = tan(angle) for a point behind a line's origin


def angular_residuals(point_mm: ArrayLike, lines: ViewLines) -> np.ndarray:
    """Gnomonic residuals (N, 2), radians for small angles, of each line at ``point_mm`` (3,).

    Lines for which the point lies behind the origin (or within 0.06 deg of perpendicular to it)
    get a residual of norm ``sqrt(MAX_TAN2)`` (1e3), far outside any sensible noise level; never NaN.
    """
    b1, b2 = tangent_basis(lines.directions)
    return gnomonic_residuals(check_vector(point_mm, "point_mm"), lines.origins_mm, lines.directions, b1, b2)[0]


def gnomonic_residuals(point_mm: np.ndarray, origins_mm: np.ndarray, directions: np.ndarray, b1: np.ndarray,
                       b2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N, 2) of lines at one point and each line's ``d . u`` (N,), for the ML fit.

    Args:
        point_mm: (3,) the point, world, mm.
        origins_mm, directions: (N, 3) lines, world frame, mm and unit vectors.
        b1, b2: (N, 3) each, the tangent basis of ``directions`` (``frames.tangent_basis``).

    Returns:
        ``r`` (N, 2): ``(b1 . u, b2 . u) / (d . u)`` with ``u = point - origin``, so
        ``|r|^2`` is tan^2 of the angle; a point behind an origin (``d . u <= |u| / sqrt(MAX_TAN2)``)
        gets the constant norm ``sqrt(MAX_TAN2)``. ``a`` (N,): ``d . u``, ``inf`` behind the origin
        (so the Jacobian rows ``(b_k - r_k d) / a`` of those lines are zero).
    """
    w = point_mm - origins_mm
    a = np.einsum("ij,ij->i", w, directions)
    norm = np.linalg.norm(w, axis=1)
    floor = (1.0 / _BEHIND_RESIDUAL) * np.maximum(norm, 1e-9)   # 1e-3 |u|
    behind = a <= floor
    a_safe = np.where(behind, np.inf, a)
    t = np.column_stack([np.einsum("ij,ij->i", w, b1), np.einsum("ij,ij->i", w, b2)])
    r = t / np.where(behind, 1.0, a)[:, None]
    if np.any(behind):
        tn = np.linalg.norm(t[behind], axis=1, keepdims=True)
        unit = np.where(tn > 0, t[behind] / np.maximum(tn, 1e-300), [[1.0, 0.0]])
        r[behind] = _BEHIND_RESIDUAL * unit
    return r, a_safe


def tan2_from_local(points_local_T: np.ndarray, points_sq: np.ndarray, origins_local: np.ndarray,
                    directions: np.ndarray) -> np.ndarray:
    """tan^2 of the angle (L, M) between each of L lines and the ray from its origin to each of M
    points, all given relative to one reference point ``c`` (any point near the points: it keeps
    the arithmetic exact). At most ``MAX_TAN2``, which is also the value behind an origin.

    Args:
        points_local_T: (3, M) the points minus ``c``, transposed (the long axis innermost: numpy is
            fast only then), mm.
        points_sq: (M,) their squared norms, mm^2.
        origins_local: (L, 3) line origins minus ``c``, mm.
        directions: (L, 3) unit line directions (same axes as the points).

    With ``w = x - e = P - f`` (``P`` a local point, ``f`` a local origin): ``d . w = P . d - f . d``
    and ``|w|^2 = |P|^2 - 2 P . f + |f|^2``, so one matrix product serves a whole batch of lines
    (and a caller may keep ``points_local_T``, ``points_sq`` across batches, as the grids do).
    """
    d = np.atleast_2d(np.asarray(directions, float))
    f = np.atleast_2d(np.asarray(origins_local, float))
    m = np.concatenate([d, f]) @ points_local_T               # (2L, M)
    L = len(d)
    a = m[:L]
    a -= (f * d).sum(1)[:, None]
    s = m[L:]
    s *= -2.0
    s += points_sq
    s += (f * f).sum(1)[:, None]
    # cos^2 with the sign of d . w; clamping it bounds tan^2 and sends "behind" to the bound
    out = np.abs(a)
    out *= a
    out /= s
    np.maximum(out, 1.0 / (MAX_TAN2 + 1.0), out=out)
    np.reciprocal(out, out=out)
    out -= 1.0
    return out


def angular_tan2(points_mm: np.ndarray, origins_mm: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """tan^2 of the angle (L, M) between each of L view lines (origins (L, 3) mm, unit directions
    (L, 3)) and the ray from its origin to each of M points (M, 3), all in one frame (world, mm);
    at most ``MAX_TAN2`` (also the value behind an origin). See ``tan2_from_local``."""
    P = np.atleast_2d(np.asarray(points_mm, float))
    c = P.mean(axis=0)
    local = P - c
    return tan2_from_local(np.ascontiguousarray(local.T), np.einsum("ij,ij->i", local, local),
                           np.atleast_2d(np.asarray(origins_mm, float)) - c, directions)


_POINT_CHUNK, _LINE_CHUNK = 4096, 256


def angular_log_likelihood(points_mm: ArrayLike, origins_mm: ArrayLike, directions: ArrayLike, sigma_rad: float,
                           weights: ArrayLike | None = None) -> np.ndarray:
    """Log-likelihood (M,) of M candidate gazed points (M, 3) under the angular noise model:
    ``-sum_l w_l tan^2(angle_l) / (2 sigma^2)`` (the gnomonic residual's squared norm is tan^2),
    up to a constant; each term bounded by ``MAX_TAN2`` (points behind an eye).

    Args:
        points_mm: (M, 3) points, world, mm.
        origins_mm, directions: (L, 3) lines, world frame, mm and unit vectors.
        sigma_rad: angular noise standard deviation per tangent axis, radians.
        weights: optional (L,) line weights (reliability); 1 each by default.
    """
    pts = check_points(points_mm, "points_mm")
    o = check_points(origins_mm, "origins_mm")
    d = check_points(directions, "directions")
    check_same_rows(o, d, "origins_mm", "directions")
    w = np.ones(len(o)) if weights is None else np.asarray(weights, float).reshape(len(o))
    out = np.zeros(len(pts))
    for start in range(0, len(pts), _POINT_CHUNK):        # bounded memory: (256 lines, 4096 points)
        p = pts[start:start + _POINT_CHUNK]
        for ls in range(0, len(o), _LINE_CHUNK):
            out[start:start + _POINT_CHUNK] += w[ls:ls + _LINE_CHUNK] @ angular_tan2(p, o[ls:ls + _LINE_CHUNK],
                                                                                     d[ls:ls + _LINE_CHUNK])
    return (-0.5 / sigma_rad**2) * out


def reliability_weights(chi2_values: ArrayLike, dof, sigma_rad: float, outlier_prob: float) -> np.ndarray:
    """Posterior probability that each sample is an inlier, under a two-component mixture.

    Inliers: Gaussian angular residuals (``dof`` components, std ``sigma_rad``), so
    ``chi2 = |r|^2 / sigma^2``. Outliers (blinks, saccades, lost pupils): residual components
    uniform over +-1 (tangent of +-45 degrees). ``outlier_prob`` is the prior outlier fraction;
    0 gives weight 1 everywhere.

    Args:
        chi2_values: (N,) per-sample chi-square values.
        dof: (N,) or scalar, residual components per sample (2 per valid eye).
    """
    c = np.asarray(chi2_values, dtype=np.float64)
    if outlier_prob <= 0:
        return np.ones_like(c)
    dof = np.broadcast_to(np.asarray(dof, dtype=np.float64), c.shape)
    log_in = np.log1p(-outlier_prob) - 0.5 * c - 0.5 * dof * np.log(2 * np.pi * sigma_rad**2)
    log_out = np.log(outlier_prob) + dof * np.log(0.5)
    return 1.0 / (1.0 + np.exp(np.clip(log_out - log_in, -700, 700)))


def reliability_weight(chi2_value: float, dof: float, sigma_rad: float, outlier_prob: float) -> float:
    """``reliability_weights`` for one sample, in scalar arithmetic (the streaming hot path)."""
    if outlier_prob <= 0:
        return 1.0
    log_in = math.log1p(-outlier_prob) - 0.5 * chi2_value - 0.5 * dof * math.log(2 * math.pi * sigma_rad**2)
    log_out = math.log(outlier_prob) + dof * math.log(0.5)
    return 1.0 / (1.0 + math.exp(min(max(log_out - log_in, -700.0), 700.0)))


def _loss_weights(chi2_per_sample, dof, sigma_rad, loss, outlier_prob, huber_k):
    if loss == "gaussian":
        return np.ones_like(chi2_per_sample)
    if loss == "mixture":
        return reliability_weights(chi2_per_sample, dof, sigma_rad, outlier_prob)
    z = np.sqrt(chi2_per_sample / dof)   # RMS residual in sigmas
    return np.where(z <= huber_k, 1.0, huber_k / np.maximum(z, 1e-300))


@dataclass(frozen=True)
class MLConfig:
    """Settings of the maximum-likelihood estimator.

    Attributes:
        sigma_deg: angular noise std per tangent axis, degrees (the EMR-8 class: about 1 deg).
        loss: ``gaussian`` (plain ML); ``mixture`` (Gaussian inliers plus a uniform outlier
            component per binocular sample, weights by EM: for blinks and saccades); ``huber``.
        outlier_prob: prior outlier fraction for ``mixture``.
        huber_k: Huber threshold, RMS residual in sigmas, for ``huber``.
        max_iterations: Levenberg-Marquardt iteration limit.
        tolerance_mm: stop when a step moves the point less than this.
        error_model: the covariance's error model (``estimator.errormodel``: per-eye noise and
            over-dispersion from the residuals, head pose, per-eye bias); None gives the inverse
            Fisher information of ``sigma_deg`` alone.
    """

    sigma_deg: float = 1.0
    loss: str = "gaussian"
    outlier_prob: float = 0.02
    huber_k: float = 2.0
    max_iterations: int = 100
    tolerance_mm: float = 1e-7
    error_model: ErrorModel | None = None

    def __post_init__(self):
        if not self.sigma_deg > 0:
            raise ValueError(f"sigma_deg must be positive, got {self.sigma_deg}")
        if self.error_model is not None and not isinstance(self.error_model, ErrorModel):
            raise ValueError(f"error_model must be an ErrorModel or None, got {type(self.error_model).__name__}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        if not 0 <= self.outlier_prob < 1:
            raise ValueError(f"outlier_prob must be in [0, 1), got {self.outlier_prob}")


class _MLProblem:
    """The weighted gnomonic least-squares problem of ``ml_point``: cost, robust weights and the
    Gauss-Newton normal equations at a point. ``line_w`` (N,) holds the current line weights."""

    def __init__(self, lines: ViewLines, config: MLConfig, n_samples: int):
        self.config = config
        self.sigma = np.deg2rad(config.sigma_deg)
        self.e, self.d = lines.origins_mm, lines.directions
        self.b1, self.b2 = tangent_basis(self.d)
        self.ns = n_samples
        assert lines.sample_index is not None           # ViewLines fills it in
        _, self.inverse = np.unique(lines.sample_index, return_inverse=True)
        self.dof = np.bincount(self.inverse, minlength=n_samples) * 2.0
        self.line_w = np.ones(len(lines))

    def cost(self, X, update_weights: bool) -> float:
        """Half the weighted chi-square at ``X`` (3,); ``update_weights`` re-weights the samples
        there first (robust losses)."""
        cfg, sigma = self.config, self.sigma
        r, _ = gnomonic_residuals(X, self.e, self.d, self.b1, self.b2)
        r2 = np.einsum("ij,ij->i", r, r) / sigma**2
        if update_weights and cfg.loss != "gaussian":
            chi2_s = np.bincount(self.inverse, weights=r2, minlength=self.ns)
            self.line_w[:] = _loss_weights(chi2_s, self.dof, sigma, cfg.loss, cfg.outlier_prob,
                                           cfg.huber_k)[self.inverse]
        return 0.5 * np.sum(self.line_w * r2)

    def normal_equations(self, X):
        """Residuals (N, 2), Gauss-Newton matrix J^T W J and gradient J^T W r at X, with
        d r_k / d X = (b_k - r_k d) / (d . u)."""
        b1, b2, d, w, sigma = self.b1, self.b2, self.d, self.line_w, self.sigma
        r, a = gnomonic_residuals(X, self.e, d, b1, b2)
        J1 = (b1 - r[:, [0]] * d) / a[:, None]
        J2 = (b2 - r[:, [1]] * d) / a[:, None]
        H = (np.einsum("n,ni,nj->ij", w, J1, J1) + np.einsum("n,ni,nj->ij", w, J2, J2)) / sigma**2
        g = (np.einsum("n,ni->i", w * r[:, 0], J1) + np.einsum("n,ni->i", w * r[:, 1], J2)) / sigma**2
        return r, H, g


def _levenberg_marquardt(problem: _MLProblem, x, config: MLConfig):
    """Minimise ``problem.cost`` from ``x`` (3,); returns (x, iterations, converged)."""
    lam = 1e-3
    cost = problem.cost(x, True)
    it = 0
    converged = False
    for it in range(1, config.max_iterations + 1):  # noqa: B007 (it is reported after the loop)
        _, H, g = problem.normal_equations(x)
        step_ok = False
        for _ in range(30):
            try:
                step = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            new_cost = problem.cost(x + step, False)
            if new_cost <= cost:
                x = x + step
                lam = max(lam / 10, 1e-12)
                step_ok = True
                break
            lam *= 10
        cost = problem.cost(x, True)
        if not step_ok or np.linalg.norm(step) < config.tolerance_mm:
            converged = bool(step_ok or np.linalg.norm(g) < 1e-9)
            break
    return x, it, converged


def _ml_start(lines: ViewLines, x0_mm, ns: int, n: int):
    """The starting point (3,) of the ML fit: ``x0_mm``, or the geometric least-squares point
    (the LSE point when that one fails); a failed ``GazeEstimate`` when the lines are degenerate."""
    if x0_mm is not None:
        return check_vector(x0_mm, "x0_mm").copy()
    start = nearest_point_to_lines(lines)
    if start.status is Status.DEGENERATE:
        return failed("ml", Status.DEGENERATE, start.reason, ns, n)
    if not start.ok:
        alt = lse_point(lines)
        start = alt if alt.ok else start
    return np.array(start.position_mm, dtype=float)      # a copy


def ml_point(lines: ViewLines, config: MLConfig = MLConfig(), x0_mm: ArrayLike | None = None) -> GazeEstimate:
    """Maximum-likelihood gazed point from view lines with Gaussian angular noise.

    Levenberg-Marquardt on the gnomonic residuals, started from the geometric least-squares
    point (or ``x0_mm``). Robust losses are iteratively reweighted per binocular sample
    (``lines.sample_index``). The covariance is ``sigma^2 (J^T W J)^-1`` at the optimum: the
    inverse Fisher information, which the estimate attains for well-conditioned geometries; with
    ``config.error_model`` it is that model's (``errormodel.model_covariance``).

    Returns:
        ``GazeEstimate`` with method ``ml``; ``info`` holds ``iterations``,
        ``residual_rms_deg``, (robust losses) ``inlier_weight_mean`` and (with an error model)
        ``error_model``, what the model found (its ``note`` says when the residuals inflated it).
    """
    n = len(lines)
    ns = _n_samples(lines)
    if n < 2:
        return failed("ml", Status.INSUFFICIENT, f"needs at least 2 view lines, got {n}", ns, n)
    x = _ml_start(lines, x0_mm, ns, n)
    if isinstance(x, GazeEstimate):
        return x
    problem = _MLProblem(lines, config, ns)
    x, it, converged = _levenberg_marquardt(problem, x, config)
    r, H, _ = problem.normal_equations(x)
    if np.linalg.cond(H) > 1e14:
        return failed("ml", Status.DEGENERATE, "the view lines do not fix a point (information matrix singular)", ns, n)
    cov = np.linalg.inv(H)
    info = {"iterations": it, "converged": bool(converged),
            "residual_rms_deg": float(np.rad2deg(np.sqrt(np.mean(np.sum(r * r, axis=1) / 2))))}
    if config.loss != "gaussian":
        info["inlier_weight_mean"] = float(np.mean(problem.line_w))
    if config.error_model is not None:
        model_cov, info["error_model"] = model_covariance(x, lines, problem.sigma, config.error_model, problem.line_w)
        info["error_model"].pop("bias_cov", None)
        info["error_model"].pop("linear_cov", None)
        cov = model_cov if model_cov is not None else cov
    log.debug("ml: %d lines, %d iterations, converged %s, residual RMS %.3f deg", n, it, converged,
              info["residual_rms_deg"])
    return _point_result("ml", x, cov, lines, info)


def perturb_directions(directions: ArrayLike, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Sample the noise model: unit directions (N, 3) with Gaussian tangent-plane errors of
    standard deviation ``sigma_rad`` per axis added to the unit directions (N, 3) given."""
    d = check_points(directions, "directions")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    b1, b2 = tangent_basis(d)
    n = rng.normal(0.0, sigma_rad, size=(len(d), 2))
    out = d + n[:, [0]] * b1 + n[:, [1]] * b2
    return out / np.linalg.norm(out, axis=1, keepdims=True)
