"""Areas of interest in room coordinates and the probability that a fixation's gazed point lies
in each (issue 28; docs/aois.md).

A fixation's gazed point is uncertain, mostly along the line of sight: its depth is Gaussian in
inverse depth (vergence and parallax are angles), its direction in two angles about the line of
sight. ``GazeSpread`` holds that distribution; ``GazeSpread.sample`` draws points from it (one
fixed seed: the same points for every area, so that the probabilities of areas that split a
region add up to the region's, to the last sample). Each area claims the points it holds:

- a solid (``Box``, ``Sphere``, ``Mesh``: a closed triangle mesh) or a surface (``Polygon``: a
  flat polygon, also a marker's square or the plane of a set of markers) is opaque: it claims a
  point whose ray from the eyes meets it and that lies on it or behind it (no more than
  ``depth_tolerance_mm`` in front of where the ray meets it): what lies behind a poster, seen
  through the poster, is the poster; a gazed point estimated behind a cup, on a line through
  the cup, is on the cup. A point well in front of it is something else;
- a transparent volume (``transparent``: a region of space, "above the table") claims the points
  inside it.

A point claimed by several areas goes to the one met first along its ray (where the ray meets an
opaque area; a transparent one at the point's own distance). The probability of an area is its
share of the points; what no area claims is "none".

World frame, mm; angles in radians unless a name ends in ``_deg``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

from ._checks import check_points, check_vector
from ._open3d import import_open3d
from .frames import tangent_basis

SAMPLES = 20000
"""Points drawn per fixation: the probability of an area is within 0.4 % (one sd, at p = 0.5) of
its exact value."""
SEED = 0
"""The fixed seed of the draws: the same fixation gives the same probabilities."""
FAR_MM = 1e9
"""Where a point with no finite depth (inverse depth at or below zero) is put along its ray, mm."""
DEPTH_TOLERANCE_MM = 50.0
"""How far in front of a surface a point may lie and still be on it, mm (a marker board's or a
poster's thickness, and the depth at which a point in front is something else)."""
MAX_GAP_S = 0.075
"""The longest gap between a fixation's samples that is fixation time, s: longer ones (a blink,
lost tracking) are not. Tobii's I-VT filter fills gaps up to 75 ms by default and splits a fixation
at a longer one (Olsen 2012, *The Tobii I-VT Fixation Filter*, sec. 3.1.1)."""


@dataclass(frozen=True)
class GazeSpread:
    """The distribution of one fixation's gazed point.

    Attributes:
        origin_mm: (3,) where it was seen from (the eyes' mean position over the fixation), world, mm.
        direction: (3,) unit direction of the line of sight, world.
        inverse_depth_per_mm: the mean of the inverse distance from ``origin_mm``, 1/mm (0: the
            depth is unknown beyond ``near_mm``).
        inverse_depth_sd_per_mm: its sd, 1/mm.
        angular_cov_rad2: (2, 2) covariance of the direction's two angles about ``direction``
            (along ``tangent_basis(direction)``), rad^2.
        near_mm: no point nearer than this (0: none), mm; with ``inverse_depth_per_mm`` 0 the
            inverse depth is uniform on [1/far_mm, 1/near_mm] (a direction-only fixation: any depth
            in its interval, none preferred in inverse depth).
        far_mm: the far end of a direction-only fixation's depth interval, mm (inf: none).
    """

    origin_mm: np.ndarray
    direction: np.ndarray
    inverse_depth_per_mm: float
    inverse_depth_sd_per_mm: float
    angular_cov_rad2: np.ndarray
    near_mm: float = 0.0
    far_mm: float = math.inf

    @classmethod
    def from_covariance(cls, origin_mm: ArrayLike, point_mm: ArrayLike, covariance_mm2: ArrayLike) -> GazeSpread:
        """The spread of a point estimate ``point_mm`` (3,) mm with covariance (3, 3) mm^2 seen
        from ``origin_mm`` (3,) mm: the covariance's sd along the line of sight at distance D
        gives the inverse depth's sd (sd / D^2), its part across the line the angles' (/ D)."""
        o, p = check_vector(origin_mm, "origin_mm"), check_vector(point_mm, "point_mm")
        C = np.asarray(covariance_mm2, float).reshape(3, 3)
        v = p - o
        D = float(np.linalg.norm(v))
        if not D > 0:
            raise ValueError("the point lies at the origin: no line of sight")
        u = v / D
        E = _basis(u)
        return cls(o, u, 1.0 / D, math.sqrt(max(float(u @ C @ u), 0.0)) / D**2, E.T @ C @ E / D**2)

    @classmethod
    def direction_only(cls, origin_mm: ArrayLike, direction: ArrayLike, cone95_deg: float, near_mm: float,
                       far_mm: float = math.inf) -> GazeSpread:
        """A fixation whose lines fix a direction but not a depth: ``direction`` (3,) with its 95 %
        cone half-angle ``cone95_deg`` (the same sd on both angles), any depth between ``near_mm``
        and ``far_mm`` (inf: none), uniform in inverse depth."""
        d = check_vector(direction, "direction")
        sd = math.radians(cone95_deg) / math.sqrt(chi2.ppf(0.95, 2))
        return cls(check_vector(origin_mm, "origin_mm"), d / np.linalg.norm(d), 0.0, 0.0, np.eye(2) * sd**2,
                   float(near_mm), float(far_mm))

    def sample(self, n: int = SAMPLES, seed: int = SEED) -> np.ndarray:
        """(n, 3) points drawn from the distribution, world, mm (``FAR_MM`` away where the drawn
        inverse depth is not positive)."""
        rng = np.random.default_rng(seed)
        ang = rng.multivariate_normal(np.zeros(2), np.asarray(self.angular_cov_rad2, float), size=n,
                                      method="eigh")
        dirs = self.direction + ang @ _basis(self.direction).T
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        if self.inverse_depth_per_mm > 0:
            inv = self.inverse_depth_per_mm + self.inverse_depth_sd_per_mm * rng.standard_normal(n)
        else:
            inv = rng.uniform(1.0 / self.far_mm, 1.0 / self.near_mm if self.near_mm > 0 else 0.0, n)
        depth = np.full(n, FAR_MM)
        pos = inv > 1.0 / FAR_MM
        depth[pos] = 1.0 / inv[pos]
        if self.near_mm > 0:
            depth = np.maximum(depth, self.near_mm)
        return self.origin_mm + depth[:, None] * dirs


def fixation_duration_s(t_s: ArrayLike, interval_s: float, max_gap_s: float = MAX_GAP_S) -> float:
    """The time a fixation's samples stand for, s (docs/aois.md, "The measures"): each sample one
    sample interval, from half an interval before the first to half an interval after the last
    (Tobii Pro's convention: a one-sample fixation lasts one interval), a gap between consecutive
    samples counted whole up to ``max_gap_s`` and as one interval beyond it (a blink is not
    fixation time).

    Args:
        t_s: (N,) the fixation's sample times, s (any order; N = 0 gives 0).
        interval_s: the sample interval, s.
        max_gap_s: the longest gap counted whole, s.
    """
    t = np.sort(np.asarray(t_s, float).ravel())
    if not len(t):
        return 0.0
    gaps = np.diff(t)
    return float(interval_s + np.sum(np.where(gaps <= max_gap_s, gaps, interval_s)))


def sample_interval_s(t_s: ArrayLike) -> float:
    """The sample interval of sample times ``t_s`` (N,) s, any order: the median step between
    consecutive distinct times, s (NaN with fewer than two). The interval ``fixation_duration_s``
    counts a session's fixations at: every place that gives a fixation's or a target's duration
    takes it from all the session's view lines (``fixation_durations_s``)."""
    t = np.unique(np.asarray(t_s, float).ravel())
    return float(np.median(np.diff(t))) if len(t) > 1 else float("nan")


def fixation_durations_s(t_s: ArrayLike, labels: ArrayLike, fixations: Iterable[int]) -> np.ndarray:
    """The duration (``fixation_duration_s``) of each of ``fixations`` (K,) (labels), s, at the
    sample interval of all the samples (``sample_interval_s``).

    Args:
        t_s: (N,) every sample's time, s (a session's view lines).
        labels: (N,) each sample's fixation, -1 none.
        fixations: the fixation labels wanted (a fixation with no sample lasts 0 s).
    """
    t, lab = np.asarray(t_s, float).ravel(), np.asarray(labels).ravel()
    if t.shape != lab.shape:
        raise ValueError(f"t_s and labels must have the same shape, got {t.shape} and {lab.shape}")
    interval = sample_interval_s(t)
    return np.array([fixation_duration_s(t[lab == f], interval) for f in fixations], float)


def _rays(origin_mm: ArrayLike, pts_world: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) unit directions from ``origin_mm`` to each of ``pts_world`` and (N,) distances, mm."""
    v = np.asarray(pts_world) - np.asarray(origin_mm)
    dist = np.linalg.norm(v, axis=1)
    return v / np.maximum(dist, 1e-12)[:, None], dist


def _claim(entry: np.ndarray, hit: np.ndarray, dist: np.ndarray, tolerance_mm: float) -> np.ndarray:
    """An opaque area's claim: its ``entry`` distance (N,) where the ray ``hit`` it and the point
    (at ``dist``) lies no more than ``tolerance_mm`` in front of that; inf elsewhere."""
    return np.where(hit & (dist >= entry - tolerance_mm), entry, np.inf)


@dataclass(frozen=True)
class Box:
    """A box: centre (3,) mm, full size (3,) mm along its own axes, ``R_world_from_box`` (3, 3).
    ``transparent``: a region of space (claims the points inside it), not a solid object."""

    center_mm: np.ndarray
    size_mm: np.ndarray
    R_world_from_box: np.ndarray
    transparent: bool = False
    depth_tolerance_mm: float = DEPTH_TOLERANCE_MM

    def claim(self, origin_mm: ArrayLike, pts_world: ArrayLike) -> np.ndarray:
        """(N,) where along each point's ray from ``origin_mm`` the box claims it, mm (inf where it
        does not): a solid box where the ray enters it, when the point lies on or behind that
        (``depth_tolerance_mm``); a transparent one at the point's distance, when inside."""
        u, dist = _rays(origin_mm, pts_world)
        if self.transparent:
            local = (pts_world - self.center_mm) @ self.R_world_from_box
            return np.where(np.all(np.abs(local) <= 0.5 * self.size_mm, axis=1), dist, np.inf)
        o = (np.asarray(origin_mm, float) - self.center_mm) @ self.R_world_from_box
        ul = u @ self.R_world_from_box
        half = 0.5 * np.asarray(self.size_mm, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / ul, (half - o) / ul
        lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))      # a ray parallel to a slab: inside it or not
        hi = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
        inside = np.abs(o) <= half
        lo = np.where((ul == 0) & ~inside, np.inf, np.where(ul == 0, -np.inf, lo))
        hi = np.where((ul == 0) & inside, np.inf, hi)
        near, far = lo.max(axis=1), hi.min(axis=1)
        return _claim(np.maximum(near, 0.0), (near <= far) & (far > 0), dist, self.depth_tolerance_mm)


