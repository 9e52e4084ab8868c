"""The depth a fixation's own lines show, which bounds the parallax the segmentation allows
(``estimator.segments``; docs/processing.md, "Segmentation").

The window test asks whether one still point explains the median rays of the windows before
and after a sample. Any point of the before-ray from ``min_depth_mm`` (250 mm) to infinity is
too loose once the head moves: a 2-sample window at 10 Hz while walking sits 150 mm from the
next, and parallax to a point 250 mm away explains turns of 30 deg. But the fixation's lines
so far (both eyes, every sample since the stretch began) already fix its point to an interval
of depth: least squares on the lines (prefix or running sums of ``I - d d^T`` and
``(I - d d^T) o``, O(1) a sample) gives the point and, from the lines' noise, its inverse-depth
interval. Only the before-ray's points within that interval may explain the after-window.
With few lines, or lines that do not fix a depth (a still head far from its target), the
interval is wide and the test is the old one; with lines that do not meet in one point (a
pursuit) the interval widens with their misfit.

World frame, mm; angles in degrees where the name says ``_deg``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .frames import angle_deg

DEPTH_K = 4.0
"""The inverse-depth interval's half-width in standard deviations of the lines' noise (generous:
a fixation cut in two by a too-narrow interval is a worse error than a small saccade missed)."""
BIAS_DEG = 1.0
"""The angular bias allowed each line beyond its noise, degrees, which does not average out
over the lines: an eye calibration's offset differs between the eyes (vergence: at the eyes'
64 mm baseline 1 deg is 0.27 per metre of inverse depth) and with where the eye looks. Twice
the 0.5 deg per-eye offset prior of the merge test (``estimator.merge.MERGE_BIAS_DEG``) and of
the simulated sessions' biases (up to 0.5 deg)."""
MEDIAN_SD = 1.2533
"""The standard deviation of the median of n normal samples over that of one sample, times
sqrt(n) (large n: sqrt(pi / 2)); the window medians' noise for independent samples (here and in
``estimator.segments``)."""


def line_noise_deg(sample_noise: float, diff_sd: float, w: int) -> float:
    """Per-axis noise sd, degrees, of one eye's line: sqrt(2) times the cyclopean per-sample
    noise (the mean of two eyes), or, where the window medians are noisier than independent
    samples would make them (devices that filter in time), the per-sample noise that their
    spread ``diff_sd`` implies (``estimator.segments.median_noise_deg``)."""
    implied = diff_sd * np.sqrt(w) / (np.sqrt(2.0) * MEDIAN_SD)
    return float(np.sqrt(2.0) * max(sample_noise, implied, 1e-3))


def line_terms(origins: np.ndarray, directions: np.ndarray, center: np.ndarray) -> tuple:
    """Each sample's least-squares terms over its lines (one per eye): ``origins`` and unit
    ``directions`` (E, M, 3), mm, NaN where an eye is invalid (or its origin unknown), taken
    relative to ``center`` (3,). Returns (P (M, 3, 3), Po (M, 3), oPo (M,), n (M,)): the sums
    over the valid lines of ``I - d d^T``, of that times ``o - center``, of ``(o - center)``
    dotted with the latter, and their count."""
    o, d = np.asarray(origins, float) - center, np.asarray(directions, float)
    valid = np.isfinite(d).all(-1) & np.isfinite(o).all(-1)
    d0, o0 = np.where(valid[..., None], d, 0.0), np.where(valid[..., None], o, 0.0)
    P = valid[..., None, None] * np.eye(3) - d0[..., :, None] * d0[..., None, :]
    Po = np.einsum("emij,emj->emi", P, o0)
    return P.sum(0), Po.sum(0), np.einsum("emi,emi->em", o0, Po).sum(0), valid.sum(0)


