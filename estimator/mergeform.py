"""The merge test's chi2 of a target's lines kept as a quadratic form of bounded size (issue 27;
docs/processing.md, Merging), so that testing and adding a revisit costs the revisit's own lines,
not all the target's lines so far.

``estimator.merge.merge_statistic`` fits the pooled lines of a target and a fixation with each
eye's offsets marginalised (one shared by all fixations per eye, one per eye and fixation, one
per fixation shared by both eyes). Its chi2 is a least-squares problem in the point and the
offsets. The point is taken in inverse-depth coordinates (``Chart``: two tangents and 1/depth
seen from the target's first fixation), in which each line's gnomonic residual is nearly linear
however far the point (a still head's vergence fixes 1/depth, not depth). Linearised at a point
``p0`` (each line's residual ``r_i + J_i dp``), the offsets of each fixation of its own (per eye
and fixation, per fixation) are eliminated there (a Schur complement), which leaves a quadratic
in ``dp`` (3) and the two eyes' shared offsets (2 x 2): a ``MergeForm`` of 7 parameters, and the
sum of two fixations' forms (one chart) is their joint one. A target keeps the sum of its
fixations' forms; the fixation being tested is linearised again at each Gauss-Newton step (its
lines only). World frame, mm; offsets and residuals in radians (small-angle tangents), chi2 in
units of the angular noise ``sigma``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .deprecation import renamed_kwargs
from .frames import tangent_basis
from .likelihood import gnomonic_residuals
from .lines import BinocularSamples

N_PARAMS = 7
"""A form's parameters: the point's chart coordinates from its centre (3: ``Chart``), then the
left and the right eye's shared offset (2 each, radians)."""
GN_STEPS = 3
"""Gauss-Newton steps of a test, each linearising the tested fixation's lines again."""
TINY_DEPTH_MM = 1e-3
"""A point this near the chart's plane (or behind it) is taken at this depth along its axis."""


@dataclass(frozen=True)
class Chart:
    """Inverse-depth coordinates ``p = (a, b, rho)`` of a point ``origin + R @ (a, b, 1) / rho``
    (``a``, ``b`` tangents, ``rho`` 1/mm; ``rho = 0`` at infinity). A line from ``o`` sees the
    point along ``R @ (a, b, 1) - rho (o - origin)``, linear in ``p``, so a line's residual is
    nearly linear in ``p`` however far the point and however parallel the lines (in ``X`` it is
    not: a still head's lines fix depth as ``1/depth``, and a quadratic in ``X`` fitted at one
    depth misjudges the chi2 at another by orders of magnitude).

    Attributes:
        origin: (3,) world frame, mm.
        R: (3, 3) columns: two axes across, then the axis of sight (world frame, orthonormal).
    """

    origin: np.ndarray
    R: np.ndarray

    @classmethod
    def toward(cls, origin_mm: ArrayLike, point_mm: ArrayLike) -> Chart:
        """The chart at ``origin_mm`` (3,) whose axis runs through ``point_mm`` (3,), mm."""
        o = np.asarray(origin_mm, float)
        axis = np.asarray(point_mm, float) - o
        axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0 else np.array([0.0, 0.0, 1.0])
        b1, b2 = tangent_basis(axis[None])
        return cls(o.copy(), np.column_stack([b1[0], b2[0], axis]))

    def coords(self, point_mm: ArrayLike) -> np.ndarray:
        """The chart coordinates (3,) of ``point_mm`` (3,) mm."""
        w = self.R.T @ (np.asarray(point_mm, float) - self.origin)
        z = max(w[2], TINY_DEPTH_MM)
        return np.array([w[0] / z, w[1] / z, 1.0 / z])

    def point(self, p: np.ndarray) -> np.ndarray:
        """The point (3,) mm of chart coordinates ``p`` (3,) (``rho > 0``)."""
        return self.origin + self.R @ np.array([p[0], p[1], 1.0]) / p[2]


@renamed_kwargs({"centred": "centered"})
@dataclass(frozen=True)
class MergeForm:
    """``chi2(p0 + dp, b) = c + 2 g . z + z^T N z`` with ``z = (dp, b)`` (7,): the merge test's
    chi2 of some fixations' lines, their own offsets eliminated, linearised at the point of chart
    coordinates ``p0``.

    Attributes:
        chart: the point's coordinates (``Chart``; forms summed share it).
        p0: (3,) the centre, chart coordinates.
        N: (7, 7) the normal matrix, chi2 per unit of ``p`` squared / rad^2.
        g: (7,) half the gradient at the centre.
        c: the chi2 at the centre (the fixations' own offsets at their best).
        n_lines: the view lines it sums.
    """

    chart: Chart
    p0: np.ndarray
    N: np.ndarray
    g: np.ndarray
    c: float
    n_lines: int

    def centered(self, p: np.ndarray) -> MergeForm:
        """The same quadratic with its centre moved to ``p`` (3,) (exact: a change of variable)."""
        s = np.zeros(N_PARAMS)
        s[:3] = np.asarray(p, float) - self.p0
        return MergeForm(self.chart, np.asarray(p, float).copy(), self.N, self.g + self.N @ s,
                         float(self.c + 2 * self.g @ s + s @ self.N @ s), self.n_lines)

    def plus(self, other: MergeForm) -> MergeForm:
        """The sum of two forms of one chart, at this one's centre."""
        if other.chart is not self.chart:
            raise ValueError("forms of two charts cannot be summed")
        o = other.centered(self.p0)
        return MergeForm(self.chart, self.p0, self.N + o.N, self.g + o.g, self.c + o.c,
                         self.n_lines + o.n_lines)


