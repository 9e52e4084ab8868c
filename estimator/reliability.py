"""The voxel estimator's reliability weights: the posterior probability that a binocular sample
is no blink or saccade, given the posterior N(center, cov) of the gazed point (world frame, mm)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .likelihood import MAX_TAN2, angular_tan2, reliability_weight, reliability_weights

REJECTED_SHARE = 0.5
"""A box whose posterior weighs its kept samples at less than this share in all (the samples'
reliability weights, the probability that each is no blink or saccade, summed) is dropped and the
voxel estimator seeds again over every kept line. With a prior outlier fraction of
``VoxelConfig.outlier_prob`` (2 %), a majority of outliers means that the posterior is wrong,
not the samples: each sample is weighed when it comes, against the posterior then, so a box laid
from a few early lines that meet where no later line goes (one eye's first lines, from one
origin, meet near that eye; a still head's Tobii G3 fixation began so) would otherwise reject
every later line and keep its point."""


def reliability_weights_at(center_mm: ArrayLike, cov_mm2: ArrayLike, origins_mm: ArrayLike, directions: ArrayLike,
                           sample_index: ArrayLike, n_samples: int,
                           sigma_rad: float, outlier_prob: float) -> np.ndarray:
    """Reliability weight (n_samples,) of each binocular sample given the posterior N(center, cov).

    Each line's chi-square is its squared tangent residual at ``center_mm`` over the predictive
    variance ``sigma^2 + lateral / a^2``: the noise plus the posterior's mean spread across the line
    (``lateral = (trace cov - d^T cov d) / 2``) at distance ``a`` along it. A sample's chi-square sums
    its lines (2 degrees of freedom each); ``likelihood.reliability_weights`` turns it into the
    posterior probability of being an inlier. Samples without a line get weight 1.

    Args:
        center_mm: (3,) posterior mean, world, mm.  cov_mm2: (3, 3) posterior covariance, mm^2.
        origins_mm, directions: (L, 3) lines, world, mm and unit vectors.
        sample_index: (L,) int in [0, n_samples): the sample each line belongs to.
    """
    center = np.asarray(center_mm, float)
    cov = np.asarray(cov_mm2, float)
    o = np.asarray(origins_mm, float).reshape(-1, 3)
    d = np.asarray(directions, float).reshape(-1, 3)
    si = np.asarray(sample_index, int)
    v = center - o
    a = np.maximum(np.einsum("ij,ij->i", v, d), 1e-6 * np.sqrt(np.einsum("ij,ij->i", v, v)))
    tan2 = angular_tan2(center, o, d)[:, 0]
    lateral = 0.5 * (np.trace(cov) - np.einsum("ij,jk,ik->i", d, cov, d))
    chi2_line = tan2 / (sigma_rad**2 + np.maximum(lateral, 0) / (a * a))
    chi2_s = np.bincount(si, weights=chi2_line, minlength=n_samples)
    dof = 2.0 * np.bincount(si, minlength=n_samples)
    wts = reliability_weights(chi2_s, np.maximum(dof, 1), sigma_rad, outlier_prob)
    return np.where(dof > 0, wts, 1.0)


def reliability_weight_at(center_mm: np.ndarray, cov_mm2: np.ndarray, origins_mm: np.ndarray, directions: np.ndarray,
                          valid: np.ndarray, sigma_rad: float,
                          outlier_prob: float) -> float:
    """``reliability_weights_at`` for one binocular sample (origins and directions (2, 3), valid
    (2,) bool), in scalar arithmetic: the streaming hot path."""
    if not (valid[0] or valid[1]):
        return 1.0
    cx, cy, cz = np.asarray(center_mm, float).tolist()
    C = np.asarray(cov_mm2, float).tolist()
    tr = C[0][0] + C[1][1] + C[2][2]
    sig2 = sigma_rad**2
    chi2 = 0.0
    dof = 0.0
    for eye in (0, 1):
        if not valid[eye]:
            continue
        ox, oy, oz = origins_mm[eye].tolist()
        dx, dy, dz = directions[eye].tolist()
        vx, vy, vz = cx - ox, cy - oy, cz - oz
        s2 = vx * vx + vy * vy + vz * vz
        a = max(vx * dx + vy * dy + vz * dz, 1e-6 * math.sqrt(s2))
        tan2 = min(s2 / (a * a) - 1.0, MAX_TAN2)   # angular_tan2, in scalars
        dCd = (dx * (C[0][0] * dx + C[0][1] * dy + C[0][2] * dz) + dy * (C[1][0] * dx + C[1][1] * dy + C[1][2] * dz)
               + dz * (C[2][0] * dx + C[2][1] * dy + C[2][2] * dz))
        lateral = max(0.5 * (tr - dCd), 0.0)
        chi2 += tan2 / (sig2 + lateral / (a * a))
        dof += 2.0
    return reliability_weight(chi2, dof, sigma_rad, outlier_prob)
