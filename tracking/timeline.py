"""Poses over time: interpolation to other timestamps (eye samples), never extrapolation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


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
    t_src = np.asarray(t_src, float)
    T_src = np.asarray(T_src, float).reshape(-1, 4, 4)
    tq = np.atleast_1d(np.asarray(t_query, float))
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
    return out, ok
