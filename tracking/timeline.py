"""Poses over time: interpolation to other timestamps (eye samples); a short constant-velocity
continuation past the newest pose for a live session (``extrapolate_pose``)."""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from estimator._checks import check_array

log = logging.getLogger(__name__)


def _times_and_poses(t, T, t_name: str, T_name: str):
    """(N,) times and (N, 4, 4) poses, checked (an empty sequence is 0 poses)."""
    T = np.asarray(T, float)
    T = T.reshape(0, 4, 4) if T.size == 0 else check_array(T, T_name, (None, 4, 4))
    t = np.asarray(t, float)
    t = t.reshape(0) if t.size == 0 else check_array(t, t_name, (None,))
    if len(t) != len(T):
        raise ValueError(f"{t_name} and {T_name} must have one entry per pose, got {len(t)} and {len(T)}")
    return t, T


def interpolate_poses(t_src, T_src, t_query, max_gap_s: float = 0.1):
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


def extrapolate_pose(t_a: float, T_a, t_b: float, T_b, t: float) -> np.ndarray:
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


def smooth_poses(t, T, window_s: float, causal: bool = False):
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
