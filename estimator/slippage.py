"""The per-eye bias a session's own view lines show (the eye calibration's error and the glasses'
slippage after it): how each eye's residuals over a fixation sit off the fitted point beyond what
their noise explains.

Model. Over one group of lines (a fixation; or all the fixations of one target, so that revisits
from other places must agree too), every line of an eye is turned by one 2D angle ``beta_e``, in
axes fixed to the head (about the normal of the plane of the line and the eyes' baseline,
"vertical", and about the axis in that plane, "horizontal"), on top of independent noise. The
point fitted to the group absorbs what a point can; the rest stays in the residuals: in the
noise-whitened residuals ``r`` (each eye by its own residual spread in the group, so the assumed
``sigma`` does not enter) the eyes' sums ``q = B^T P r`` (``B`` the lines' membership of the 4
angles, ``P`` the fit's residual projector) have noise covariance ``S = B^T P B`` and mean
``S beta``.

The bias is one over the session (fixed to the head), so the groups pool: ``q = sum q_g``,
``S = sum S_g``. Along each eigenvector of ``S`` with eigenvalue ``lam`` the angles' component is
``z = v^T q / lam`` with noise variance ``1 / lam``; the directions the lines fix to
``WELL_SEEN_DEG`` or better count, and with each eye's angle's components of std ``s`` (per eye
and axis, the eyes independent)

    s^2 = mean over them of (z^2 - 1 / lam),     standard error sqrt(sum 2 / lam^2) / count

(negative: no bias seen, 0). A point absorbs the eyes' common turn (a lateral shift) and, from a
still head, the horizontal difference (depth); head travel and revisits let the lines fix the
eyes' vertical and horizontal differences, not the common turn. ``s`` rests on the directions
seen and takes the others alike (isotropy), which the report says: glasses that slip both eyes
alike show less than they have. Groups whose noise is far above the session's (a missed saccade,
a moving target) are left out (``OUTLIER_NOISE``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ._checks import check_same_rows
from .lines import BinocularSamples, ViewLines

MIN_GROUP_SAMPLES = 10
"""A group of lines is used when it has this many binocular samples."""

OUTLIER_NOISE = 2.5
"""A group whose residual spread exceeds this many times the median group's is left out."""

WELL_SEEN_DEG = 0.15
"""A combination of the eyes' angles counts as seen when the session's lines fix it to this
standard error (degrees) or better."""


@dataclass(frozen=True)
class SeenBias:
    """The per-eye bias the lines showed (``seen_bias``).

    Attributes:
        deg: per eye and axis std of the bias, degrees (0 when none was seen beyond the noise).
        se_deg: the standard error of ``deg`` from the noise alone, degrees (``deg`` 0: the
            largest bias the noise could hide, one standard error of ``s^2``).
        groups: groups of lines used.
        left_out: groups left out (too few samples, no fit, or noise far above the others').
        seen: how many of the 4 combinations of the eyes' angles the lines fixed
            (``WELL_SEEN_DEG``): ``deg`` rests on these alone (the others are taken alike).
    """

    deg: float
    se_deg: float
    groups: int
    left_out: int
    seen: int

    def record(self) -> dict:
        """A JSON-ready record (targets.json's ``error_model.seen``; null for an undefined figure)."""
        return {"deg": round(self.deg, 4), "se_deg": round(self.se_deg, 4) if math.isfinite(self.se_deg) else None,
                "groups": self.groups, "left_out": self.left_out, "seen": self.seen}


def seen_bias(samples: BinocularSamples, labels: ArrayLike) -> SeenBias:
    """The per-eye bias std (per axis, degrees) that the groups of view lines show, pooled over
    the session (module docstring).

    Args:
        samples: (N) world view lines, mm, in time order.
        labels: (N,) group of each sample (a fixation's or a target's index), -1 none.
    """
    labels = np.asarray(labels).reshape(-1)
    check_same_rows(labels, samples, "labels", "samples", "one entry per sample")
    sums, left_out = [], 0
    for k in np.unique(labels[labels >= 0]):
        t = group_sums(samples.select(np.flatnonzero(labels == k)))
        if t is None:
            left_out += 1
        else:
            sums.append(t)
    if sums:
        noise = np.array([t[2] for t in sums])
        keep = noise <= OUTLIER_NOISE * np.median(noise)
        left_out += int(np.sum(~keep))
        sums = [t for t, k in zip(sums, keep, strict=True) if k]
    if not sums:
        return SeenBias(0.0, float("nan"), 0, left_out, 0)
    q, S = sum(t[0] for t in sums), sum((t[1] for t in sums), np.zeros_like(sums[0][1]))
    lam, V = np.linalg.eigh(0.5 * (S + S.T))
    seen = lam > 1.0 / math.radians(WELL_SEEN_DEG) ** 2
    if not np.any(seen):
        return SeenBias(0.0, float("nan"), len(sums), left_out, 0)
    z, var = (V.T @ q)[seen] / lam[seen], 1.0 / lam[seen]
    s2 = float(np.mean(z**2 - var))
    se2 = float(math.sqrt(np.sum(2.0 * var**2)) / len(var))
    return SeenBias(math.degrees(math.sqrt(max(s2, 0.0))), math.degrees(math.sqrt(se2)), len(sums), left_out,
                    int(np.sum(seen)))


