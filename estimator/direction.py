"""A fixation answered by its direction when its lines do not fix a point (issue 27): the
cyclopean gaze direction with its 95 % cone, and the interval of depths the lines allow, which
may have no far end.

Lines fix a direction long before they fix a depth: two eyes' rays that diverge by a small
vergence bias (a far target), one cyclopean line per sample from a still head (a 2D-only tracker,
Pupil Cloud's Timeseries export; a Tobii G3 without video) all say where the person looked, not
how far. ``gaze_direction`` gives that answer from the lines themselves:

- the direction: the mean over the fixation of each sample's cyclopean direction (the mean of
  its two eyes' unit directions, normalised, from the midpoint of its eyes; a lone eye's line
  as it is), seen from the mean of those origins;
- its 95 % cone (``cone95_deg``, the half-angle): the uncertainty of that mean direction, which
  sums (per tangent axis, as a 2x2 covariance) the data's angular spread of the samples'
  cyclopean directions about their mean divided by their number (times the variance factor of
  their lag-one correlation in time, as ``errormodel`` counts it), the calibration's per-eye
  bias (``ErrorModel.bias_deg``: each eye's lines turned by one 2D angle, the two eyes' angles
  correlated by ``bias_correlation``, seen through the cyclopean mean) and the head pose's offset
  over a fixation (``ErrorModel.pose_offset_deg``, shared by every line); the cone's half-angle is
  the 95 % radius of that 2D Gaussian along its longest axis (chi-square, 2 degrees of freedom;
  Student's when part of the bias was sized from the session's lines, ``ErrorModel.slip_dof``:
  the common turn it carries is known to their few degrees of freedom);
- its depth interval: inverse depth ``q`` along the direction fitted, with the direction's
  2D offset, to every eye line by least squares about the point at infinity (first order in
  ``q``: a line from ``e`` sees the point ``o + u / q`` at the angle ``q (o - e)`` across ``u``),
  its sd from the fit's residuals and the same bias and pose terms; the interval is symmetric in
  inverse depth at 95 %, cut to the physical range (in front of the eyes, not nearer than
  ``NEAR_POINT_MM``): its far end is ``inf`` when inverse depth 0 (a point at infinity) is
  inside it, and it is (``NEAR_POINT_MM``, ``inf``) when the lines hold no depth at all (one
  line per sample from a still head; lines seen from one place, ``ONE_VIEWPOINT_MM``: one eye
  from a still head, whose only parallax is its eye model's centre moving) or contradict every
  depth beyond the near point.

World frame, mm, radians inside; degrees at the boundary (``_deg`` names).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import norm

from .errormodel import ErrorModel, _corr, eye_labels
from .errormodel_regions import region_radius
from .frames import tangent_basis
from .lines import BinocularSamples, ViewLines
from .result import NEAR_POINT_MM, ONE_VIEWPOINT_MM, GazeEstimate, Status, origin_spread_mm

if TYPE_CHECKING:                      # motion imports merge; at run time only the path's attributes are read
    from .motion import Trajectory

MIN_DIRECTION_SAMPLES = 3
"""The samples a direction needs: a mean and a 2D spread about it (2 degrees of freedom)."""
CONE_P = 0.95
"""The level of the cone and of the depth interval."""


@dataclass(frozen=True)
class GazeDirection:
    """Where a fixation looked when its depth is not known (``gaze_direction``).

    Attributes:
        origin_mm: (3,) where it was seen from: the mean of the samples' cyclopean origins,
            world frame, mm.
        unit: (3,) the mean cyclopean direction, world frame, unit.
        cone95_deg: the 95 % cone's half-angle about ``unit``, degrees.
        depth95_mm: (near, far) the 95 % interval of the distance from ``origin_mm``, mm; far
            ``inf`` when it has no far end.
        spread_deg: the samples' RMS angular spread about ``unit`` per axis, degrees (the data's
            part of the cone before it is divided by their number).
        n_samples: the samples it came from.
    """

    origin_mm: np.ndarray
    unit: np.ndarray
    cone95_deg: float
    depth95_mm: tuple
    spread_deg: float
    n_samples: int

    def contains(self, point_mm: ArrayLike) -> bool:
        """Whether the direction to ``point_mm`` (3,) world mm from ``origin_mm`` lies in the cone."""
        v = np.asarray(point_mm, float) - self.origin_mm
        cos = float(v @ self.unit) / max(float(np.linalg.norm(v)), 1e-300)
        return bool(np.degrees(math.acos(min(1.0, max(-1.0, cos)))) <= self.cone95_deg)

    def to_dict(self, decimals: int | None = None) -> dict:
        """JSON-ready (a ``direction`` of the target record): ``seen_from_mm``, ``unit``,
        ``cone95_deg``, ``depth95_mm`` [near, far or None], ``spread_deg``, ``n_samples``;
        ``decimals``: mm rounded to that many places (the live messages)."""
        def r(v: float, d: int | None) -> float:
            return float(v) if d is None else round(float(v), d)

        near, far = self.depth95_mm
        return {"seen_from_mm": [r(v, decimals) for v in self.origin_mm], "unit": [float(v) for v in self.unit],
                "cone95_deg": r(self.cone95_deg, 4), "depth95_mm": [r(near, decimals),
                                                                   r(far, decimals) if math.isfinite(far) else None],
                "spread_deg": r(self.spread_deg, 4), "n_samples": int(self.n_samples)}

    @classmethod
    def from_dict(cls, d: dict | None) -> GazeDirection | None:
        """The direction of a record's ``direction`` (``to_dict``), or None."""
        if not d:
            return None
        near, far = d["depth95_mm"]
        return cls(np.asarray(d["seen_from_mm"], float), np.asarray(d["unit"], float), float(d["cone95_deg"]),
                   (float(near), float("inf") if far is None else float(far)), float(d["spread_deg"]),
                   int(d["n_samples"]))


