"""The regions of a point fitted under the error model (``estimator.errormodel``): its covariance
stretched along the line of sight (depth from vergence and parallax is Gaussian in inverse depth,
``far_side``), the region at any level (``at_level``) and the depth interval (``depth_interval``),
and what an estimate keeps to draw them (``Sight``).

A covariance whose scale rests in part on a bias estimated from few combinations of the eyes'
angles (``ErrorModel.slip_dof``) is known to that many degrees of freedom (``scale_dof``,
Welch-Satterthwaite: ``model_covariance``): its regions are Student's (the region at level ``p``
in ``n`` dimensions is ``n F(n, dof; p)`` in squared Mahalanobis distance, not ``chi2(n; p)``) and
its depth intervals take ``t(dof)``'s quantile, not the normal's. The covariance itself (the
scale) stays: its median squared distance hardly moves, its tails do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2, norm
from scipy.stats import f as f_dist
from scipy.stats import t as t_dist

FAR_SIDE_CAP = 10.0
"""The largest depth stretch ``far_side`` applies (a point whose far side has no end is
``unresolved`` anyway)."""


def far_side(C: np.ndarray, point_mm: ArrayLike, origin_mm: ArrayLike, k: float) -> tuple[np.ndarray, float]:
    """The covariance (3, 3) stretched along the line of sight so that its depth interval reaches
    the far end of the interval that is symmetric in inverse depth, and the stretch.

    Depth from vergence and parallax is Gaussian in inverse depth (angles), not in depth: a point
    estimated too near has a truth farther away than its linearised sd says (the sd, evaluated at
    the estimate, shrinks as depth squared), one estimated too far a truth nearer than it says.
    With ``r`` the relative depth sd, the interval of ``k`` sds in inverse depth ends at
    ``D / (1 - k r)`` on the far side; the depth sd is stretched by ``f = 1 / (1 - k r)`` so that
    ``k`` of its sds reach it (at most ``FAR_SIDE_CAP``). The near side is then wider than it
    needs to be. ``k`` = 0: unchanged.

    Args:
        C: (3, 3) covariance of the point, mm^2.
        point_mm, origin_mm: (3,) the point and the eyes' mean origin, world, mm.
        k: the interval's half-width in sds (``ErrorModel.far_side_k``).
    """
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    D = float(np.linalg.norm(v))
    if k <= 0 or not D > 0 or not np.all(np.isfinite(C)):
        return C, 1.0
    u = v / D
    f = _stretch(k, math.sqrt(max(float(u @ C @ u), 0.0)) / D)
    S = np.eye(3) + (f - 1.0) * np.outer(u, u)
    return S @ C @ S, float(f)


def sight_info(C_lin: np.ndarray, point_mm: ArrayLike, origin_mm: ArrayLike, k: float) -> dict:
    """What an estimate's ``info["error_model"]`` keeps so that its regions at any level can be
    drawn (``at_level``, ``depth_interval``): where its lines were seen from (``sight_origin_mm``,
    the eyes' mean origin, world, mm), the far side's ``k`` its covariance was stretched with,
    and ``depth_rel_sd``, the relative sd of its distance from there in the linearised
    covariance ``C_lin`` (3, 3) mm^2 (before the stretch; NaN when undefined). (The degrees of
    freedom of its scale, ``scale_dof`` and ``depth_dof``, are ``errormodel.region_dofs``'s.)"""
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    D = float(np.linalg.norm(v))
    r = math.sqrt(max(float(v @ np.asarray(C_lin, float) @ v), 0.0)) / D**2 if D > 0 else float("nan")
    return {"sight_origin_mm": [float(x) for x in np.asarray(origin_mm, float).reshape(3)], "far_side_k": float(k),
            "depth_rel_sd": float(r)}


@dataclass(frozen=True)
class Sight:
    """Where an estimate's view lines were seen from and how the error model shaped its
    covariance (``sight_info``): what its region at any level and its depth intervals are drawn
    from (``at_level``, ``depth_interval``).

    Attributes:
        origin_mm: (3,) the lines' mean origin, world frame, mm.
        far_side_k: the far side's ``k`` the covariance was stretched with (0: not stretched).
        depth_rel_sd: the linearised relative sd of the distance from ``origin_mm`` (NaN: none).
        scale_dof: the degrees of freedom of the covariance's scale (module docstring), for the
            3D regions; ``inf``: known, the regions are chi-square's.
        depth_dof: the same along the line of sight, for the depth intervals.
    """

    origin_mm: np.ndarray
    far_side_k: float
    depth_rel_sd: float
    scale_dof: float = math.inf
    depth_dof: float = math.inf

    @classmethod
    def from_info(cls, error_model_info: dict | None) -> Sight | None:
        """The sight kept in an estimate's ``info["error_model"]``, or None (no error model)."""
        em = error_model_info or {}
        if em.get("sight_origin_mm") is None:
            return None
        dof, ddof = (math.inf if em.get(key) is None else float(em[key]) for key in ("scale_dof", "depth_dof"))
        return cls(np.asarray(em["sight_origin_mm"], float), float(em["far_side_k"]), float(em["depth_rel_sd"]),
                   dof, ddof)

    def level_covariance(self, C: np.ndarray, point_mm: ArrayLike, probability: float) -> np.ndarray:
        """``at_level`` of the covariance ``C`` (3, 3) mm^2 of the point ``point_mm`` (3,) mm."""
        return at_level(C, point_mm, self.origin_mm, probability, self.far_side_k, self.depth_rel_sd,
                        scale_dof=self.scale_dof, depth_dof=self.depth_dof)

    def depth_interval(self, point_mm: ArrayLike, probability: float) -> tuple[float, float]:
        """``depth_interval`` of the point ``point_mm`` (3,) mm: (near, far) mm."""
        return depth_interval(point_mm, self.origin_mm, probability, self.depth_rel_sd, self.depth_dof)

    def distance_mm(self, point_mm: ArrayLike) -> float:
        """The distance of ``point_mm`` (3,) from ``origin_mm``, mm."""
        return float(np.linalg.norm(np.asarray(point_mm, float) - self.origin_mm))


def _stretch(k: float, r: float) -> float:
    """``far_side``'s stretch ``1 / (1 - k r)``, at most ``FAR_SIDE_CAP``."""
    return FAR_SIDE_CAP if k * r >= 1.0 - 1.0 / FAR_SIDE_CAP else 1.0 / (1.0 - k * r)


def region_radius(probability: float, dof: int = 3, scale_dof: float = math.inf) -> float:
    """The radius, in sds, of the ``probability`` region in ``dof`` dimensions: ``sqrt(chi2(dof;
    p))``, or ``sqrt(dof F(dof, scale_dof; p))`` (Student's) when the covariance's scale has
    ``scale_dof`` degrees of freedom."""
    if math.isfinite(scale_dof) and scale_dof > 0:
        return math.sqrt(dof * f_dist.ppf(probability, dof, scale_dof))
    return math.sqrt(chi2.ppf(probability, dof))


def at_level(C: np.ndarray, point_mm: ArrayLike, origin_mm: ArrayLike, probability: float, k: float, rel_sd: float,
             dof: int = 3, scale_dof: float = math.inf, depth_dof: float = math.inf) -> np.ndarray:
    """The covariance (3, 3) mm^2 whose ``probability`` ellipsoid (chi2 with ``dof``) is the
    region of that level, from ``C``, the error model's covariance stretched by ``far_side``
    with ``k`` (the 95 % level's). The stretch that makes the 95 % region reach the far end of
    the 95 % interval in inverse depth makes a 68 % region too long (on the real Aria walk's
    0.5 s windows, a median 3.4 times): each level gets its own, with ``k_p = sqrt(chi2.ppf(p,
    dof))``. When the covariance's scale has few degrees of freedom (``Sight``) the region is
    Student's: across the line of sight its radius is ``region_radius(p, dof, scale_dof)``,
    along it ``region_radius(p, dof, depth_dof)`` (the stretch taken with that radius). ``C``
    unchanged when it was not stretched (``k`` 0) or nothing is defined, but for that radius.

    Args:
        C: (3, 3) covariance, mm^2 (``GazeEstimate.covariance_mm2``).
        point_mm, origin_mm: (3,) the point and where it was seen from, mm.
        probability: the region's level, in (0, 1).
        k, rel_sd: the far side's ``k`` and the linearised relative depth sd (``sight_info``).
        dof: 3 for a 3D region; 1 for an interval along the line of sight.
        scale_dof, depth_dof: the degrees of freedom of ``C``'s scale across and along the line
            of sight (``Sight``); ``inf``: known.
    """
    C = np.asarray(C, float)
    v = np.asarray(point_mm, float) - np.asarray(origin_mm, float)
    D = float(np.linalg.norm(v))
    q = math.sqrt(chi2.ppf(probability, dof))
    lateral = region_radius(probability, dof, scale_dof) / q
    if k <= 0 or not D > 0 or not math.isfinite(rel_sd):
        return C * lateral**2
    u = v / D
    kd = region_radius(probability, dof, depth_dof)
    along = _stretch(kd, rel_sd) / _stretch(k, rel_sd) * kd / q
    S = lateral * np.eye(3) + (along - lateral) * np.outer(u, u)
    return S @ C @ S


def depth_interval(point_mm: ArrayLike, origin_mm: ArrayLike, probability: float, rel_sd: float,
                   scale_dof: float = math.inf) -> tuple[float, float]:
    """The ``probability`` interval (near, far) of the distance of ``point_mm`` from
    ``origin_mm``, mm, symmetric in inverse depth (where vergence and parallax are Gaussian):
    ``D / (1 +- z r)`` with ``r = rel_sd`` the linearised relative depth sd (``sight_info``) and
    ``z`` the normal's quantile, or ``t(scale_dof)``'s when the scale has that many degrees of
    freedom; far is ``inf`` when the interval has no far end; (NaN, NaN) when ``r`` is undefined."""
    D = float(np.linalg.norm(np.asarray(point_mm, float) - np.asarray(origin_mm, float)))
    if not (D > 0 and math.isfinite(rel_sd)):
        return float("nan"), float("nan")
    q = 0.5 + probability / 2.0
    z = float(t_dist.ppf(q, scale_dof) if math.isfinite(scale_dof) and scale_dof > 0 else norm.ppf(q))
    return D / (1.0 + z * rel_sd), (D / (1.0 - z * rel_sd) if z * rel_sd < 1.0 else float("inf"))