def group_terms(samples: BinocularSamples) -> tuple[float, float, float, float] | None:
    """``(q^T q, tr S, tr S^2, noise)`` of one group's binocular samples (module docstring;
    ``noise`` the RMS residual over both eyes, radians), or None (too few samples, or the lines
    do not fix a point)."""
    qs = group_sums(samples)
    if qs is None:
        return None
    q, S, noise = qs
    return float(q @ q), float(np.trace(S)), float(np.trace(S @ S)), noise


def group_sums(samples: BinocularSamples) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``(q, S, noise)`` of one group's binocular samples: the eyes' residual sums (4,) (left h,
    v, right h, v; in each eye's noise units per radian), their noise covariance (4, 4) and the
    RMS residual, radians (module docstring); None (too few samples, no fit)."""
    s = samples.select(samples.binocular)
    n = len(s)
    if n < MIN_GROUP_SAMPLES:
        return None
    o = np.concatenate([s.left_origin_mm, s.right_origin_mm])
    d = np.concatenate([s.left_direction, s.right_direction])
    eye = np.repeat([0, 1], n)
    v = np.cross(d, np.tile(s.right_origin_mm - s.left_origin_mm, (2, 1)))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    h = np.cross(v, d)
    X = _start_point(ViewLines(o, d))
    sig = np.ones(2)
    for _ in range(4):                     # Gauss-Newton in each eye's noise units, the noise re-estimated
        res = _residuals(X, o, d, h, v)
        if res is None:
            return None
        r, J = res
        sig = np.array([math.sqrt(np.sum(r[eye == e] ** 2) / max(2 * n - 1.5, 1.0)) for e in (0, 1)])
        w = 1.0 / sig[eye] ** 2
        H = np.einsum("n,nki,nkj->ij", w, J, J)
        if np.linalg.cond(H) > 1e12:
            return None
        X = X - np.linalg.solve(H, np.einsum("n,nki,nk->i", w, J, r))
    res = _residuals(X, o, d, h, v)
    if res is None:
        return None
    r, J = res
    w = 1.0 / sig[eye] ** 2
    H = np.einsum("n,nki,nkj->ij", w, J, J)
    BtJ = np.concatenate([np.einsum("n,nki->ki", w[eye == e], J[eye == e]) for e in (0, 1)])   # (4, 3)
    q = np.concatenate([np.sum(w[eye == e, None] * r[eye == e], axis=0) for e in (0, 1)])
    q = q - BtJ @ np.linalg.solve(H, np.einsum("n,nki,nk->i", w, J, r))     # what the point absorbs: out
    S = np.diag(np.repeat([n / sig[0] ** 2, n / sig[1] ** 2], 2)) - BtJ @ np.linalg.solve(H, BtJ.T)
    return q, S, float(math.sqrt(np.mean(r**2)))


def _residuals(X: np.ndarray, o: np.ndarray, d: np.ndarray, h: np.ndarray, v: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """Gnomonic residuals (N, 2) of the lines at ``X`` in the (h, v) axes, and their Jacobians
    (N, 2, 3); None when the point is behind an eye."""
    w = X - o
    a = np.einsum("ij,ij->i", w, d)
    if np.any(a <= 0):
        return None
    r = np.column_stack([np.einsum("ij,ij->i", w, h), np.einsum("ij,ij->i", w, v)]) / a[:, None]
    J = np.stack([(h - r[:, [0]] * d) / a[:, None], (v - r[:, [1]] * d) / a[:, None]], axis=1)
    return r, J


def _start_point(lines: ViewLines) -> np.ndarray:
    """The point (3,) nearest all lines in the least-squares sense, mm."""
    d, o = lines.directions, lines.origins_mm
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    return np.linalg.lstsq(P.sum(axis=0), np.einsum("nij,nj->i", P, o), rcond=None)[0]