@dataclass(frozen=True)
class Sphere:
    """A ball: centre (3,) mm and radius mm; ``transparent`` and the tolerance as ``Box``'s."""

    center_mm: np.ndarray
    radius_mm: float
    transparent: bool = False
    depth_tolerance_mm: float = DEPTH_TOLERANCE_MM

    def claim(self, origin_mm: ArrayLike, pts_world: ArrayLike) -> np.ndarray:
        """As ``Box.claim``."""
        u, dist = _rays(origin_mm, pts_world)
        if self.transparent:
            return np.where(np.linalg.norm(pts_world - self.center_mm, axis=1) <= self.radius_mm, dist, np.inf)
        oc = np.asarray(origin_mm, float) - self.center_mm
        b = u @ oc
        disc = b * b - (oc @ oc - self.radius_mm**2)
        root = np.sqrt(np.maximum(disc, 0.0))
        return _claim(np.maximum(-b - root, 0.0), (disc >= 0) & (-b + root > 0), dist, self.depth_tolerance_mm)


@dataclass(frozen=True)
class Polygon:
    """An opaque flat polygon: ``corners_mm`` (K, 3) in order around it, on one plane (K >= 3),
    and how far in front of it a point may lie and still be on it."""

    corners_mm: np.ndarray
    depth_tolerance_mm: float = DEPTH_TOLERANCE_MM

    def __post_init__(self) -> None:
        c = check_points(self.corners_mm, "corners_mm")
        if len(c) < 3:
            raise ValueError(f"a polygon needs at least 3 corners, got {len(c)}")
        n = plane_normal(c)
        off = np.abs((c - c.mean(axis=0)) @ n)
        if off.max() > 1e-3 * max(1.0, float(np.ptp(c, axis=0).max())):
            raise ValueError(f"the polygon's corners are not on one plane (up to {off.max():.1f} mm off)")

    def claim(self, origin_mm: ArrayLike, pts_world: ArrayLike) -> np.ndarray:
        """(N,) the distance at which each point's ray from ``origin_mm`` crosses the polygon,
        where it does and the point lies on or behind it (no more than ``depth_tolerance_mm`` in
        front), mm; inf elsewhere."""
        c = np.asarray(self.corners_mm, float)
        n = plane_normal(c)
        u, dist = _rays(origin_mm, pts_world)
        den = u @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c[0] - origin_mm) @ n) / den
        ok = (np.abs(den) > 1e-12) & (t > 0)
        t = np.where(ok, t, 0.0)
        hit = origin_mm + t[:, None] * u
        E = _basis(n)
        ok &= _inside_2d((hit - c[0]) @ E, (c - c[0]) @ E)
        return _claim(t, ok, dist, self.depth_tolerance_mm)