def depth_bounds(sums: tuple, o_a: np.ndarray, d_a: np.ndarray, noise_deg: float,
                 min_depth_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """((K,) near, (K,) far) depths, mm, along before-rays ``(o_a, d_a)`` (K, 3) (origins relative
    to the sums' center) of the point the lines summed in ``sums`` ((K, 3, 3), (K, 3), (K,), (K,)
    as ``line_terms`` gives, summed) fix: least squares on the lines, its distance from ``o_a``
    and the inverse-depth interval of ``DEPTH_K`` sd of the lines' noise ``noise_deg`` (per
    line, per axis; inflated by their misfit beyond it, chi-square over its degrees of freedom)
    plus ``BIAS_DEG`` (which does not average out). Near never under ``min_depth_mm``; far
    infinite when the interval reaches zero inverse depth; (``min_depth_mm``, inf) with fewer
    than 3 lines or a point not ahead of ``o_a``."""
    A, b, c, n = sums
    K = len(n)
    near, far = np.full(K, float(min_depth_mm)), np.full(K, np.inf)
    ok = n >= 3
    if not ok.any():
        return near, far
    A, b, c, n, o_a, d_a = A[ok], b[ok], c[ok], n[ok], o_a[ok], d_a[ok]
    reg = 1e-9 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    X = np.linalg.solve(A + reg, b[..., None])[..., 0]
    rss = np.maximum(np.einsum("ki,kij,kj->k", X, A, X) - 2 * (X * b).sum(1) + c, 0.0)
    v = X - o_a
    rho = np.linalg.norm(v, axis=1)
    sigma, bias = np.deg2rad(noise_deg), np.deg2rad(BIAS_DEG)
    with np.errstate(invalid="ignore", divide="ignore"):     # a point at the origin, or none: not ahead
        u = v / rho[:, None]
        g = np.sqrt(np.maximum((u * np.linalg.solve(A + reg, np.nan_to_num(u)[..., None])[..., 0]).sum(1), 0.0)) / rho
        inflate = np.maximum(1.0, rss / (sigma * rho) ** 2 / np.maximum(2 * n - 3, 1))
        half = g * (DEPTH_K * sigma * np.sqrt(inflate) + bias * np.sqrt(n))
        q = 1.0 / rho
        ahead = (rho > 0) & np.isfinite(rho) & ((v * d_a).sum(1) > 0) & np.isfinite(half)
        sub_near = np.where(ahead, np.maximum(min_depth_mm, 1.0 / (q + half)), min_depth_mm)
        sub_far = np.where(ahead & (q > half), 1.0 / (q - half), np.inf)
    near[ok], far[ok] = sub_near, np.maximum(sub_far, sub_near)
    return near, far


def prefix_sums(terms: tuple, a: int, e: int) -> tuple:
    """The sums of ``line_terms`` over samples ``a .. a + j - 1`` for j = 0 .. e - a: arrays of
    e - a + 1 rows."""
    out = []
    for x in terms:
        part = x[a:e]
        z = np.zeros((1,) + part.shape[1:], dtype=float)
        out.append(np.concatenate([z, np.cumsum(part, axis=0, dtype=float)]))
    return tuple(out)


class LineSums:
    """``line_terms`` summed over a stream of samples (``OnlineSegmenter``): O(1) a sample,
    relative to the first line's origin."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.center: np.ndarray | None = None
        self.A, self.b, self.c, self.n = np.zeros((3, 3)), np.zeros(3), 0.0, 0

    def add(self, origins: np.ndarray, directions: np.ndarray) -> None:
        """Add one sample's lines: ``origins`` and unit ``directions`` (E, 3), mm, NaN: invalid."""
        o = np.asarray(origins, float)
        if not np.isfinite(o).all(-1).any():
            return
        if self.center is None:
            self.center = o[np.isfinite(o).all(-1)][0].copy()
        for oe, de in zip(o - self.center, np.asarray(directions, float), strict=True):    # line_terms, per line
            if np.isfinite(oe).all() and np.isfinite(de).all():
                P = np.eye(3) - np.outer(de, de)
                Po = P @ oe
                self.A, self.b, self.c, self.n = self.A + P, self.b + Po, self.c + float(oe @ Po), self.n + 1

    def bounds(self, o_a: np.ndarray, d_a: np.ndarray, noise_deg: float, min_depth_mm: float) -> tuple[float, float]:
        """(near, far) depths, mm, along the ray ``(o_a, d_a)`` (world) (``depth_bounds``)."""
        if self.center is None:
            return float(min_depth_mm), float("inf")
        near, far = depth_bounds((self.A[None], self.b[None], np.array([self.c]), np.array([self.n])),
                                 (np.asarray(o_a, float) - self.center)[None], np.asarray(d_a, float)[None],
                                 noise_deg, min_depth_mm)
        return float(near[0]), float(far[0])


def world_jump_deg(o_a: ArrayLike, d_a: ArrayLike, o_b: ArrayLike, d_b: ArrayLike, min_depth_mm: ArrayLike,
                   max_depth_mm: ArrayLike = np.inf) -> np.ndarray:
    """(K,) the least angle, degrees, between directions ``d_b`` (K, 3) from origins ``o_b`` (K, 3)
    and the directions from ``o_b`` to the points of rays ``(o_a, d_a)`` from ``min_depth_mm`` to
    ``max_depth_mm`` along them (scalars or (K,); world frame, mm; unit directions): how far ray
    b misses every point ray a could have fixated. Seen from ``o_b``, those points sweep an arc of
    the great circle through the points at the two depths (the far one at infinity: ``d_a``);
    inside the arc the angle is the one off its plane, else the nearer end's. With no baseline it
    is the angle between the directions."""
    o_a, d_a, o_b, d_b = (np.atleast_2d(np.asarray(x, float)) for x in (o_a, d_a, o_b, d_b))
    near = np.broadcast_to(np.asarray(min_depth_mm, float), (len(d_a),))[:, None]
    far = np.broadcast_to(np.asarray(max_depth_mm, float), (len(d_a),))[:, None]
    u0 = _unit(o_a - o_b + near * d_a)
    with np.errstate(invalid="ignore"):
        u1 = np.where(np.isfinite(far), _unit(o_a - o_b + np.where(np.isfinite(far), far, 0.0) * d_a), d_a)
    m = np.cross(u0, u1)
    mn = np.linalg.norm(m, axis=1)
    ends = np.minimum(angle_deg(d_b, u0), angle_deg(d_b, u1))
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.degrees(np.arcsin(np.clip(np.abs((d_b * m).sum(1)) / mn, 0.0, 1.0)))
    inside = ((np.cross(u0, d_b) * m).sum(1) >= 0) & ((np.cross(d_b, u1) * m).sum(1) >= 0) & (mn > 1e-12)
    return np.where(inside, off, ends)


def window_medians(x: np.ndarray, w: int) -> np.ndarray:
    """(M - w + 1, 3) the median of each run of ``w`` rows of ``x`` (M, 3); row j: rows j .. j + w - 1."""
    return np.median(np.lib.stride_tricks.sliding_window_view(x, w, axis=0), axis=-1)


def _unit(x: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return x / np.linalg.norm(x, axis=-1, keepdims=True)


def peaks(score: np.ndarray, threshold: float) -> list[tuple[int, int, int]]:
    """[(first, last, peak)] of each run of ``score`` above ``threshold`` (one per saccade)."""
    above = np.concatenate([[False], np.asarray(score) > threshold, [False]])
    edges = np.flatnonzero(np.diff(above.astype(int)))
    return [(int(a), int(b) - 1, int(a) + int(np.argmax(score[a:b])))
            for a, b in zip(edges[::2], edges[1::2], strict=True)]


def mixed_positions(directions: np.ndarray, w: int) -> np.ndarray:
    """(M,) bool: the test positions k whose windows (samples k - w .. k + w - 1) do not all have
    the same eyes valid (per-eye ``directions`` (2, M, 3), NaN where invalid), which the window
    test compares like with like (``estimator.segments._mixed_score``)."""
    code = np.isfinite(directions[0, :, 0]) + 2 * np.isfinite(directions[1, :, 0])
    m, out = len(code), np.zeros(len(code), bool)
    if m >= 2 * w:
        span = np.lib.stride_tricks.sliding_window_view(code, 2 * w)
        out[w:m - w + 1] = span.min(axis=1) != span.max(axis=1)
    return out


def stretches(cuts: list, gaps: np.ndarray, m: int, w: int) -> list[tuple[int, int]]:
    """[(first, end)] of the runs of samples (M = ``m``) between the runs of the window test
    above its threshold (``cuts``: (first, last, peak)) and the time gaps (the first sample
    after each), long enough for two windows of ``w``."""
    marks = sorted([(k0, k1 + 1) for k0, k1, _ in cuts] + [(int(g), int(g)) for g in gaps])
    starts, ends = [0] + [b for _, b in marks], [a for a, _ in marks] + [m]
    return [(a, e) for a, e in zip(starts, ends, strict=True) if e - a >= 2 * w]


def refine_cuts(o: np.ndarray, d: np.ndarray, eyes: tuple, spans: list, w: int, threshold: float,
                noise_deg: float, min_depth_mm: float) -> list[tuple[int, int, int]]:
    """The saccades the depth-bounded window test finds inside ``spans`` [(first, end)] of the
    valid samples' cyclopean rays ``(o, d)`` (M, 3) (``stretches``): at each k, the after-window's
    median ray against the before-window's between the depths the stretch's lines from its start
    (or from the end of the last saccade found in it) to k - 1 fix (``depth_bounds``; ``eyes``:
    per-eye origins and directions (2, M, 3), NaN where invalid). A new crossing of ``threshold``
    starts a saccade [(first, last, peak)] (``run_end``), and the lines start again after it, as
    ``OnlineSegmenter`` does. Positions whose windows mix eyes, or without origins, keep the
    first pass's test (0 here)."""
    if len(d) < 2 * w:
        return []
    med_d, med_o = _unit(window_medians(d, w)), window_medians(o, w)
    skip = mixed_positions(eyes[1], w)
    cuts = []
    for a, e in spans:
        center = med_o[a] if np.isfinite(med_o[a]).all() else np.zeros(3)
        terms = line_terms(eyes[0][:, a:e], eyes[1][:, a:e], center)
        start = a
        while e - start >= 2 * w:
            k = np.arange(start + w, e - w + 1)
            use = ~skip[k] & np.isfinite(med_o[k - w]).all(1) & np.isfinite(med_o[k]).all(1)
            prefix = prefix_sums(terms, start - a, e - a)
            score = _bounded(med_o, med_d, k, use, tuple(x[k - start] for x in prefix), center, w, noise_deg,
                             min_depth_mm)
            above = np.flatnonzero(score > threshold)
            if not len(above):
                break
            r0 = int(above[0])
            frozen = _bounded(med_o, med_d, k[r0:], use[r0:], tuple(np.repeat(x[k[r0] - start][None], len(k) - r0, 0)
                                                                   for x in prefix), center, w, noise_deg, min_depth_mm)
            free = _bounded(med_o, med_d, k[r0:], use[r0:], None, center, w, noise_deg, min_depth_mm)
            n = run_end(frozen, free, threshold, w)
            cuts.append((int(k[r0]), int(k[r0 + n - 1]), int(k[r0 + int(np.argmax(frozen[:n]))])))
            start = int(k[r0 + n - 1]) + 1
    return cuts


def run_end(frozen: np.ndarray, free: np.ndarray, threshold: float, w: int) -> int:
    """How many positions a saccade's run lasts from its crossing (position 0): while the test
    with the lines frozen at the crossing (``frozen`` (K,), degrees) stays over ``threshold``, for
    at most ``w`` positions (by then the windows have both passed the jump; the old fixation's
    depth does not hold for the new one's rays), and as long as the test without depth bounds
    (``free``) does."""
    j = np.arange(len(frozen))
    on = (free > threshold) | ((frozen > threshold) & (j < w))
    on[0] = True
    return int(np.argmin(on)) if not on.all() else len(on)


def _bounded(med_o: np.ndarray, med_d: np.ndarray, k: np.ndarray, use: np.ndarray, sums: tuple | None,
             center: np.ndarray, w: int, noise_deg: float, min_depth_mm: float) -> np.ndarray:
    """(K,) the window test at positions ``k`` (``use``: else 0) between window medians
    ``(med_o, med_d)``, the points of the before-ray limited to the depths ``sums`` fix
    (``depth_bounds``; None: from ``min_depth_mm`` to infinity)."""
    score = np.zeros(len(k))
    if not use.any():
        return score
    oa, da, ob, db = med_o[k - w][use], med_d[k - w][use], med_o[k][use], med_d[k][use]
    near, far = (min_depth_mm, np.inf) if sums is None else \
        depth_bounds(tuple(x[use] for x in sums), oa - center, da, noise_deg, min_depth_mm)
    score[use] = world_jump_deg(oa, da, ob, db, near, far)
    return score


def at_gap(cut: tuple[int, int, int], t: np.ndarray) -> tuple[int, int, int]:
    """A saccade whose run of the window test spans a gap in the samples (a blink, more than
    twice the median interval) is put in the gap: the peak moves to the first sample after its
    longest gap, so no fixation reaches across the blink to the saccade's other side."""
    k0, k1, c = cut
    if k1 <= k0 or len(t) < 2:
        return cut
    dt = np.diff(t[k0:k1 + 1])
    j = int(np.argmax(dt))
    return (k0, k1, k0 + j + 1) if dt[j] > 2 * np.median(np.diff(t)) else cut