def cyclopean(samples: BinocularSamples) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's cyclopean line: origins (N, 3) mm and unit directions (N, 3), the mean of
    its two eyes (origins' midpoint, the directions' normalised sum) or its one valid eye's line;
    NaN rows for a sample with no valid eye."""
    both = samples.left_valid & samples.right_valid
    o = np.where(samples.left_valid[:, None], samples.left_origin_mm, samples.right_origin_mm)
    d = np.where(samples.left_valid[:, None], samples.left_direction, samples.right_direction)
    o[both] = 0.5 * (samples.left_origin_mm[both] + samples.right_origin_mm[both])
    s = samples.left_direction[both] + samples.right_direction[both]
    d[both] = s / np.linalg.norm(s, axis=1, keepdims=True)
    return o, d


def gaze_direction(samples: BinocularSamples, model: ErrorModel | None = None) -> GazeDirection | None:
    """The fixation's direction, its 95 % cone and depth interval (module docstring), from its
    samples (N,) (world frame, time order); None with fewer than ``MIN_DIRECTION_SAMPLES``
    samples carrying a line. ``model``: the bias and pose terms (None: the data's spread alone)."""
    o, d = cyclopean(samples)
    keep = np.all(np.isfinite(d), axis=1)
    if keep.sum() < MIN_DIRECTION_SAMPLES:
        return None
    o, d = o[keep], d[keep]
    n = len(d)
    m = d.mean(axis=0)
    u = m / np.linalg.norm(m)
    origin = o.mean(axis=0)
    b1, b2 = (b[0] for b in tangent_basis(u[None]))
    a = np.column_stack([d @ b1, d @ b2]) / (d @ u)[:, None]        # gnomonic offsets (N, 2), rad
    a0 = a.mean(axis=0)
    dev = a - a0
    spread = np.cov(dev.T, ddof=1) if n > 2 else np.zeros((2, 2))
    rho_t = _corr(dev[:-1], dev[1:], np.ones(n - 1))
    sys_var, slip_var = _systematic(samples.select(np.flatnonzero(keep)), model)
    C = spread * (1 + rho_t) / (1 - rho_t) / n + sys_var * np.eye(2)
    top = max(float(np.linalg.eigvalsh(C)[-1]), 0.0)
    # the common turn's part sized from the session's lines has their few degrees of freedom:
    # the cone is Student's (Welch-Satterthwaite along the widest axis; estimator.errormodel_regions)
    dof = (model.slip_dof / min(slip_var / top, 1.0) ** 2 if model is not None and slip_var > 0 and top > 0
           else math.inf)
    cone = math.degrees(math.sqrt(top) * region_radius(CONE_P, 2, dof))
    unit = u + a0[0] * b1 + a0[1] * b2                          # the mean offset back into the direction
    unit /= np.linalg.norm(unit)
    spread_deg = math.degrees(math.sqrt(max(float(np.trace(spread)) / 2.0, 0.0)))
    return GazeDirection(origin, unit, cone, depth_bounds(samples.select(np.flatnonzero(keep)), origin, unit, model),
                         spread_deg, n)


def point_direction(samples: BinocularSamples, point_mm: ArrayLike, covariance_mm2: ArrayLike,
                    origin_mm: ArrayLike | None = None, points_mm: ArrayLike | None = None,
                    probability: float = CONE_P) -> GazeDirection | None:
    """The direction of a point with its covariance, as its lines ``samples`` (N,) (world frame,
    time order) saw it: from ``origin_mm`` (3,) (None: the mean of the samples' cyclopean
    origins) toward ``point_mm`` (3,); the cone is the ``probability`` radius (2 degrees of
    freedom) of ``covariance_mm2`` (3, 3) across the line of sight, as an angle; the depth
    interval is the covariance along the line of sight, symmetric in inverse depth and cut at
    ``NEAR_POINT_MM`` (far ``inf`` when inverse depth 0 is inside it); ``spread_deg``: the
    samples' RMS angular offset per axis from ``points_mm`` (N, 3) (None: the point), each seen
    from its own cyclopean origin. A target with a point is answered by it; its direction is
    then where that point lies, not the mean of directions that a walking head turned by tens of
    degrees (tests/test_direction_only.py: 80 deg of walk around a point, the mean's cone over
    20 deg, the point's under 3). None with fewer than ``MIN_DIRECTION_SAMPLES`` samples
    carrying a line, or a point at the origin."""
    o, d = cyclopean(samples)
    keep = np.all(np.isfinite(d), axis=1)
    if keep.sum() < MIN_DIRECTION_SAMPLES:
        return None
    o, d = o[keep], d[keep]
    point, cov = np.asarray(point_mm, float), np.asarray(covariance_mm2, float)
    origin = o.mean(axis=0) if origin_mm is None else np.asarray(origin_mm, float)
    v = point - origin
    r = float(np.linalg.norm(v))
    if not (math.isfinite(r) and r > 0 and np.all(np.isfinite(cov))):
        return None
    u = v / r
    b1, b2 = (b[0] for b in tangent_basis(u[None]))
    B = np.stack([b1, b2])                                          # (2, 3)
    top = max(float(np.linalg.eigvalsh(B @ cov @ B.T)[-1]), 0.0) / (r * r)
    cone = math.degrees(math.sqrt(top) * region_radius(probability, 2))
    z = float(norm.ppf(0.5 + probability / 2.0))
    q, s = 1.0 / r, math.sqrt(max(float(u @ cov @ u), 0.0)) / (r * r)
    hi, lo = min(q + z * s, 1.0 / NEAR_POINT_MM), q - z * s
    depth = (1.0 / hi, 1.0 / lo if lo > 0 else float("inf"))
    seen = (point if points_mm is None else np.asarray(points_mm, float)[keep]) - o
    seen = seen / np.linalg.norm(seen, axis=1, keepdims=True)
    off = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", seen, d), -1.0, 1.0)))
    return GazeDirection(origin, u, cone, depth, float(np.sqrt(np.mean(off ** 2) / 2.0)), len(d))


def path_direction(samples: BinocularSamples, path: Trajectory, probability: float = CONE_P) -> GazeDirection | None:
    """A moving target's direction (its ``path``, ``estimator.motion.Trajectory``, fitted to
    ``samples`` (N,), world frame, time order): where the gaze pointed at the path's middle knot
    (``point_direction`` of that knot's point and covariance, seen from the samples' cyclopean
    origin at the knot's time, interpolated; ``spread_deg`` about the path at each sample's
    time). None as ``point_direction``."""
    o, d = cyclopean(samples)
    keep = np.all(np.isfinite(d), axis=1)
    if keep.sum() < MIN_DIRECTION_SAMPLES:
        return None
    t = np.asarray(samples.t_s, float)
    t_mid = float(path.t_s[path.middle_knot()])
    origin = np.array([np.interp(t_mid, t[keep], o[keep, j]) for j in range(3)])
    point, cov = path.middle()
    return point_direction(samples, point, cov, origin, path.at(t), probability)


def _systematic(samples: BinocularSamples, model: ErrorModel | None) -> tuple[float, float]:
    """(variance per axis, rad^2, of the mean cyclopean direction from each eye's bias (its weight
    in the mean: half a binocular sample's direction, a lone eye's whole) and the pose offset;
    the part of it from the bias's ``slip_deg``, the size the session's lines gave it)."""
    if model is None:
        return 0.0, 0.0
    both = samples.left_valid & samples.right_valid
    n = len(samples)
    w_left = (0.5 * both.sum() + (samples.left_valid & ~both).sum()) / n
    w_right = (0.5 * both.sum() + (samples.right_valid & ~both).sum()) / n
    b, p = math.radians(model.bias_deg), math.radians(model.pose_offset_deg)
    gain = w_left ** 2 + w_right ** 2 + 2 * model.bias_correlation * w_left * w_right
    return b * b * gain + p * p, math.radians(model.slip_deg) ** 2 * gain


def depth_bounds(samples: BinocularSamples, origin_mm: ArrayLike, unit: ArrayLike, model: ErrorModel | None,
                 probability: float = CONE_P) -> tuple[float, float]:
    """(near, far) mm: the ``probability`` interval of the distance along ``unit`` from
    ``origin_mm`` that the eye lines of ``samples`` allow (module docstring: inverse depth
    fitted about the point at infinity, symmetric in inverse depth, cut to in front of the eyes
    and beyond ``NEAR_POINT_MM``); far ``inf`` without a far end; (``NEAR_POINT_MM``, inf) when
    the lines hold no depth (seen from one place: ``ONE_VIEWPOINT_MM``) or none beyond the near
    point."""
    lines = samples.lines()
    if len(lines) and origin_spread_mm(lines.origins_mm) < ONE_VIEWPOINT_MM:
        return NEAR_POINT_MM, float("inf")
    b1, b2 = (b[0] for b in tangent_basis(np.asarray(unit, float)[None]))
    dd, e = lines.directions, lines.origins_mm
    a = np.column_stack([dd @ b1, dd @ b2]) / (dd @ unit)[:, None]          # (L, 2) rad
    c = np.column_stack([(origin_mm - e) @ b1, (origin_mm - e) @ b2])          # (L, 2) mm: d(angle)/dq
    J = np.zeros((len(a), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, :, 2] = c
    H = np.einsum("nki,nkj->ij", J, J)
    if len(a) < 4 or np.linalg.cond(H) > 1e12:
        return NEAR_POINT_MM, float("inf")
    Hi = np.linalg.inv(H)
    x = Hi @ np.einsum("nki,nk->i", J, a)
    r = a - np.einsum("nkj,j->nk", J, x)
    sigma2 = float(np.sum(r * r)) / max(2 * len(a) - 3, 1)
    rho_t = _corr(r[:-1], r[1:], np.ones(len(r) - 1))
    var_q = sigma2 * (1 + rho_t) / (1 - rho_t) * Hi[2, 2] + _bias_var_q(Hi, J, lines, model)
    z = float(norm.ppf(0.5 + probability / 2.0))
    q, s = float(x[2]), math.sqrt(max(var_q, 0.0))
    hi, lo = min(q + z * s, 1.0 / NEAR_POINT_MM), q - z * s
    if hi <= 0 or lo >= hi:          # every depth ahead (or beyond the near point) is rejected: the lines are off
        return NEAR_POINT_MM, float("inf")
    return 1.0 / hi, (1.0 / lo if lo > 0 else float("inf"))


def _bias_var_q(Hi: np.ndarray, J: np.ndarray, lines: ViewLines, model: ErrorModel | None) -> float:
    """The inverse depth's variance, mm^-2, from each eye's bias (all its lines turned by one 2D
    angle, the eyes' correlated by ``bias_correlation``) and the pose offset (every line turned)."""
    if model is None:
        return 0.0
    eye = eye_labels(lines)
    G = [Hi @ J[eye == k].sum(axis=0).T for k in (0, 1) if np.any(eye == k)]      # (3, 2) each
    b, p = math.radians(model.bias_deg), math.radians(model.pose_offset_deg)
    C = sum(g @ g.T for g in G)
    if len(G) == 2:
        C = C + model.bias_correlation * (G[0] @ G[1].T + G[1] @ G[0].T)
    g_all = Hi @ J.sum(axis=0).T
    return float(b * b * C[2, 2] + p * p * (g_all @ g_all.T)[2, 2])


UNANSWERED = ("degenerate", "insufficient-data", "behind")
"""The statuses of an estimate whose lines did not fix a point ahead of the eyes (parallel or
diverging rays, a density with no bounded peak, too few lines for a point): such a fixation is
answered by its direction (``with_direction``). ``too-near`` is not among them: its lines are
wrong (eye model, visual axes), not merely far; a near point of lines seen from one place is
``degenerate`` (``result.near_point_check``): no parallax, not wrong lines."""


def with_direction(e: GazeEstimate, samples: BinocularSamples, model: ErrorModel | None = None) -> GazeEstimate:
    """``e`` unchanged when it has a point (or its lines are wrong: ``too-near``), else, when its
    samples (N,) (world frame, time order) give a direction (``gaze_direction``), the estimate
    with ``Status.DIRECTION_ONLY``: no point, no covariance, ``direction`` set, the reason saying
    why there is no point; ``e`` when they give none (fewer than ``MIN_DIRECTION_SAMPLES``)."""
    if e.status.value not in UNANSWERED:
        return e
    g = gaze_direction(samples, model)
    if g is None:
        return e
    near, far = g.depth95_mm
    depth = (f"{near / 1000:.2f} m or more" if not math.isfinite(far)
             else f"{near / 1000:.2f}-{far / 1000:.2f} m")
    why = e.reason or e.status.value
    return GazeEstimate(e.method, Status.DIRECTION_ONLY, None, None, len(samples), len(samples.lines()),
                        f"the view lines fix a direction (95 % cone {g.cone95_deg:.2f} deg) but not a point ({why}); "
                        f"95 % depth interval {depth}", dict(e.info), g)