@dataclass(frozen=True)
class Mesh:
    """A closed triangle mesh: ``vertices_mm`` (V, 3), ``faces`` (F, 3) vertex indices;
    ``transparent`` and the tolerance as ``Box``'s. Rays are cast with Open3D's
    ``RaycastingScene`` (a scanned object's thousands of triangles); inside is its occupancy."""

    vertices_mm: np.ndarray
    faces: np.ndarray
    transparent: bool = False
    depth_tolerance_mm: float = DEPTH_TOLERANCE_MM

    def _scene(self) -> Any:          # open3d.t.geometry.RaycastingScene
        o3d = import_open3d()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(self.vertices_mm, np.float32)),
                            o3d.core.Tensor(np.asarray(self.faces, np.uint32)))
        return o3d, scene

    def claim(self, origin_mm: ArrayLike, pts_world: ArrayLike) -> np.ndarray:
        """As ``Box.claim``."""
        o3d, scene = self._scene()
        u, dist = _rays(origin_mm, pts_world)
        if self.transparent:
            inside = scene.compute_occupancy(o3d.core.Tensor(np.asarray(pts_world, np.float32))).numpy() > 0.5
            return np.where(inside, dist, np.inf)
        o = np.asarray(origin_mm, float)
        if scene.compute_occupancy(o3d.core.Tensor(o[None].astype(np.float32))).numpy()[0] > 0.5:
            return _claim(np.zeros(len(u)), np.ones(len(u), bool), dist, self.depth_tolerance_mm)
        rays = np.hstack([np.broadcast_to(o, u.shape), u]).astype(np.float32)
        entry = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)
        return _claim(entry, np.isfinite(entry), dist, self.depth_tolerance_mm)


