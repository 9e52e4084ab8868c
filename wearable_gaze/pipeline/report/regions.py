"""The targets' credible regions as the report and targets.ply draw them (docs/processing.md,
"The report"): the box the views are scaled to, the head path and the targets, not the regions
(a region whose far end is 40 m away would make the room a dot), and each region as lines
inside that box: its near end's cross-section, its far end's when the box holds it, the cone's
edges and its line of sight, cut at the box's edge with an arrow where it runs on past it, and
dashed where it has no far end (``estimator.region``). World frame, mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.region import RING_POINTS, CredibleRegion, ray_exit

BOX_MARGIN = 0.25
"""The box is the head path's and the targets' bounding box grown on every side by this share of
its largest side ..."""
BOX_MARGIN_MIN_MM = 500.0
"""... and by at least this, mm."""
SIDES = (0, RING_POINTS // 4, RING_POINTS // 2, 3 * RING_POINTS // 4)
"""The ring points the cone's four drawn edges run through (along +-``across[0]``, +-``across[1]``)."""


def scene_box(*point_sets) -> tuple[np.ndarray, np.ndarray]:
    """(lo (3,), hi (3,)) mm: the bounding box of the finite rows of ``point_sets`` ((K, 3) or
    (3,) each, None skipped: the head path, the targets' points, their paths and truth), grown by
    ``BOX_MARGIN`` of its largest side (at least ``BOX_MARGIN_MIN_MM``) on every side; about
    the origin without any point."""
    sets = [np.asarray(p, float).reshape(-1, 3) for p in point_sets if p is not None]
    pts = np.concatenate(sets) if sets else np.zeros((0, 3))
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        pts = np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    m = max(BOX_MARGIN * float(np.max(hi - lo)), BOX_MARGIN_MIN_MM)
    return lo - m, hi + m


def anchor_points(regions) -> np.ndarray:
    """(K, 3) mm: a point for the box of each region without a point of its own: its near end
    (a direction alone with a near end of 0 adds its apex)."""
    return np.array([r.point_at(r.near_mm) for r in regions if r is not None], float).reshape(-1, 3)


@dataclass(frozen=True)
class RegionLines:
    """A region as lines inside a box (world frame, mm).

    Attributes:
        rings: closed polylines (n, 3) each: the near end's cross-section, and the far end's when
            the box holds it.
        sides: (4, 2, 3) the cone's edges from the near end to the drawn end.
        axis: (2, 3) the line of sight from the near end to the drawn end.
        hull: (2n, 3) the near and the drawn end's rings (the region's outline seen from any
            side is their convex hull's).
        open: the interval has no far end (drawn dashed).
        cut: the drawn end is the box's edge, short of the far end (an arrow at ``axis[1]``).
        near_mm, far_mm: the interval (``far_mm`` inf: open); end_mm: the drawn end's distance.
    """

    rings: list
    sides: np.ndarray
    axis: np.ndarray
    hull: np.ndarray
    open: bool
    cut: bool
    near_mm: float
    far_mm: float
    end_mm: float


def region_lines(region: CredibleRegion, lo, hi) -> RegionLines:
    """``region`` drawn inside the box ``[lo, hi]`` ((3,) each, mm; a side may be +-inf, as the
    top view's height): from its near end to its far end or, nearer, where its line of sight
    leaves the box."""
    leave = ray_exit(region.origin_mm, region.direction, lo, hi)
    end = min(region.far_mm, leave) if leave > region.near_mm else region.near_mm
    cut = end < region.far_mm
    if not math.isfinite(end):                    # an unbounded box: no edge to draw to
        end = max(region.near_mm, 1.0) * 10.0
    near, far = region.ring(region.near_mm), region.ring(end)
    sides = np.stack([np.stack([near[k], far[k]]) for k in SIDES])
    axis = np.stack([region.point_at(region.near_mm), region.point_at(end)])
    return RegionLines([near] + ([] if cut else [far]), sides, axis, np.concatenate([near, far]), not region.closed,
                       cut, region.near_mm, region.far_mm, end)
