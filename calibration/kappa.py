"""The visual-axis (kappa) offset: from the optical axes an eye tracker reports to the visual
axes the person looks along (issue 14, docs/importers.md "Pupil Labs Neon").

Model. Each eye's direction ``d`` (head frame = scene camera, OpenCV axes: x right, y down,
z forward) is written in Fick angles,

    h = atan2(d_x, d_z)                 (horizontal, + toward the wearer's right, +x)
    v = atan2(d_y, hypot(d_x, d_z))     (vertical, + downward, +y)

and the visual axis is the optical axis with a constant per-eye offset added to both angles:
``(h + kappa_h, v + kappa_v)``. This is a rotation of the axis about the head's vertical axis
then about its rotated horizontal axis (a Fick gimbal): for the small eye rotations of a
head-worn tracker it equals a rotation fixed in the eye to a few hundredths of a degree.

Estimation. Given for each sample a point the eye looks at (a known target, or a point on a
cyclopean gaze ray), the offset of one eye is the median over samples of the Fick-angle
differences between the direction eye centre -> point and the optical axis: the median keeps
saccades and blinks that slipped through the validity checks from pulling the fit.

With a cyclopean gaze ray only (a 2D gaze in the scene image, as Neon gives), the point along
the ray is unknown: the eyes sit about 32 mm to each side of the scene camera and 36 mm behind
it, so the common (version) and vertical parts of the offsets are fixed by the ray but their
horizontal difference (the vergence) is fixed only by an assumed depth ``depth_mm``. Iterating
"fit at D, move D to the median depth the corrected rays imply" has no fixed point on real data
(it drifts by a few percent per step toward the near field), so the depth is an input and the
caller records it.

Pure library: no I/O, no printing. Units: mm, radians inside, degrees in ``KappaFit``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from estimator._checks import check_points
from estimator.triangulation import PairStatus, closest_point_two_lines

log = logging.getLogger(__name__)

MIN_SAMPLES = 10


def fick_angles(directions: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) directions (any length > 0) -> horizontal h (N,) and vertical v (N,) Fick angles, rad."""
    d = check_points(directions, "directions")
    return np.arctan2(d[:, 0], d[:, 2]), np.arctan2(d[:, 1], np.hypot(d[:, 0], d[:, 2]))


def from_fick_angles(h: ArrayLike, v: ArrayLike) -> np.ndarray:
    """Horizontal and vertical Fick angles (N,) rad -> (N, 3) unit directions."""
    h, v = np.asarray(h, float).reshape(-1), np.asarray(v, float).reshape(-1)
    return np.column_stack([np.cos(v) * np.sin(h), np.sin(v), np.cos(v) * np.cos(h)])


def apply_kappa(directions: ArrayLike, kappa_deg: ArrayLike) -> np.ndarray:
    """Optical axes (N, 3) -> visual axes (N, 3) unit, with ``kappa_deg`` = (h, v) degrees added
    to the Fick angles. Rows that are not finite stay NaN."""
    d = np.asarray(directions, float).reshape(-1, 3)
    out = np.full(d.shape, np.nan)
    ok = np.all(np.isfinite(d), axis=1) & (np.linalg.norm(d, axis=1) > 0)
    if ok.any():
        h, v = fick_angles(d[ok])
        k = np.radians(np.asarray(kappa_deg, float).reshape(2))
        out[ok] = from_fick_angles(h + k[0], v + k[1])
    return out