def _basis(direction: np.ndarray) -> np.ndarray:
    """(3, 2): ``tangent_basis`` of one unit direction (3,), its two vectors as columns."""
    b1, b2 = tangent_basis(direction)
    return np.column_stack([b1[0], b2[0]])


def plane_normal(corners_mm: ArrayLike) -> np.ndarray:
    """(3,) unit normal of the best plane through ``corners_mm`` (K, 3) (the least singular
    direction), sign arbitrary."""
    c = np.asarray(corners_mm, float)
    return np.linalg.svd(c - c.mean(axis=0))[2][-1]


def _inside_2d(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) whether each of ``pts`` (N, 2) lies inside the polygon ``poly`` (K, 2) (even-odd)."""
    x, y = pts[:, 0:1], pts[:, 1:2]
    x0, y0 = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.sum(crosses & (x < xc), axis=1) % 2) == 1


def probabilities(spread: GazeSpread, areas: Sequence[Box | Sphere | Polygon | Mesh], n: int = SAMPLES) -> np.ndarray:
    """(K + 1,) the probability that the fixation's gazed point lies in each of the ``areas``
    (K of ``Box``, ``Sphere``, ``Polygon``, ``Mesh``), and last that it lies in none. They sum to
    1: a point in several goes to the one its ray meets first."""
    pts = spread.sample(n)
    if not areas:
        return np.ones(1)
    claims = np.stack([a.claim(spread.origin_mm, pts) for a in areas])         # (K, n)
    first = np.argmin(claims, axis=0)
    claimed = np.isfinite(claims[first, np.arange(n)])
    out = np.bincount(first[claimed], minlength=len(areas)).astype(float) / n
    return np.append(out, 1.0 - out.sum())
