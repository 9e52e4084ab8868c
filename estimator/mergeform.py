"""The merge test's chi2 of a target's lines kept as a quadratic form of bounded size (issue 27;
docs/processing.md, Merging), so that testing and adding a revisit costs the revisit's own lines,
not all the target's lines so far.

``estimator.merge.merge_statistic`` fits the pooled lines of a target and a fixation with each
eye's offsets marginalised (one shared by all fixations per eye, one per eye and fixation, one
per fixation shared by both eyes). Its chi2 is a least-squares problem in the point ``X`` and
the offsets. Linearised at a point ``x0`` (each line's gnomonic residual ``r_i + J_i dX``), the
offsets of each fixation of its own (per eye and fixation, per fixation) are eliminated there
(a Schur complement), which leaves a quadratic in ``dX`` (3) and the two eyes' shared offsets
(2 x 2): a ``MergeForm`` of 7 parameters, and the sum of two fixations' forms is their joint
one. A target keeps the sum of its fixations' forms; the fixation being tested is linearised
again at each Gauss-Newton step (its lines only). World frame, mm; offsets and residuals in
radians (small-angle tangents), chi2 in units of the angular noise ``sigma``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .frames import tangent_basis
from .likelihood import gnomonic_residuals
from .lines import BinocularSamples

N_PARAMS = 7
"""A form's parameters: dX (3, mm) from its centre, then the left and the right eye's shared
offset (2 each, radians)."""
GN_STEPS = 3
"""Gauss-Newton steps of a test, each linearising the tested fixation's lines again."""


@dataclass(frozen=True)
class MergeForm:
    """``chi2(x0 + dX, b) = c + 2 g . z + z^T N z`` with ``z = (dX, b)`` (7,): the merge test's chi2
    of some fixations' lines, their own offsets eliminated, linearised at ``x0``.

    Attributes:
        x0: (3,) the centre, world frame, mm.
        N: (7, 7) the normal matrix, chi2 per mm^2 / rad^2.
        g: (7,) half the gradient at the centre.
        c: the chi2 at the centre (the fixations' own offsets at their best).
        n_lines: the view lines it sums.
    """

    x0: np.ndarray
    N: np.ndarray
    g: np.ndarray
    c: float
    n_lines: int

    def centred(self, x_mm) -> MergeForm:
        """The same quadratic with its centre moved to ``x_mm`` (3,) (exact: a change of variable)."""
        s = np.zeros(N_PARAMS)
        s[:3] = np.asarray(x_mm, float) - self.x0
        return MergeForm(np.asarray(x_mm, float).copy(), self.N, self.g + self.N @ s,
                         float(self.c + 2 * self.g @ s + s @ self.N @ s), self.n_lines)

    def plus(self, other: MergeForm) -> MergeForm:
        """The sum of two forms, at this one's centre."""
        o = other.centred(self.x0)
        return MergeForm(self.x0, self.N + o.N, self.g + o.g, self.c + o.c, self.n_lines + o.n_lines)


def fixation_form(samples: BinocularSamples, x0_mm, sigma_rad: float, fixation_deg: float,
                  pose_deg: float) -> MergeForm:
    """The ``MergeForm`` of one fixation's view lines (world frame) linearised at ``x0_mm`` (3,)
    mm: its per-eye offsets (prior sd ``fixation_deg`` per axis) and its offset shared by both
    eyes (``pose_deg``; 0: none) eliminated; ``sigma_rad`` the angular noise."""
    x0 = np.asarray(x0_mm, float)
    # parameters: dX 0-2, shared offsets 3-6, this fixation's per-eye offsets 7-10, its pose 11-12
    n_all = 13
    N, g, c, n_lines = np.zeros((n_all, n_all)), np.zeros(n_all), 0.0, 0
    for eye, o, d, b1, b2 in _eye_lines(samples):
        r, a = gnomonic_residuals(x0, o, d, b1, b2)
        J = np.stack([(b1 - r[:, :1] * d), (b2 - r[:, 1:] * d)], axis=1) / a[:, None, None]     # (n, 2, 3)
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
    return MergeForm(x0, N[np.ix_(keep, keep)] - Nkl @ sol[:, :-1], g[keep] - Nkl @ sol[:, -1],
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
    common (prior sd ``bias_deg`` per axis), and each form's best point (3,) mm."""
    k = len(forms)
    n = 3 * k + 4
    N, g, c = np.zeros((n, n)), np.zeros(n), 0.0
    for j, f in enumerate(forms):
        idx = [3 * j, 3 * j + 1, 3 * j + 2, *range(3 * k, 3 * k + 4)]
        N[np.ix_(idx, idx)] += f.N
        g[idx] += f.g
        c += f.c
    N[3 * k:, 3 * k:] += np.eye(4) * np.deg2rad(bias_deg) ** -2
    z = -np.linalg.lstsq(N, g, rcond=None)[0]
    return float(c + g @ z), [f.x0 + z[3 * j:3 * j + 3] for j, f in enumerate(forms)]
