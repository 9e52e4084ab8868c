"""Whether gaze rays hold one point in the world, for fixation segmentation (``estimator.segments``).

A person who fixates a point while the head moves keeps the gaze ray on it: the eyes counter-
rotate in the head (the vestibulo-ocular reflex), and as the head travels the ray's direction in
the world turns by the parallax (1 deg per 17 mm sideways at 1 m). So the test of a fixation in
the world is not a still direction but rays through one point: Hessels et al. (2018, "Is the
eye-movement field confused about fixations and saccades?", R. Soc. Open Sci. 5:180502) define
a fixation by the frame in which the gaze is still; for a head-free wearer fixating the world
that frame is the world, and the rays' common point is what stays still.

The fit: the rays' origins o_i (world, mm) and unit directions d_i; the point is
X = o_mean + u / rho, a unit direction u and an inverse depth rho in [0, 1 / ``NEAREST_MM``]
(rho 0: a point at infinity, the rays parallel), fitted by Gauss-Newton on the tangent-plane
angles. The residual of ray i is its angle to X as seen from o_i. Without head travel the depth
is free and the fit is the spread of the directions about their mean, the dispersion of
Salvucci & Goldberg's (2000, ETRA, "Identifying fixations and saccades in eye-tracking
protocols") I-DT in the world frame.

The noise (``measured_noise_deg``): per axis, one sample's angular sd, measured on the session's
own lines as the median spread of short windows about their best point (most windows lie inside
fixations, so the median is the fixations' spread; windows across a saccade are the minority).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

NEAREST_MM = 250.0
"""The nearest point a fixation holds, mm (the near point of the eye's accommodation in young
adults is about 100-250 mm): the fit's inverse depth is at most 1 / this."""
MAX_NOISE_WINDOWS = 2000
"""``measured_noise_deg`` uses at most this many windows, evenly spread over the session."""


def _basis(u: np.ndarray) -> np.ndarray:
    """(3, 2) two unit vectors orthogonal to unit u (3,) and to each other."""
    a = np.array([0.0, 1.0, 0.0]) if abs(u[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)], axis=1)


def hold_fit(origins_mm, directions, iterations: int = 3) -> tuple[np.ndarray, float, np.ndarray]:
    """The one point that rays (N,) hold best, and each ray's angle to it.

    Args:
        origins_mm: (N, 3) ray origins (the eyes' midpoint), world, mm.
        directions: (N, 3) unit gaze directions, world frame.

    Returns:
        (u (3,) the point's unit direction from the mean origin, rho the inverse depth, 1/mm, in
        [0, 1 / ``NEAREST_MM``], residuals (N,) degrees: each ray's angle to the point).
    """
    o = np.asarray(origins_mm, float)
    d = np.asarray(directions, float)
    rel = o - o.mean(axis=0)
    rho = 0.0
    u = d.mean(axis=0)
    u /= np.linalg.norm(u)
    for _ in range(iterations):
        c = d + rho * rel
        c /= np.linalg.norm(c, axis=1, keepdims=True)
        u = c.mean(axis=0)
        u /= np.linalg.norm(u)
        B = _basis(u)
        t = (c @ B) / (c @ u)[:, None]
        p = rel @ B
        tc, pc = t - t.mean(axis=0), p - p.mean(axis=0)
        den = float((pc * pc).sum())
        if den <= 1e-9:
            break
        rho = float(np.clip(rho - (tc * pc).sum() / den, 0.0, 1.0 / NEAREST_MM))
    c = d + rho * rel
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    u = c.mean(axis=0)
    u /= np.linalg.norm(u)
    res = _residuals_deg(u, rho, rel, d)
    if rho > 0:                 # the head travelled: the point itself, refined (the fit above moves
        x = _refined_point(u / rho, rel, d, iterations)      # each ray's point along it)
        r_x = np.linalg.norm(x)
        if x @ u > NEAREST_MM:
            res_x = _residuals_deg(x / r_x, 1.0 / r_x, rel, d)
            if res_x @ res_x < res @ res:
                return x / r_x, 1.0 / r_x, res_x
    return u, rho, res


def _residuals_deg(u: np.ndarray, rho: float, rel: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(N,) angles, degrees, of directions d (N, 3) to the point u / rho from the mean origin,
    seen from origins ``rel`` (N, 3) (relative to the mean origin, mm)."""
    to_x = u[None, :] - rho * rel                       # from each origin toward X = o_mean + u / rho
    to_x /= np.linalg.norm(to_x, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(to_x * d, axis=1), -1.0, 1.0)))


def _refined_point(x: np.ndarray, rel: np.ndarray, d: np.ndarray, iterations: int) -> np.ndarray:
    """(3,) the point (relative to the mean origin, mm) nearest the rays (origins ``rel`` (N, 3),
    unit directions d (N, 3)) in angle: least squares on the perpendicular distances, each
    weighted by 1 / distance^2 from the point's previous estimate ``x`` (3,)."""
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    for _ in range(iterations):
        w = 1.0 / np.maximum(np.sum((x - rel) ** 2, axis=1), 1.0)
        A = np.einsum("n,nij->ij", w, P)
        if np.linalg.cond(A) > 1e8:
            break
        x = np.linalg.solve(A, np.einsum("n,nij,nj->i", w, P, rel))
    return x


def angles_to_point_deg(u, rho: float, origin_mm, origins_mm, directions) -> np.ndarray:
    """(N,) angles, degrees, of rays (origins (N, 3) mm, unit directions (N, 3), world) to the
    point ``origin_mm + u / rho`` (``hold_fit``'s u and rho, its rays' mean origin (3,) mm)."""
    rel = np.asarray(origins_mm, float) - np.asarray(origin_mm, float)
    return _residuals_deg(np.asarray(u, float), float(rho), rel, np.asarray(directions, float))


def hold_rms_deg(origins_mm, directions) -> float:
    """The root mean square angle, degrees, of rays (N,) to the one point they hold best
    (``hold_fit``)."""
    return float(np.sqrt(np.mean(hold_fit(origins_mm, directions)[2] ** 2)))


def measured_noise_deg(origins_mm, directions, n: int) -> float | None:
    """One sample's angular noise, degrees per axis, measured on rays (N,) in time order: over
    windows of ``n`` consecutive rays (at most ``MAX_NOISE_WINDOWS``, evenly spread), the median
    sum of squared residuals about each window's point (``hold_fit``) over the median of its
    chi-square distribution (2 n - 3 degrees of freedom: two angles per ray, less the point's
    direction and depth). None with fewer than ``n`` rays or ``n`` < 3."""
    o = np.asarray(origins_mm, float)
    d = np.asarray(directions, float)
    if n < 3 or len(d) < n:
        return None
    starts = np.unique(np.linspace(0, len(d) - n, min(MAX_NOISE_WINDOWS, len(d) - n + 1)).astype(int))
    ss = [float(np.sum(hold_fit(o[s:s + n], d[s:s + n])[2] ** 2)) for s in starts]
    return float(np.sqrt(np.median(ss) / chi2.ppf(0.5, 2 * n - 3)))
