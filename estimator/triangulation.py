"""Closed-form triangulation of view lines: the paper's eq. 12 and its geometric counterpart."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike

from ._checks import check_points, normalize_directions
from .lines import ViewLines
from .result import GazeEstimate, Status, failed


class PairStatus(IntEnum):
    """Outcome of intersecting two lines."""

    OK = 0
    PARALLEL = 1   # the lines are (nearly) parallel: no finite closest point
    BEHIND = 2     # the closest points lie behind an eye (the lines diverge)


@dataclass(frozen=True)
class LinePairResult:
    """Closest points of N pairs of lines.

    Attributes:
        point_mm: (N, 3) midpoint of the common perpendicular (the point nearest both lines), mm;
            computed even for ``BEHIND`` pairs (not mirrored), NaN only for ``PARALLEL`` pairs.
        gap_mm: (N,) distance between the two lines, mm (their distance for parallel lines).
        distance1_mm, distance2_mm: (N,) signed distance of the closest points along each line, mm.
        status: (N,) ``PairStatus`` codes.
    """

    point_mm: np.ndarray
    gap_mm: np.ndarray
    distance1_mm: np.ndarray
    distance2_mm: np.ndarray
    status: np.ndarray


def closest_point_two_lines(origin1_mm: ArrayLike, direction1: ArrayLike, origin2_mm: ArrayLike, direction2: ArrayLike,
                            min_angle_rad: float = 1e-7) -> LinePairResult:
    """The point nearest two lines and the gap between them, batch-first.

    Args:
        origin1_mm, origin2_mm: (N, 3) line origins, mm.
        direction1, direction2: (N, 3) directions (normalised here).
        min_angle_rad: lines closer to parallel than this are reported ``PARALLEL``.

    Returns:
        ``LinePairResult``; pairs whose closest points lie behind either origin are ``BEHIND``.
    """
    o1, o2 = check_points(origin1_mm, "origin1_mm"), check_points(origin2_mm, "origin2_mm")
    d1, d2 = normalize_directions(direction1, "direction1"), normalize_directions(direction2, "direction2")
    w0 = o1 - o2
    b = np.einsum("ij,ij->i", d1, d2)
    dd = np.einsum("ij,ij->i", d1, w0)
    e = np.einsum("ij,ij->i", d2, w0)
    denom = 1.0 - b * b
    parallel = denom < np.sin(min_angle_rad) ** 2
    safe = np.where(parallel, 1.0, denom)
    s = np.where(parallel, np.nan, (b * e - dd) / safe)
    t = np.where(parallel, np.nan, (e - b * dd) / safe)
    p1 = o1 + s[:, None] * d1
    p2 = o2 + t[:, None] * d2
    perp = w0 - dd[:, None] * d1                      # for parallel lines: their distance
    gap = np.where(parallel, np.linalg.norm(perp, axis=1), np.linalg.norm(p1 - p2, axis=1))
    status = np.full(len(o1), PairStatus.OK, dtype=np.int64)
    status[~parallel & ((s < 0) | (t < 0))] = PairStatus.BEHIND
    status[parallel] = PairStatus.PARALLEL
    return LinePairResult(0.5 * (p1 + p2), gap, s, t, status)


def _n_samples(lines: ViewLines) -> int:
    assert lines.sample_index is not None          # ViewLines fills it in
    return int(len(np.unique(lines.sample_index)))


def lse_point(lines: ViewLines) -> GazeEstimate:
    """The paper's LSE method: eq. 12 stacked over all lines, solved by least squares, as written.

    Each line (e, d) contributes ``d_z x - d_x z = d_z e_x - d_x e_z`` and
    ``d_z y - d_y z = d_z e_y - d_y e_z``. These algebraic residuals scale with the distance
    from the line, so with noisy directions the solution is biased toward the eyes as depth grows
    (an errors-in-variables bias): reproduced here on purpose, it is the paper's baseline.
    """
    n = len(lines)
    if n < 2:
        return failed("lse", Status.INSUFFICIENT, f"needs at least 2 view lines, got {n}", _n_samples(lines), n)
    e, d = lines.origins_mm, lines.directions
    zeros = np.zeros(n)
    A = np.concatenate([np.column_stack([d[:, 2], zeros, -d[:, 0]]),
                        np.column_stack([zeros, d[:, 2], -d[:, 1]])])
    rhs = np.concatenate([d[:, 2] * e[:, 0] - d[:, 0] * e[:, 2], d[:, 2] * e[:, 1] - d[:, 1] * e[:, 2]])
    x, _, rank, sv = np.linalg.lstsq(A, rhs, rcond=None)
    if rank < 3 or sv[-1] < 1e-9 * sv[0]:
        return failed("lse", Status.DEGENERATE, "the view lines are (nearly) parallel: eq. 12 has no unique solution",
                      _n_samples(lines), n)
    return _point_result("lse", x, None, lines)


def nearest_point_to_lines(lines: ViewLines, weights: ArrayLike | None = None,
                           method: str = "geometric") -> GazeEstimate:
    """The point minimising the (weighted) sum of squared perpendicular distances to the lines, mm^2.

    Closed form ``sum_i w_i (I - d_i d_i^T) x = sum_i w_i (I - d_i d_i^T) e_i``. Unbiased for
    Gaussian errors across the lines, not for angular errors (those grow with distance), which is
    what the ML estimator models.

    Args:
        lines: N >= 2 view lines.
        weights: optional (N,) non-negative weights.
    """
    n = len(lines)
    if n < 2:
        return failed(method, Status.INSUFFICIENT, f"needs at least 2 view lines, got {n}", _n_samples(lines), n)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    d, e = lines.directions, lines.origins_mm
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = np.einsum("n,nij->ij", w, P)
    b = np.einsum("n,nij,nj->i", w, P, e)
    ev = np.linalg.eigvalsh(A)
    if ev[0] <= 1e-9 * max(ev[-1], 1e-300):
        return failed(method, Status.DEGENERATE, "the view lines are (nearly) parallel: no unique nearest point",
                      _n_samples(lines), n)
    return _point_result(method, np.linalg.solve(A, b), None, lines)


def _point_result(method: str, x: np.ndarray, cov: np.ndarray | None, lines: ViewLines,
                  info: dict | None = None) -> GazeEstimate:
    """OK, or BEHIND when the point lies behind most of the eyes (kept, not mirrored)."""
    ahead = np.einsum("ij,ij->i", x - lines.origins_mm, lines.directions)
    info = dict(info or {})
    info["fraction_behind"] = float(np.mean(ahead <= 0))
    if np.mean(ahead > 0) < 0.5:
        return GazeEstimate(method, Status.BEHIND, np.asarray(x, float), cov, _n_samples(lines), len(lines),
                            "the lines meet behind the eyes: the view directions diverge", info)
    return GazeEstimate(method, Status.OK, np.asarray(x, float), cov, _n_samples(lines), len(lines), "", info)