def angular_errors_deg(centers_mm: ArrayLike, directions: ArrayLike, points_mm: ArrayLike) -> np.ndarray:
    """(N,) angles, degrees, between each direction (N, 3) and the direction from its centre
    (N, 3, mm) to its point (N, 3, mm), one frame; NaN where a row is not finite."""
    c, d, p = (np.asarray(a, float).reshape(-1, 3) for a in (centers_mm, directions, points_mm))
    to_point = p - c
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.sum(d * to_point, axis=1) / (np.linalg.norm(d, axis=1) * np.linalg.norm(to_point, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class EyeKappa:
    """One eye's fitted offset.

    Attributes:
        kappa_deg: (2,) (h, v) degrees added to the optical axis's Fick angles.
        spread_deg: (2,) median absolute deviation of the per-sample differences, degrees.
        n: samples used.
    """

    kappa_deg: np.ndarray
    spread_deg: np.ndarray
    n: int


def fit_eye_kappa(centers_mm: ArrayLike, optical_axes: ArrayLike, points_mm: ArrayLike) -> EyeKappa:
    """The offset of one eye that turns its optical axes toward the points looked at.

    Args:
        centers_mm: (N, 3) eye centres, head frame, mm.
        optical_axes: (N, 3) optical-axis directions, head frame.
        points_mm: (N, 3) the points looked at, head frame, mm.

    Rows with any non-finite value are left out.

    Raises:
        ValueError: fewer than ``MIN_SAMPLES`` usable rows.
    """
    c = np.asarray(centers_mm, float).reshape(-1, 3)
    a = np.asarray(optical_axes, float).reshape(-1, 3)
    p = np.asarray(points_mm, float).reshape(-1, 3)
    if not len(c) == len(a) == len(p):
        raise ValueError(f"centers ({len(c)}), axes ({len(a)}) and points ({len(p)}) must have one row per sample")
    to_point = p - c
    ok = (np.all(np.isfinite(np.hstack([c, a, p])), axis=1) & (np.linalg.norm(a, axis=1) > 0)
          & (np.linalg.norm(to_point, axis=1) > 0))
    if ok.sum() < MIN_SAMPLES:
        raise ValueError(f"{int(ok.sum())} usable samples to fit the kappa offset, need {MIN_SAMPLES}")
    ht, vt = fick_angles(to_point[ok])
    ho, vo = fick_angles(a[ok])
    diff = np.column_stack([_wrap(ht - ho), vt - vo])
    k = np.median(diff, axis=0)
    spread = np.median(np.abs(diff - k), axis=0)
    return EyeKappa(np.degrees(k), np.degrees(spread), int(ok.sum()))


@dataclass(frozen=True)
class KappaFit:
    """Both eyes' offsets and how they were found.

    Attributes:
        left, right: ``EyeKappa`` of each eye.
        method: 'targets' (known targets) or 'cyclopean-ray' (a gaze ray from the scene camera
            at an assumed depth).
        depth_mm: the assumed depth along the cyclopean rays (None for 'targets').
    """

    left: EyeKappa
    right: EyeKappa
    method: str
    depth_mm: float | None = None


def fit_kappa_targets(left_centers_mm: ArrayLike, left_axes: ArrayLike, right_centers_mm: ArrayLike,
                      right_axes: ArrayLike,
                      targets_mm: ArrayLike) -> KappaFit:
    """Per-eye offsets from samples during which the wearer looked at known points.

    Args:
        left_centers_mm, right_centers_mm: (N, 3) eye centres, head frame, mm (NaN: eye invalid).
        left_axes, right_axes: (N, 3) optical axes, head frame (NaN: eye invalid).
        targets_mm: (N, 3) the target looked at during each sample, head frame, mm.
    """
    return KappaFit(fit_eye_kappa(left_centers_mm, left_axes, targets_mm),
                    fit_eye_kappa(right_centers_mm, right_axes, targets_mm), "targets")


def points_on_rays(ray_directions: ArrayLike, depth_mm: float) -> np.ndarray:
    """(N, 3) directions of rays from the head-frame origin (the scene camera's centre) -> the
    (N, 3) points where they reach depth z = ``depth_mm``, mm (NaN for rays not pointing forward)."""
    d = np.asarray(ray_directions, float).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = d * (float(depth_mm) / d[:, 2:3])
    p[~(d[:, 2] > 0)] = np.nan
    return p


def fit_kappa_cyclopean(left_centers_mm: ArrayLike, left_axes: ArrayLike, right_centers_mm: ArrayLike,
                        right_axes: ArrayLike, gaze_rays: ArrayLike,
                        depth_mm: float) -> KappaFit:
    """Per-eye offsets that make each eye's visual axis meet the cyclopean gaze ray (from the
    scene camera's centre, e.g. a tracker's 2D gaze through the scene camera) at depth
    ``depth_mm`` (z in the head frame).

    The horizontal difference of the two offsets, i.e. the vergence of the result, follows from
    ``depth_mm`` (see the module docstring): report it with the offsets.

    Args:
        left_centers_mm, right_centers_mm: (N, 3) eye centres, head frame, mm (NaN: invalid).
        left_axes, right_axes: (N, 3) optical axes, head frame (NaN: invalid).
        gaze_rays: (N, 3) directions of the gaze ray from the head-frame origin (NaN: none).
        depth_mm: the assumed depth, mm (> 0).
    """
    if not np.isfinite(depth_mm) or depth_mm <= 0:
        raise ValueError(f"depth_mm must be a positive number of mm, got {depth_mm}")
    pts = points_on_rays(gaze_rays, depth_mm)
    return KappaFit(fit_eye_kappa(left_centers_mm, left_axes, pts), fit_eye_kappa(right_centers_mm, right_axes, pts),
                    "cyclopean-ray", float(depth_mm))


def vergence(left_centers_mm: ArrayLike, left_directions: ArrayLike, right_centers_mm: ArrayLike,
             right_directions: ArrayLike) -> dict:
    """How a set of binocular rays meet: per sample the horizontal vergence and the depth.

    Returns:
        dict of (N,) arrays: ``vergence_deg`` (left h minus right h: > 0 when the rays converge,
        < 0 when they diverge), ``depth_mm`` (z of the point nearest both lines, NaN for parallel
        lines), ``in_front`` (the point lies ahead of both eyes).
    """
    lc, rc = check_points(left_centers_mm, "left_centers_mm"), check_points(right_centers_mm, "right_centers_mm")
    ld, rd = check_points(left_directions, "left_directions"), check_points(right_directions, "right_directions")
    pair = closest_point_two_lines(lc, ld, rc, rd)
    return {"vergence_deg": np.degrees(_wrap(fick_angles(ld)[0] - fick_angles(rd)[0])),
            "depth_mm": pair.point_mm[:, 2], "in_front": pair.status == PairStatus.OK}


def vergence_summary(left_centers_mm: ArrayLike, left_directions: ArrayLike, right_centers_mm: ArrayLike,
                     right_directions: ArrayLike) -> dict:
    """``vergence`` of N binocular rays in three numbers: ``median_vergence_deg``,
    ``in_front_share`` (of samples whose rays meet ahead of both eyes) and
    ``median_depth_in_front_mm`` (None when none do). An empty input gives {}."""
    if not len(np.asarray(left_centers_mm).reshape(-1, 3)):
        return {}
    v = vergence(left_centers_mm, left_directions, right_centers_mm, right_directions)
    front = v["in_front"]
    return {"median_vergence_deg": float(np.median(v["vergence_deg"])), "in_front_share": float(front.mean()),
            "median_depth_in_front_mm": float(np.median(v["depth_mm"][front])) if front.any() else None}