def fixation_form(samples: BinocularSamples, chart: Chart, p0: np.ndarray, sigma_rad: float, fixation_deg: float,
                  pose_deg: float) -> MergeForm:
    """The ``MergeForm`` of one fixation's view lines (world frame) linearised at the point of
    ``chart`` coordinates ``p0`` (3,): its per-eye offsets (prior sd ``fixation_deg`` per axis)
    and its offset shared by both eyes (``pose_deg``; 0: none) eliminated; ``sigma_rad`` the
    angular noise."""
    p0 = np.asarray(p0, float)
    ahead = chart.R @ np.array([p0[0], p0[1], 1.0])
    # parameters: dp 0-2, shared offsets 3-6, this fixation's per-eye offsets 7-10, its pose 11-12
    n_all = 13
    N, g, c, n_lines = np.zeros((n_all, n_all)), np.zeros(n_all), 0.0, 0
    for eye, o, d, b1, b2 in _eye_lines(samples):
        delta = o - chart.origin
        r, a = gnomonic_residuals(ahead, p0[2] * delta, d, b1, b2)         # along R (a, b, 1) - rho delta
        Jv = np.stack([(b1 - r[:, :1] * d), (b2 - r[:, 1:] * d)], axis=1) / a[:, None, None]    # (n, 2, 3)
        J = np.concatenate([Jv @ chart.R[:, :2], -np.einsum("nkj,nj->nk", Jv, delta)[:, :, None]], axis=2)
        slots = [3 + 2 * eye, 7 + 2 * eye, 11]              # the offsets this eye's lines carry
        JtJ, Jt = np.einsum("nki,nkj->ij", J, J), J.sum(axis=0).T                          # (3, 3), (3, 2)
        N[:3, :3] += JtJ
        g[:3] += np.einsum("nki,nk->i", J, r)
        rs = r.sum(axis=0)
        for s in slots:
            N[:3, s:s + 2] -= Jt
            N[s:s + 2, :3] -= Jt.T
            g[s:s + 2] -= rs
            for t in slots:
                N[s:s + 2, t:t + 2] += len(r) * np.eye(2)
        c += float(np.sum(r * r))
        n_lines += len(r)
    s2 = sigma_rad**2
    N, g, c = N / s2, g / s2, c / s2
    own = [7, 8, 9, 10] + ([11, 12] if pose_deg > 0 else [])
    prior = [np.deg2rad(fixation_deg) ** -2] * 4 + ([np.deg2rad(pose_deg) ** -2] * 2 if pose_deg > 0 else [])
    keep = list(range(N_PARAMS))
    K = N[np.ix_(own, own)] + np.diag(prior)
    Nkl = N[np.ix_(keep, own)]
    sol = np.linalg.solve(K, np.column_stack([Nkl.T, g[own]]))
    return MergeForm(chart, p0, N[np.ix_(keep, keep)] - Nkl @ sol[:, :-1], g[keep] - Nkl @ sol[:, -1],
                     float(c - g[own] @ sol[:, -1]), n_lines)


def _eye_lines(s: BinocularSamples) -> list:
    """The lines of each eye with any: [(eye 0 left / 1 right, origins (n, 3), directions (n, 3),
    b1, b2), ...]."""
    out = []
    for eye, (valid, o, d) in enumerate(((s.left_valid, s.left_origin_mm, s.left_direction),
                                         (s.right_valid, s.right_origin_mm, s.right_direction))):
        if valid.any():
            out.append((eye, o[valid], d[valid], *tangent_basis(d[valid])))
    return out


def least_chi2(forms: list, bias_deg: float) -> tuple[float, list]:
    """The least chi2 of forms each with a point of its own and the eyes' shared offsets in
    common (prior sd ``bias_deg`` per axis), each point at a finite or an infinite distance
    (``rho >= 0``: the search over points in the world reaches no farther), and each form's best
    point (3,) in its chart's coordinates."""
    k = len(forms)
    n = 3 * k + 4
    N, g, c = np.zeros((n, n)), np.zeros(n), 0.0
    for j, f in enumerate(forms):
        idx = [3 * j, 3 * j + 1, 3 * j + 2, *range(3 * k, 3 * k + 4)]
        N[np.ix_(idx, idx)] += f.N
        g[idx] += f.g
        c += f.c
    N[3 * k:, 3 * k:] += np.eye(4) * np.deg2rad(bias_deg) ** -2
    z = np.zeros(n)
    at_infinity = np.zeros(n, bool)
    for _ in range(k + 1):                     # an active set: a point beyond infinity is held there
        z[at_infinity] = [-forms[j].p0[2] for j in range(k) if at_infinity[3 * j + 2]]
        free = ~at_infinity
        z[free] = -np.linalg.lstsq(N[np.ix_(free, free)], g[free] + N[np.ix_(free, at_infinity)] @ z[at_infinity],
                                   rcond=None)[0]
        beyond = [3 * j + 2 for j in range(k) if forms[j].p0[2] + z[3 * j + 2] < 0 and not at_infinity[3 * j + 2]]
        if not beyond:
            break
        at_infinity[beyond] = True
    return float(c + 2 * g @ z + z @ N @ z), [f.p0 + z[3 * j:3 * j + 3] for j, f in enumerate(forms)]
