"""Moving targets: what a fixation's view lines looked at (one static point, a moving point
followed by smooth pursuit, or two static points with a switch between them) and the path of a
moving point.

Every model here is a path of the gazed point sampled at knots, linear between them, fitted to
the view lines by Gauss-Newton on the angular noise model of ``estimator.likelihood``: each line
at time ``t`` gives the two gnomonic residuals ``r`` of the path's point ``p(t)``, with
``chi2 = sum |r|^2 / sigma^2``.

- static point: one knot (3 parameters), its chi2 the lesser of the plain fit's and the fit with
  each eye's calibration offsets marginalised (``estimator.merge.offset_chi2``, the merge test's
  model): an eye calibration's bias seen from a walking head makes a static point's lines miss
  each other as a moving point's would (on simulated walking sessions 6 of 10 static fixations
  called moving were so);
- constant-velocity point: two knots at the first and last line (6 parameters);
- two static points: one knot before a switch time, one after, the switch time searched (7);
- the moving point's path (``smooth_trajectory``): knots every ``knot_s`` seconds with a
  smoothness prior, white acceleration of ``accel_mm_s2`` (the second difference of the knots
  over the knot spacing squared, scaled so the prior does not depend on the spacing). Its
  covariance is the inverse of the Gauss-Newton information (data and prior), so each knot's
  (3, 3) block is the marginal covariance of the path there (an RTS smoother over the same
  linear-Gaussian model gives the same marginals).

``classify_lines`` compares the three models by the Bayesian information criterion on the
angular likelihood (``chi2 + k ln n``, ``n`` the number of residual components). The noise of
real fits is over-dispersed (eye-calibration error and head-pose error are not white), so the
chi2 values are first divided by the over-dispersion of the richest model (its chi2 per degree
of freedom, at least 1): the models are compared on the scatter the data show, not on the
nominal ``sigma``. Pure maths on arrays: world frame, mm and s.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .errormodel import ErrorModel, bias_floor
from .frames import tangent_basis
from .likelihood import gnomonic_residuals
from .lines import BinocularSamples, ViewLines
from .merge import offset_chi2
from .triangulation import nearest_point_to_lines

log = logging.getLogger(__name__)

STATIC, MOVING, TWO_POINTS = "static", "moving", "two-points"
PATH = "path"
MODEL_PARAMS = {STATIC: 3, MOVING: 6, TWO_POINTS: 7}
MIN_LINES = 12
"""Fewer lines than this are always called static (no test has the power to say more)."""
MIN_SWEEP_DEG = 4.0
"""A moving point must sweep at least this angle as seen from the eyes: less is within a few
times the eye calibration's error (biases of up to 1.3 deg per eye in benchmarks/
moving_targets.py), which a walking head turns into apparent motion of a static point (at 2 deg,
4 % of static fixations there were called moving; at 3 deg, 1-2 %)."""
MIN_DEPTH_RATIO = 1.5
"""Two points must be ``MIN_SWEEP_DEG`` apart as seen from the eyes, or their distances from
the eyes differ by this ratio (a switch between a near and a far object along one line)."""
MIN_MOVING_S = 0.5
"""A fixation shorter than this is never called moving (too short to tell pursuit from a
saccade's tail)."""
DEFAULT_ACCEL_MM_S2 = 100.0
"""The smooth path's prior in the motion test, mm/s^2."""
ACCEL_GRID_MM_S2 = (30.0, 100.0, 300.0, 1000.0, 3000.0)
"""The priors ``smooth_trajectory`` chooses from by AIC when none is given, mm/s^2."""
DEFAULT_KNOT_S = 0.1
RADIAL_SPEEDS_MM_S = (300.0, 100.0, 30.0, 10.0)
"""Priors on the path's speed along the line of sight (RMS, mm/s) tried after the acceleration
prior is chosen, by BIC against none: depth is what vergence and parallax fix worst (a still head
2 m from a target sees its depth to about a metre per sample), and the acceleration prior leaves
a constant drift in depth free, so a path with it alone wanders in depth by hundreds of mm. AIC
cannot tell these apart (the data hardly fix depth); BIC keeps the stiffer depth unless the data
pay for the motion in depth."""
MAX_KNOTS = 200


@dataclass(frozen=True)
class MotionTest:
    """What ``classify_lines`` found.

    Attributes:
        kind: 'static', 'moving' or 'two-points'.
        bic: {kind: the model's BIC} (over-dispersion-scaled chi2 + k ln n).
        chi2: {kind: the model's chi2 at the nominal sigma}.
        dispersion: the over-dispersion factor the chi2 values were divided by (>= 1).
        split_t: the switch time of the two-point model, s (NaN when it was not fitted).
        points_mm: (2, 3) the two-point model's points (before, after the switch), mm.
        speed_mm_s: the constant-velocity model's speed, mm/s.
        n_lines: the view lines tested.
    """

    kind: str
    bic: dict
    chi2: dict
    dispersion: float
    split_t: float
    points_mm: np.ndarray
    speed_mm_s: float
    n_lines: int


@dataclass(frozen=True)
class Trajectory:
    """A moving point's path: positions at times, with their marginal covariances.

    Attributes:
        t_s: (K,) knot times, s, increasing.
        positions_mm: (K, 3) the path's points, world frame, mm.
        covariances_mm2: (K, 3, 3) each point's covariance, mm^2.
        chi2: the fit's chi2 (data part) at the nominal sigma.
        n_lines: the view lines fitted.
        accel_mm_s2: the smoothness prior's RMS acceleration (given, or chosen by AIC).
        dispersion: the chi2 per residual degree of freedom of the roughest path tried (>= 1);
            the covariances are scaled by it.
        radial_mm_s: the prior's RMS speed along the line of sight, mm/s (``RADIAL_SPEEDS_MM_S``
            chosen by BIC), or None (the acceleration prior alone).
    """

    t_s: np.ndarray
    positions_mm: np.ndarray
    covariances_mm2: np.ndarray
    chi2: float
    n_lines: int
    accel_mm_s2: float = DEFAULT_ACCEL_MM_S2
    dispersion: float = 1.0
    radial_mm_s: float | None = None

    def at(self, t_s) -> np.ndarray:
        """(M, 3) the path at times ``t_s`` (M,), linear between knots, held beyond the ends."""
        t = np.atleast_1d(np.asarray(t_s, float))
        return np.column_stack([np.interp(t, self.t_s, self.positions_mm[:, j]) for j in range(3)])

    def middle_knot(self) -> int:
        """The index of the knot nearest the middle time."""
        return int(np.argmin(np.abs(self.t_s - 0.5 * (self.t_s[0] + self.t_s[-1]))))

    def middle(self) -> tuple[np.ndarray, np.ndarray]:
        """The knot nearest the middle time: its position (3,) and covariance (3, 3)."""
        k = self.middle_knot()
        return self.positions_mm[k], self.covariances_mm2[k]


class _Lines:
    """Valid view lines of some samples with their times and tangent bases."""

    def __init__(self, samples: BinocularSamples):
        lines: ViewLines = samples.lines()
        self.lines: ViewLines | None = lines
        self.o, self.d = lines.origins_mm, lines.directions
        self.t = np.asarray(samples.t_s, float)[lines.sample_index]
        self.b1, self.b2 = tangent_basis(self.d) if len(lines) else (self.d, self.d)

    def __len__(self) -> int:
        return len(self.o)

    def subset(self, mask) -> _Lines:
        out = object.__new__(_Lines)
        out.lines = None
        out.o, out.d, out.t, out.b1, out.b2 = self.o[mask], self.d[mask], self.t[mask], self.b1[mask], self.b2[mask]
        return out


def _interp_weights(t, knots):
    """Each time's two knots (k0, k1) and weights (w0, w1) of linear interpolation (held at the ends)."""
    if len(knots) == 1:
        z = np.zeros(len(t), int)
        return z, z, np.ones(len(t)), np.zeros(len(t))
    k0 = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    a = np.clip((t - knots[k0]) / (knots[k0 + 1] - knots[k0]), 0.0, 1.0)
    return k0, k0 + 1, 1.0 - a, a


def _residuals(L: _Lines, p):
    """Residuals (N, 2) of each line at its own point p (N, 3) and their Jacobians (N, 2, 3).
    (``gnomonic_residuals`` at the point 0 with origins ``o - p``: ``u = p - o`` line by line.)"""
    r, a = gnomonic_residuals(np.zeros(3), L.o - p, L.d, L.b1, L.b2)
    J = np.stack([(L.b1 - r[:, :1] * L.d), (L.b2 - r[:, 1:] * L.d)], axis=1) / a[:, None, None]
    return r, J


def _smoothness_prior(knots, accel_mm_s2, radial_mm_s=None, axis=None):
    """Precision (3K, 3K) of the path's prior on K knots: white acceleration of RMS
    ``accel_mm_s2`` (0 for K < 3), and, with ``radial_mm_s``, a white velocity of that RMS along
    ``axis`` (a (3,) vector: the line of sight; 0 for K < 2): a depth that changes slowly."""
    K = len(knots)
    P = np.zeros((3 * K, 3 * K))
    if K >= 3 and np.isfinite(accel_mm_s2):
        D = np.zeros((K - 2, K))
        for k in range(K - 2):
            h0, h1 = knots[k + 1] - knots[k], knots[k + 2] - knots[k + 1]
            hm = 0.5 * (h0 + h1)
            # acceleration estimate at knot k+1; its integral over hm seconds is the prior's energy
            D[k, k], D[k, k + 1], D[k, k + 2] = 1 / (h0 * hm), -(1 / h0 + 1 / h1) / hm, 1 / (h1 * hm)
            D[k] *= math.sqrt(hm) / accel_mm_s2
        P += np.kron(D.T @ D, np.eye(3))
    if K >= 2 and radial_mm_s is not None and axis is not None:
        h = np.diff(knots)
        V = (np.eye(K, k=1)[:-1] - np.eye(K)[:-1]) / (np.sqrt(h)[:, None] * radial_mm_s)    # velocity x sqrt(h)
        u = np.asarray(axis, float) / np.linalg.norm(axis)
        P += np.kron(V.T @ V, np.outer(u, u))
    return P


def _fit_knots(L: _Lines, knots, sigma_rad: float, x0, prior=None, iterations: int = 20):
    """Gauss-Newton fit of knot points (K, 3) to the lines; returns (points, information (3K, 3K)
    with the prior, chi2 of the data at the nominal sigma)."""
    K = len(knots)
    k0, k1, w0, w1 = _interp_weights(L.t, knots)
    X = np.array(x0, float).reshape(K, 3)
    prior = np.zeros((3 * K, 3 * K)) if prior is None else prior
    lam = 1e-3

    def cost(Xc):
        r, _ = _residuals(L, w0[:, None] * Xc[k0] + w1[:, None] * Xc[k1])
        return float(np.sum(r * r)) / sigma_rad**2 + float(Xc.ravel() @ prior @ Xc.ravel())

    c = cost(X)
    for _ in range(iterations):
        H, g = _normal_equations(L, X, k0, k1, w0, w1, K, sigma_rad)
        H += prior
        g += prior @ X.ravel()
        scale = np.maximum(np.diag(H), 1e-12)
        while True:
            step = np.linalg.solve(H + lam * np.diag(scale), -g)
            Xn = X + step.reshape(K, 3)
            cn = cost(Xn)
            if cn <= c or lam > 1e8:
                break
            lam *= 10
        if cn > c:
            break
        done = c - cn < 1e-6 * max(c, 1.0)
        X, c, lam = Xn, cn, max(lam / 10, 1e-9)
        if done:
            break
    H, _ = _normal_equations(L, X, k0, k1, w0, w1, K, sigma_rad)
    r, _ = _residuals(L, w0[:, None] * X[k0] + w1[:, None] * X[k1])
    return X, H + prior, float(np.sum(r * r)) / sigma_rad**2


def _normal_equations(L, X, k0, k1, w0, w1, K, sigma_rad):
    """Gauss-Newton information (3K, 3K) and gradient (3K,) of the data term at knots X (K, 3)."""
    r, J = _residuals(L, w0[:, None] * X[k0] + w1[:, None] * X[k1])
    JtJ = np.einsum("nki,nkj->nij", J, J) / sigma_rad**2
    Jtr = np.einsum("nki,nk->ni", J, r) / sigma_rad**2
    return _scatter(K, k0, k1, w0, w1, JtJ, Jtr)


def _scatter(K: int, k0, k1, w0, w1, M, v):
    """Per-line blocks onto the knots: the path's point of line n is ``w0 X[k0] + w1 X[k1]``, so
    its (3, 3) block ``M[n]`` adds ``wa wb M[n]`` to knot pair (ka, kb) and its vector ``v[n]``
    adds ``wa v[n]`` to knot ka. Returns (3K, 3K) and (3K,)."""
    if K == 1:                                  # one knot (a static point): plain sums
        w = w0 + w1
        return np.einsum("n,nij->ij", w * w, M), np.einsum("n,ni->i", w, v)
    H = np.zeros((K, K, 3, 3))
    g = np.zeros((K, 3))
    for ka, wa in ((k0, w0), (k1, w1)):
        np.add.at(g, ka, wa[:, None] * v)
        for kb, wb in ((k0, w0), (k1, w1)):
            np.add.at(H, (ka, kb), (wa * wb)[:, None, None] * M)
    return H.transpose(0, 2, 1, 3).reshape(3 * K, 3 * K), g.ravel()


def _start_point(L: _Lines) -> np.ndarray:
    """A starting point: the nearest point to the lines when it is ahead of them, else 1 m along
    the mean direction."""
    if len(L) >= 2:
        e = nearest_point_to_lines(ViewLines(L.o, L.d))
        if e.ok and e.position_mm is not None and np.all(np.isfinite(e.position_mm)):
            return np.asarray(e.position_mm, float)
    d = L.d.mean(axis=0)
    return L.o.mean(axis=0) + 1000.0 * d / max(np.linalg.norm(d), 1e-12)


def _linear_start(L: _Lines, knots, sigma_rad: float, prior, x_static, rounds: int = 3) -> np.ndarray:
    """Knots (K, 3) minimising the perpendicular distances of the path's points to their lines,
    each divided by the point's distance from the eye (the angular error for small angles), with
    the prior: a linear problem, solved again with the distances of the last solution. The
    Gauss-Newton fit starts here (from a static point it can run off toward infinity, where a
    point sweeping in angle fits the lines without parallax)."""
    K = len(knots)
    k0, k1, w0, w1 = _interp_weights(L.t, knots)
    rho = np.maximum(np.linalg.norm(x_static - L.o, axis=1), 100.0)
    Pm = np.eye(3)[None] - L.d[:, :, None] * L.d[:, None, :]
    X = np.repeat(np.asarray(x_static, float).reshape(1, 3), K, axis=0)
    for _ in range(rounds):
        A = Pm / (sigma_rad * rho)[:, None, None] ** 2
        H, b = _scatter(K, k0, k1, w0, w1, A, np.einsum("nij,nj->ni", A, L.o))
        try:
            X = np.linalg.solve(H + prior, b).reshape(K, 3)
        except np.linalg.LinAlgError:
            break
        p = w0[:, None] * X[k0] + w1[:, None] * X[k1]
        rho = np.maximum(np.einsum("ij,ij->i", p - L.o, L.d), 100.0)
    return X


def _two_points(L: _Lines, sigma_rad: float, x_static, n_splits: int = 24):
    """The best switch time (between lines, at least 10 % of them each side; a coarse search
    over ``n_splits`` places, then every place between the coarse neighbours of the best):
    (chi2, switch time s, the two points (2, 3) mm)."""
    ts = np.sort(L.t)
    n = len(ts)
    margin = max(2, n // 10)
    best = (np.inf, np.nan, np.full((2, 3), np.nan))
    coarse = np.unique(np.linspace(margin, n - margin, n_splits).astype(int))
    step = int(np.max(np.diff(coarse))) if len(coarse) > 1 else 1
    tried = set()
    start = [x_static, x_static]
    for cand in (coarse, None):
        if cand is None:
            c0 = int(np.searchsorted(ts, best[1]))
            cand = np.arange(max(margin, c0 - step), min(n - margin, c0 + step) + 1)
        for c in cand:
            if c <= 0 or c >= n or ts[c] == ts[c - 1] or c in tried:
                continue
            tried.add(c)
            split = 0.5 * (ts[c - 1] + ts[c])
            pts, chi = [], 0.0
            for side, m in enumerate((L.t < split, L.t >= split)):
                # from the neighbouring split's point of this side (a few lines moved: a step or two)
                Xk, _, ck = _fit_knots(L.subset(m), np.zeros(1), sigma_rad, start[side], iterations=8)
                pts.append(Xk[0])
                chi += ck
            start = pts
            if chi < best[0]:
                best = (chi, split, np.array(pts))
        if not np.isfinite(best[0]):
            break
    return best


def classify_lines(samples: BinocularSamples, sigma_deg: float, accel_mm_s2: float | None = None,
                   knot_s: float | None = None) -> MotionTest:
    """Whether the view lines of one fixation looked at one static point, a moving point, or two
    static points (a switch inside the fixation): the model of least BIC on the angular
    likelihood (module docstring). A moving point must sweep ``MIN_SWEEP_DEG`` as seen from the
    eyes over at least ``MIN_MOVING_S``; two points, ``MIN_SWEEP_DEG`` apart or at distances
    ``MIN_DEPTH_RATIO`` apart. The moving point has two forms, constant velocity (6
    parameters) and the smooth path of ``smooth_trajectory`` (its effective number of parameters,
    the trace of the data's share of its information); either winning calls the lines moving.
    The chi2 values are divided by the smooth path's over-dispersion (its chi2 per residual
    degree of freedom, at least 1).

    Args:
        samples: the fixation's view lines (world frame, mm, s), in time order.
        sigma_deg: the nominal angular noise per tangent axis, degrees.
        accel_mm_s2, knot_s: the smooth path's prior and knot spacing (``smooth_trajectory``).

    Returns:
        ``MotionTest``; fewer than ``MIN_LINES`` lines are called static.
    """
    if not (np.isfinite(sigma_deg) and sigma_deg > 0):
        raise ValueError(f"sigma_deg must be positive, got {sigma_deg}")
    L = _Lines(samples)
    sigma = math.radians(sigma_deg)
    nan2 = np.full((2, 3), np.nan)
    if len(L) < MIN_LINES or L.t.max() <= L.t.min():
        return MotionTest(STATIC, {}, {}, 1.0, math.nan, nan2, 0.0, len(L))
    Xs, _, chi_s = _fit_knots(L, np.zeros(1), sigma, _start_point(L))
    chi_s = min(chi_s, offset_chi2(samples, Xs[0], sigma))         # the eyes' calibration offsets allowed
    knots = np.array([L.t.min(), L.t.max()])
    Xc, _, chi_c = _fit_knots(L, knots, sigma, _linear_start(L, knots, sigma, np.zeros((6, 6)), Xs[0]))
    chi_2, split, pts = _two_points(L, sigma, Xs[0])
    (_, Xp, _), chi_p, edf = _smooth_fit(L, sigma, accel_mm_s2 or DEFAULT_ACCEL_MM_S2, knot_s or DEFAULT_KNOT_S,
                                         Xs[0])
    n_obs = 2 * len(L)
    chi2 = {STATIC: chi_s, MOVING: chi_c, TWO_POINTS: chi_2, PATH: chi_p}
    params = MODEL_PARAMS | {PATH: edf}
    dispersion = max(1.0, min(chi2.values()) / max(n_obs - max(params.values()), 1.0))
    bic = {k: v / dispersion + params[k] * math.log(n_obs) for k, v in chi2.items()}
    eye = L.o.mean(axis=0)
    bic_kind = dict(bic)
    if sweep_deg(np.vstack([Xp, Xc]), eye) < MIN_SWEEP_DEG or knots[1] - knots[0] < MIN_MOVING_S:
        del bic_kind[MOVING], bic_kind[PATH]                    # no motion that matters
    depths = np.linalg.norm(pts - eye, axis=1)
    if not (sweep_deg(pts, eye) >= MIN_SWEEP_DEG or abs(math.log(depths[0] / depths[1])) >= math.log(MIN_DEPTH_RATIO)):
        del bic_kind[TWO_POINTS]                                # two points a calibration error could make
    best = min(bic_kind, key=lambda kind: bic_kind[kind])
    kind = MOVING if best == PATH else best
    speed = float(np.linalg.norm(Xc[1] - Xc[0]) / (knots[1] - knots[0]))
    log.debug("motion test on %d lines: %s (bic %s, dispersion %.2f)", len(L), kind, bic, dispersion)
    return MotionTest(kind, bic, chi2, dispersion, split, pts, speed, len(L))


def _path_bias_floor(L: _Lines, knots, X, Hi, model: ErrorModel) -> np.ndarray:
    """(3K, 3K) the bias floor of the path with knots ``X`` (K, 3): ``bias_floor`` with each
    line's Jacobian spread onto its two knots by the interpolation weights; ``Hi`` the inverse
    normal matrix in units of the residuals' Jacobian (the fit's covariance over sigma^2)."""
    K = len(knots)
    k0, k1, w0, w1 = _interp_weights(L.t, knots)
    _, J = _residuals(L, w0[:, None] * X[k0] + w1[:, None] * X[k1])
    Jp = np.zeros((len(L), 2, 3 * K))
    n = np.arange(len(L))
    for j in range(3):
        Jp[n, :, 3 * k0 + j] += w0[:, None] * J[:, :, j]
        Jp[n, :, 3 * k1 + j] += w1[:, None] * J[:, :, j]
    assert L.lines is not None                  # the caller's check: a subset carries no lines
    return bias_floor(Hi, Jp, L.lines, model)


def sweep_deg(points_mm, origin_mm) -> float:
    """The angle a set of points (M, 3) spans as seen from ``origin_mm`` (3,), degrees: the
    largest angle between the directions to two of them."""
    v = np.asarray(points_mm, float) - origin_mm
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
    return float(np.degrees(np.arccos(np.clip((v @ v.T).min(), -1.0, 1.0))))


_Fits = dict[tuple[float, float | None], tuple]
"""Smooth-path fits by (RMS acceleration, radial speed or None): ``_smooth_fit``'s results."""


def _smooth_fit(L: _Lines, sigma: float, accel_mm_s2: float, knot_s: float, x_static, radial_mm_s=None):
    """The smooth path's fit: (knots (K,), points (K, 3), covariance (3K, 3K)), its data chi2,
    and its effective number of parameters (the trace of cov @ data information). With
    ``radial_mm_s``, the prior also holds the speed along the line of sight (the lines' mean
    direction) to about that, mm/s."""
    t0, t1 = float(L.t.min()), float(L.t.max())
    K = int(min(MAX_KNOTS, max(2, math.ceil((t1 - t0) / knot_s) + 1)))
    knots = np.linspace(t0, t1, K) if t1 > t0 else np.array([t0])
    prior = _smoothness_prior(knots, accel_mm_s2, radial_mm_s, L.d.mean(axis=0))
    X, H, chi = _fit_knots(L, knots, sigma, _linear_start(L, knots, sigma, prior, x_static), prior)
    cov = np.linalg.pinv(H, hermitian=True)
    edf = float(np.trace(cov @ (H - prior)))
    return (knots, X, cov), chi, edf


def _converged(fits: _Fits) -> _Fits:
    """The fits that reached their optimum: a rougher prior's fits at least as well as a stiffer
    one's, so one worse than the stiffest ran off from its start (tests/test_motion.py)."""
    stiffest = fits[min(fits)][1]
    return {k: f for k, f in fits.items() if f[1] <= stiffest * (1.0 + 1e-6) + 1e-9}


def smooth_trajectory(samples: BinocularSamples, sigma_deg: float, accel_mm_s2: float | None = None,
                      knot_s: float = DEFAULT_KNOT_S, start_mm=None, error_model: ErrorModel | None = None
                      ) -> Trajectory:
    """The path of a moving gazed point from its view lines: knots every ``knot_s`` seconds
    (at most ``MAX_KNOTS``), linear between them, fitted with a white-acceleration smoothness
    prior (module docstring). Without ``accel_mm_s2`` the prior is chosen from
    ``ACCEL_GRID_MM_S2`` by AIC (``chi2 / dispersion + 2 * effective parameters``): a slow sweep
    gets a stiff path (its depth, which only vergence and parallax fix, averaged over seconds), a
    fast swing a supple one; then a speed prior along the line of sight (``RADIAL_SPEEDS_MM_S``)
    by BIC. The choices weigh the chi2 by the roughest path's scatter (its chi2 per degree of
    freedom: lines less noisy than ``sigma_deg`` say more); the covariances are scaled by it when
    it is above 1 (over-dispersion), never below.

    Args:
        samples: the view lines (world frame, mm, s), in time order; at least ``MIN_LINES``.
        sigma_deg: angular noise per tangent axis, degrees.
        accel_mm_s2: the prior's RMS acceleration, mm/s^2 (larger: a rougher path), or None.
        knot_s: the knot spacing, s.
        start_mm: optional (3,) starting point (else the nearest point to the lines).
        error_model: with a per-eye bias, each knot's covariance gets the path's bias floor
            (``estimator.errormodel.bias_floor``: each eye's lines all turned by one angle),
            which no smoothing averages down; None: noise alone.

    Returns:
        ``Trajectory``: knot times (K,), positions (K, 3), covariances (K, 3, 3).

    Raises:
        ValueError: too few lines, a non-positive sigma, spacing or acceleration.
    """
    for name, v in (("sigma_deg", sigma_deg), ("accel_mm_s2", 1.0 if accel_mm_s2 is None else accel_mm_s2),
                    ("knot_s", knot_s)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be positive, got {v}")
    L = _Lines(samples)
    if len(L) < MIN_LINES:
        raise ValueError(f"a trajectory needs at least {MIN_LINES} view lines, got {len(L)}")
    sigma = math.radians(sigma_deg)
    x0 = _start_point(L) if start_mm is None else np.asarray(start_mm, float)
    Xs, _, _ = _fit_knots(L, np.zeros(1), sigma, x0)
    grid = ACCEL_GRID_MM_S2 if accel_mm_s2 is None else (accel_mm_s2,)
    fits = _converged({(q, None): _smooth_fit(L, sigma, q, knot_s, Xs[0]) for q in sorted(grid)})
    _, chi_rough, edf_rough = fits[max(fits)]
    scatter = max(chi_rough / max(2 * len(L) - edf_rough, 1.0), 1e-3)     # the data's own, for choosing
    dispersion = max(1.0, scatter)                                       # never below sigma, for covariances

    def aic(key):
        return fits[key][1] / scatter + 2.0 * fits[key][2]
    key = min(fits, key=aic)
    if accel_mm_s2 is None:                 # then a speed prior along the line of sight, by BIC
        q = key[0]
        stiff: list[tuple[float, float | None]] = [(q, v) for v in RADIAL_SPEEDS_MM_S]
        fits.update({k: _smooth_fit(L, sigma, q, knot_s, Xs[0], k[1]) for k in stiff})
        key = min([key, *stiff], key=lambda k: fits[k][1] / scatter + math.log(2 * len(L)) * fits[k][2])
    (knots, X, cov), chi, _ = fits[key]
    full = cov * dispersion
    if error_model is not None and error_model.bias_deg > 0 and L.lines is not None:
        full = full + _path_bias_floor(L, knots, X, cov / sigma**2, error_model)
    blocks = np.stack([full[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k in range(len(knots))])
    log.debug("path over %d lines: prior %g mm/s^2, %s mm/s in depth, dispersion %.2f", len(L), *key, dispersion)
    return Trajectory(knots, X, blocks, chi, len(L), float(key[0]), float(dispersion), key[1])
