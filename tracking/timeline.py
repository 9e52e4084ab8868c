"""Poses over time: interpolation to other timestamps (eye samples); a short constant-velocity
continuation past the newest pose for a live session (``extrapolate_pose``)."""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation, Slerp

from estimator._checks import check_array, check_same_rows

log = logging.getLogger(__name__)

MAX_POSE_GAP_S = 0.1
"""A sample gets a head pose only between two valid poses this close to it, s (``interpolate_poses``'
``max_gap_s``): the view-line step's, the exports' and the person step's, referenced from here."""


def _times_and_poses(t: ArrayLike, T: ArrayLike, t_name: str, T_name: str) -> tuple[np.ndarray, np.ndarray]:
    """(N,) times and (N, 4, 4) poses, checked (an empty sequence is 0 poses)."""
    T = np.asarray(T, float)
    T = T.reshape(0, 4, 4) if T.size == 0 else check_array(T, T_name, (None, 4, 4))
    t = np.asarray(t, float)
    t = t.reshape(0) if t.size == 0 else check_array(t, t_name, (None,))
    check_same_rows(t, T, t_name, T_name, "one entry per pose")
    return t, T


def interpolate_poses(t_src: ArrayLike, T_src: ArrayLike, t_query: ArrayLike, max_gap_s: float = MAX_POSE_GAP_S
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``T_world_from_cam`` at query times: SLERP for rotation, linear for translation, between
    the two valid poses around each query.

    Args:
        t_src: (N,) pose times, s, increasing.
        T_src: (N, 4, 4) poses; frames without a pose are NaN.
        t_query: (M,) times.
        max_gap_s: a query is answered only when both neighbouring valid poses lie within this
            of it (and of each other plus it): no pose is invented across a gap.

    Returns:
        T (M, 4, 4) (NaN where unanswered) and ok (M,) bool.
    """
    t_src, T_src = _times_and_poses(t_src, T_src, "t_src", "T_src")
    tq = np.atleast_1d(np.asarray(t_query, float))
    if tq.ndim != 1:
        raise ValueError(f"t_query must have shape (M,), got {tq.shape}")
    good = np.all(np.isfinite(T_src.reshape(len(T_src), -1)), axis=1)
    out = np.full((len(tq), 4, 4), np.nan)
    ok = np.zeros(len(tq), bool)
    ts, Ts = t_src[good], T_src[good]
    if len(ts) == 0:
        return out, ok
    j = np.searchsorted(ts, tq, side="right")           # ts[j-1] <= tq < ts[j]
    lo = np.clip(j - 1, 0, len(ts) - 1)
    hi = np.clip(j, 0, len(ts) - 1)
    exact = np.isclose(ts[lo], tq, atol=1e-9, rtol=0)
    inside = (j > 0) & (j < len(ts))
    near = inside & (tq - ts[lo] <= max_gap_s) & (ts[hi] - tq <= max_gap_s)
    ok = exact | near
    if len(ts) == 1:
        sel = np.flatnonzero(ok)
        out[sel] = Ts[0]
        return out, ok
    slerp = Slerp(ts, Rotation.from_matrix(Ts[:, :3, :3]))
    sel = np.flatnonzero(ok)
    if len(sel):
        tt = np.clip(tq[sel], ts[0], ts[-1])
        out[sel] = np.eye(4)
        out[sel, :3, :3] = slerp(tt).as_matrix()
        for i in range(3):
            out[sel, i, 3] = np.interp(tt, ts, Ts[:, i, 3])
    log.debug("poses at %d of %d query times (%d source poses, gaps over %g s left open)", int(ok.sum()), len(tq),
              len(ts), max_gap_s)
    return out, ok


def nearest_in_time(t_src: ArrayLike, values: ArrayLike, t_query: ArrayLike, max_dt: float,
                    inclusive: bool = False) -> np.ndarray:
    """The value of the sample nearest each query time, or NaN where none is nearer than
    ``max_dt`` (or as near, ``inclusive``).

    Args:
        t_src: (M,) sorted sample times (seconds, or integer nanoseconds: any one unit).
        values: (M, K) the samples' values.
        t_query: (N,) query times, the same unit.
        max_dt: the largest time difference answered, the same unit.
    Returns:
        (N, K) float64; a tie between two neighbours goes to the later one.
    """
    t_src, t_query = np.asarray(t_src), np.asarray(t_query)
    values = np.asarray(values, float)
    out = np.full((len(t_query), values.shape[1]), np.nan)
    if not len(t_src) or not len(t_query):
        return out
    if len(t_src) > 1:
        j = np.searchsorted(t_src, t_query).clip(1, len(t_src) - 1)
        near = np.where(np.abs(t_src[j - 1] - t_query) < np.abs(t_src[j] - t_query), j - 1, j)
    else:
        near = np.zeros(len(t_query), int)
    dt = np.abs(t_src[near] - t_query)
    close = dt <= max_dt if inclusive else dt < max_dt
    out[close] = values[near[close]]
    return out


def extrapolate_pose(t_a: float, T_a: ArrayLike, t_b: float, T_b: ArrayLike, t: float) -> np.ndarray:
    """``T_world_from_cam`` (4, 4) at ``t`` >= ``t_b`` continued from two poses at ``t_a`` < ``t_b``
    (s) at their constant velocity: the rotation from ``T_a`` to ``T_b`` carried on at the same
    rate (about the same axis), the translation linearly. For a live session, where a sample
    can be newer than the newest tracked frame (docs/live.md). Keep ``t - t_b`` short: a change
    of velocity since ``t_b`` is not seen.
    """
    T_a, T_b = check_array(T_a, "T_a", (4, 4)), check_array(T_b, "T_b", (4, 4))
    if not t_b > t_a:
        raise ValueError(f"t_b must come after t_a, got {t_a} and {t_b}")
    f = (t - t_b) / (t_b - t_a)
    step = Rotation.from_matrix(T_b[:3, :3] @ T_a[:3, :3].T).as_rotvec()       # world-frame rotation a -> b
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(f * step).as_matrix() @ T_b[:3, :3]
    out[:3, 3] = T_b[:3, 3] + f * (T_b[:3, 3] - T_a[:3, 3])
    return out


def pose_between(t_a: float, T_a: ArrayLike, t_b: float, T_b: ArrayLike, t: float) -> np.ndarray:
    """``T_world_from_cam`` (4, 4) at ``t_a <= t <= t_b`` (s) between two poses: SLERP for the
    rotation, linear for the translation, ``interpolate_poses``'s answer for one time between two
    poses without its set-up (about a quarter of its cost: the live loop asks once a sample). It
    is ``extrapolate_pose``'s constant-velocity path read between its two ends.
    """
    if not t_a <= t <= t_b:
        raise ValueError(f"t must lie between t_a and t_b, got {t} not in [{t_a}, {t_b}]")
    if t_b == t_a:
        return check_array(T_b, "T_b", (4, 4)).copy()
    return extrapolate_pose(t_a, T_a, t_b, T_b, t)


SPIKE_MM = 50.0
"""A tracked pose farther than this from the line between its neighbours' poses is a spike (mm):
a head accelerating at 10 m/s^2 leaves that line by 6 mm over two frames at 30 fps (1/15 s)."""
SPIKE_DEG = 5.0
"""... or turned farther than this from their SLERP (degrees; 3000 deg/s^2: 1.7 deg)."""


def pose_spikes(t: ArrayLike, T: ArrayLike, max_gap_s: float = 0.2, spike_mm: float = SPIKE_MM,
                spike_deg: float = SPIKE_DEG) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which poses jump away from both neighbours and back: a marker pose fixed on one or two
    markers (a single marker's two IPPE solutions, a wrong corner) can land hundreds of mm off
    while the head moves smoothly.

    Each valid pose is compared with its two nearest valid neighbours' interpolation at its time
    (``interpolate_poses``; neighbours at most ``max_gap_s`` apart), or beside a gap (or at
    either end) with the two valid poses on its other side continued to its time
    (``extrapolate_pose``; within ``max_gap_s`` of it). It is a spike when it is
    off that by over ``spike_mm`` or ``spike_deg`` and by more than either neighbour is off its
    own neighbours (so that one bad pose does not also condemn the good ones beside it); a
    neighbour that could not be compared leaves it undecided: kept.

    Args:
        t: (N,) times, s, increasing.
        T: (N, 4, 4) ``T_world_from_cam``, NaN where no pose.

    Returns:
        (N,) bool, True for a spike (never for a NaN pose or the first or last valid one), and
        (N,) each pose's distance from the interpolation, mm, and (N,) its angle from it,
        degrees (NaN where not compared).
    """
    t, T = _times_and_poses(t, T, "t", "T")
    good = np.flatnonzero(np.all(np.isfinite(T.reshape(len(T), -1)), axis=1))
    off_mm, off_deg = np.full(len(t), np.nan), np.full(len(t), np.nan)
    for j, k in enumerate(good):
        Ti = _neighbors_pose(t, T, good, j, max_gap_s)
        if Ti is None:
            continue
        off_mm[k] = np.linalg.norm(T[k, :3, 3] - Ti[:3, 3])
        off_deg[k] = np.degrees(Rotation.from_matrix(T[k, :3, :3] @ Ti[:3, :3].T).magnitude())
    score = np.fmax(off_mm / spike_mm, off_deg / spike_deg)
    spike = np.zeros(len(t), bool)
    for j, k in enumerate(good):
        if not score[k] > 1:
            continue
        near = [score[good[i]] for i in (j - 1, j + 1) if 0 <= i < len(good)]
        spike[k] = all(x < score[k] for x in near)                   # a neighbour not compared objects
    return spike, off_mm, off_deg


def _neighbors_pose(t: np.ndarray, T: np.ndarray, good: np.ndarray, j: int, max_gap_s: float) -> np.ndarray | None:
    """The pose at ``t[good[j]]`` its valid neighbours (indices ``good``) give: SLERP between the
    two around it when at most ``max_gap_s`` apart; else the two on one side, continued, when
    that side's nearer one is within half ``max_gap_s`` and the farther within ``max_gap_s``;
    else None."""
    k = good[j]
    before, after = good[max(j - 2, 0):j], good[j + 1:j + 3]
    if len(before) and len(after) and t[after[0]] - t[before[-1]] <= max_gap_s:
        ab = [before[-1], after[0]]
        return interpolate_poses(t[ab], T[ab], [t[k]], max_gap_s=max_gap_s)[0][0]
    if len(after) == 2 and t[after[0]] - t[k] <= max_gap_s / 2 and t[after[1]] - t[k] <= max_gap_s:
        return _extrapolate_back(t[after[1]], T[after[1]], t[after[0]], T[after[0]], t[k])
    if len(before) == 2 and t[k] - t[before[1]] <= max_gap_s / 2 and t[k] - t[before[0]] <= max_gap_s:
        return extrapolate_pose(t[before[0]], T[before[0]], t[before[1]], T[before[1]], t[k])
    return None


def _extrapolate_back(t_far: float, T_far: np.ndarray, t_near: float, T_near: np.ndarray, t: float) -> np.ndarray:
    """``extrapolate_pose`` backwards in time: the pose at ``t`` < ``t_near`` < ``t_far``."""
    return extrapolate_pose(-t_far, T_far, -t_near, T_near, -t)


def smooth_poses(t: ArrayLike, T: ArrayLike, window_s: float, causal: bool = False) -> np.ndarray:
    """Moving-average smoothing of poses (N, 4, 4) at times t (N,): translations averaged,
    rotations averaged as sign-aligned quaternions, over ``window_s`` seconds.

    Centred (default, for offline processing) it adds no lag; ``causal`` (for the live loop)
    uses only past poses and lags by about ``window_s / 2``. Frames without a pose stay NaN
    and are left out of their neighbours' averages.
    """
    t, T = _times_and_poses(t, T, "t", "T")
    out = np.full_like(T, np.nan)
    good = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    if not good.any() or window_s <= 0:
        return T.copy()
    q = np.zeros((len(T), 4))
    q[good] = Rotation.from_matrix(T[good, :3, :3]).as_quat()
    for i in np.flatnonzero(good):
        lo = t[i] - (window_s if causal else window_s / 2)
        hi = t[i] if causal else t[i] + window_s / 2
        sel = good & (t >= lo - 1e-9) & (t <= hi + 1e-9)          # symmetric despite rounding
        qs = q[sel] * np.where(q[sel] @ q[i] < 0, -1.0, 1.0)[:, None]
        qm = qs.mean(axis=0)
        out[i] = np.eye(4)
        out[i, :3, :3] = Rotation.from_quat(qm / np.linalg.norm(qm)).as_matrix()
        out[i, :3, 3] = T[sel, :3, 3].mean(axis=0)
    return out
