"""The first surface of a point cloud along a ray: a reference depth for a gaze ray where a
SLAM map of the scene exists (Aria's semi-dense points), to judge gaze-depth estimates on real
recordings. It is a reference, not the truth: it inherits the ray's direction error, and at
grazing angles a 1 deg error moves it along the surface.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from estimator._checks import check_points, check_same_rows


def first_surface(points_mm: ArrayLike, origins_mm: ArrayLike, directions: ArrayLike, cone_deg: float = 1.5,
                  bin_mm: float = 50.0, min_points: int = 5, min_dist_mm: float = 100.0) -> np.ndarray:
    """Depth along each ray of the nearest surface of a point cloud.

    Per ray: the points within ``cone_deg`` of it and more than ``min_dist_mm`` along it, sorted
    by their distance along the ray; the first distance ``z`` with at least ``min_points`` points
    in ``[z, z + bin_mm]`` marks the surface, and the median of that bin is its depth.

    Args:
        points_mm: (P, 3) the cloud, mm, in the rays' frame.
        origins_mm: (N, 3) ray origins, mm.
        directions: (N, 3) unit ray directions.

    Returns:
        (N,) depth along each ray, mm; NaN where no surface is found.
    """
    pts = check_points(points_mm, "points_mm")
    o = check_points(origins_mm, "origins_mm")
    d = check_points(directions, "directions")
    check_same_rows(o, d, "origins_mm", "directions")
    cos_max = np.cos(np.deg2rad(cone_deg))
    out = np.full(len(o), np.nan)
    for i in range(len(o)):
        if not (np.all(np.isfinite(o[i])) and np.all(np.isfinite(d[i]))):
            continue
        v = pts - o[i]
        along = v @ d[i]
        near = along > min_dist_mm
        cosang = along[near] / np.linalg.norm(v[near], axis=1)
        z = np.sort(along[near][cosang >= cos_max])
        if len(z) < min_points:
            continue
        end = np.searchsorted(z, z + bin_mm, side="right")
        hit = np.flatnonzero(end - np.arange(len(z)) >= min_points)
        if len(hit):
            j = hit[0]
            out[i] = float(np.median(z[j:end[j]]))
    return out
