"""A target's credible region drawn as it is: a piece of the cone of its lines of sight.

Depth from vergence and parallax is Gaussian in inverse depth, not in depth (``errormodel``):
the 95 % interval of a distance is ``D / (1 +- z r)`` (``errormodel.depth_interval``), longer on
the far side, and has no far end when ``z r >= 1``. The Gaussian ellipsoid of the covariance is
symmetric about the point, so a far point's reaches behind the head (the demo's third target:
a 95 % semi-axis of 8.1 m, its interval 2.47-7.08 m). Across the line of sight the error is an
angle seen from the head, so the region widens with the distance.

The region is the set of points ``O + s v`` (``O`` the apex) with ``near <= s <= far`` (``far`` may be ``inf``)
and ``v`` a unit direction inside an elliptic cone about the line of sight ``u``: its angular
semi-axes ``half_angles_rad`` along the two unit vectors ``across`` (orthogonal to ``u``).
From a point estimate (``region_of_point``): the depth interval of the error model and the
covariance's lateral marginal (the 2x2 block across ``u``) at the same level, as angles at
the point's distance (each at the level asked: the two together hold about its square, depth
and lateral errors being nearly independent). From a direction alone (``region_of_direction``):
a circular cone.

Frames: whatever frame the inputs share (world, mm). Pure numpy; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

from .frames import tangent_basis

RING_POINTS = 24
"""Points on each ring of a drawn or meshed region (its cross-section at one distance)."""


@dataclass(frozen=True)
class CredibleRegion:
    """A credible region as a piece of the cone of sight (module docstring).

    Attributes:
        origin_mm: (3,) where the lines were seen from (the cone's apex), mm.
        direction: (3,) unit line of sight ``u`` (to the point, or the gaze direction).
        near_mm, far_mm: the distance interval from ``origin_mm``, mm; ``far_mm`` inf: no far end.
        across: (2, 3) unit vectors orthogonal to ``direction`` and to each other.
        half_angles_rad: (2,) the cone's angular semi-axes along ``across``, radians.
        probability: the level of the depth interval and of the lateral extent (each).
    """

    origin_mm: np.ndarray
    direction: np.ndarray
    near_mm: float
    far_mm: float
    across: np.ndarray
    half_angles_rad: np.ndarray
    probability: float

    @property
    def closed(self) -> bool:
        """The interval has a far end."""
        return math.isfinite(self.far_mm)

    def ring(self, distance_mm: float, n: int = RING_POINTS) -> np.ndarray:
        """(n, 3) points of the cross-section at ``distance_mm`` from the apex (each exactly that
        far from it), mm."""
        th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        t = np.tan(np.minimum(self.half_angles_rad, np.deg2rad(89.0)))
        v = (self.direction[None] + (t[0] * np.cos(th))[:, None] * self.across[0]
             + (t[1] * np.sin(th))[:, None] * self.across[1])
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return self.origin_mm + distance_mm * v

    def point_at(self, distance_mm: float) -> np.ndarray:
        """(3,) the point on the line of sight ``distance_mm`` from the apex, mm."""
        return self.origin_mm + distance_mm * self.direction


def _region(origin_mm: ArrayLike, direction: ArrayLike, near_mm: float, far_mm: float, across: ArrayLike,
            half_angles: ArrayLike, probability: float) -> CredibleRegion:
    """A ``CredibleRegion`` with ``(across[0], across[1], direction)`` right-handed."""
    u, e = np.asarray(direction, float).reshape(3), np.array(across, float).reshape(2, 3)
    if np.dot(np.cross(e[0], e[1]), u) < 0:
        e[1] = -e[1]
    return CredibleRegion(np.asarray(origin_mm, float).reshape(3), u, float(near_mm), float(far_mm), e,
                          np.asarray(half_angles, float).reshape(2), float(probability))


def region_of_point(point_mm: ArrayLike, covariance_mm2: ArrayLike, origin_mm: ArrayLike, near_mm: float, far_mm: float,
                    probability: float = 0.95) -> CredibleRegion | None:
    """The region of a point estimate seen from ``origin_mm``: its distance interval (``near_mm``,
    ``far_mm``: ``errormodel.depth_interval`` at ``probability``; ``far_mm`` inf or NaN: no far
    end) along the line of sight, and, across it, the ``probability`` ellipse of the
    covariance's 2D marginal in the plane orthogonal to the line of sight, turned into angles at
    the point's distance. None when nothing is defined (no covariance, the point at the origin,
    no near end).

    Args:
        point_mm: (3,) the estimate, mm.
        covariance_mm2: (3, 3) its covariance, mm^2 (a stretch along the line of sight, as
            ``errormodel.far_side``'s, leaves the lateral marginal unchanged).
        origin_mm: (3,) where its lines were seen from, mm.
        near_mm, far_mm: the distance interval, mm.
        probability: the level of the interval and of the lateral ellipse (each), in (0, 1).
    """
    X, apex = np.asarray(point_mm, float).reshape(3), np.asarray(origin_mm, float).reshape(3)
    if covariance_mm2 is None or not (np.all(np.isfinite(X)) and np.all(np.isfinite(apex))):
        return None
    C = np.asarray(covariance_mm2, float).reshape(3, 3)
    D = float(np.linalg.norm(X - apex))
    if not (D > 0 and np.all(np.isfinite(C)) and math.isfinite(near_mm) and near_mm >= 0):
        return None
    u = (X - apex) / D
    b = np.vstack(tangent_basis(u[None]))                                 # (2, 3) across u
    w, V = np.linalg.eigh(b @ (0.5 * (C + C.T)) @ b.T)                   # the lateral marginal, mm^2
    k = math.sqrt(chi2.ppf(probability, 2))
    half = np.arctan(k * np.sqrt(np.clip(w, 0.0, None)) / D)
    far = float(far_mm) if far_mm is not None and math.isfinite(far_mm) else math.inf
    return _region(apex, u, near_mm, far, V.T @ b, half, probability)


def region_of_direction(origin_mm: ArrayLike, direction: ArrayLike, half_angle_rad: float, near_mm: float = 0.0,
                        far_mm: float = math.inf, probability: float = 0.95) -> CredibleRegion | None:
    """The region of a direction without a point: a circular cone of ``half_angle_rad`` about the
    unit ``direction`` (3,) from ``origin_mm`` (3,) mm, between ``near_mm`` (0: from the apex)
    and ``far_mm`` (inf: no far end). None when the direction or the origin is not defined."""
    apex, d = np.asarray(origin_mm, float).reshape(3), np.asarray(direction, float).reshape(3)
    n = float(np.linalg.norm(d))
    if not (np.all(np.isfinite(apex)) and n > 0 and math.isfinite(n) and math.isfinite(half_angle_rad)):
        return None
    u = d / n
    near = float(near_mm) if near_mm is not None and math.isfinite(near_mm) and near_mm > 0 else 0.0
    far = float(far_mm) if far_mm is not None and math.isfinite(far_mm) else math.inf
    return _region(apex, u, near, far, np.vstack(tangent_basis(u[None])), [half_angle_rad, half_angle_rad], probability)


def ray_exit(origin_mm: ArrayLike, direction: ArrayLike, lo_mm: ArrayLike, hi_mm: ArrayLike) -> float:
    """The distance along the ray ``origin_mm + s direction`` (s >= 0) at which it leaves the
    box ``[lo_mm, hi_mm]`` ((3,) each, mm); 0 when the ray starts outside and never enters it."""
    apex, d = np.asarray(origin_mm, float), np.asarray(direction, float)
    lo, hi = np.asarray(lo_mm, float), np.asarray(hi_mm, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - apex) / d, (hi - apex) / d
    t_in = np.where(d != 0, np.minimum(a, b), np.where((apex >= lo) & (apex <= hi), -np.inf, np.inf))
    t_out = np.where(d != 0, np.maximum(a, b), np.where((apex >= lo) & (apex <= hi), np.inf, -np.inf))
    enter, leave = max(float(np.max(t_in)), 0.0), float(np.min(t_out))
    return leave if leave >= enter else 0.0


def region_mesh(region: CredibleRegion, reach_mm: float, n: int = RING_POINTS) -> tuple[np.ndarray, np.ndarray, int]:
    """The region as a triangle mesh: (vertices (V, 3) mm, faces (F, 3) outward, the number of
    vertices of the near end). The near cap's centre and its ring, the far ring (at ``far_mm``,
    or at ``reach_mm`` where the interval has no far end) and, for a closed interval, the far
    cap's centre. Every vertex is between ``near_mm`` and the far end from the apex."""
    far = region.far_mm if region.closed else max(float(reach_mm), region.near_mm)
    near_ring, far_ring = region.ring(region.near_mm, n), region.ring(far, n)
    V = [region.point_at(region.near_mm)[None], near_ring, far_ring]
    j = np.arange(n)
    a, b = 1 + j, 1 + (j + 1) % n                    # the near ring's consecutive vertices
    c, e = a + n, b + n                              # the far ring's
    F = [np.column_stack([np.zeros(n, int), b, a]),  # near cap, facing the apex
         np.column_stack([a, b, e]), np.column_stack([a, e, c])]
    if region.closed:
        V.append(region.point_at(far)[None])
        F.append(np.column_stack([np.full(n, 1 + 2 * n), c, e]))
    return np.concatenate(V), np.concatenate(F).astype(int), 1 + n
