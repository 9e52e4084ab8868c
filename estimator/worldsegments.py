"""Fixation segmentation in the world (docs/processing.md, "Fixations"): the rule for view lines
in the world frame with the head's poses, offline (``segment_world``, through
``estimator.segments.segment_fixations``) and live (``NoiseMeter``, ``ChainSplitter``, the course
score, used by ``estimator.segments.OnlineSegmenter``).

A wearer who fixates a point while walking keeps the gaze ray on it: the eyes counter-rotate in
the head (the vestibulo-ocular reflex) and, as the head travels, the ray's direction in the world
turns with the parallax. A rule on eye-in-head motion cuts or rejects exactly those fixations;
so does one on the world direction alone when the head travels fast past a near point (the Aria
sample: 2-4 deg between 10 Hz samples). Here a fixation is a stretch of rays that hold one point
in the world (``estimator.worldpoint``), in the sense of Hessels et al. (2018): the frame in which
the gaze is still is the world's.

1. Saccades: steps off the gaze's smooth course in the world (``course_scores``: robust straight
   lines over ``window`` samples on each side). The parallax of a walk and a pursuit's drift are
   smooth and leave the course; a saccade steps off it. Threshold: ``jump_deg`` or ``JUMP_K`` sd
   of the score for the measured noise, whichever is larger, so it follows the eye rate (the
   window's samples) and the device's noise.
2. A stretch between saccades whose rays hold one point is one fixation; one whose rays hold
   consecutive different points is a chain of fixations whose saccades fell between samples
   (``ChainSplitter``: at 10 Hz a 30-50 ms saccade is not sampled); one that holds none for
   long is a pursuit, kept whole (the motion test downstream makes it a moving target).
3. Two stretches a moment apart whose rays hold one point together are one fixation
   (``join_returns``: a bad pose or a glance that came back).

Thresholds: a run holds a point when its RMS angle to it is within ``HOLD_K`` times the noise
(the dispersion test of Salvucci & Goldberg's 2000 I-DT, made on world points instead of
directions); the minimum fixation (``min_fixation_s``, 0.3 s) is within the 0.1-0.3 s minimum
durations of the fixation filters Salvucci & Goldberg (2000) and Komogortsev et al. (2010,
IEEE Trans. Biomed. Eng. 57(11), "Standardization of automated analyses of oculomotor fixation
and saccadic behaviors") compare, at the long end because the estimators need the lines.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import deque
from typing import TYPE_CHECKING

import numpy as np
from scipy.stats import chi2

from .lines import BinocularSamples
from .worldpoint import angles_to_point_deg, hold_fit, hold_rms_deg, measured_noise_deg

if TYPE_CHECKING:
    from .segments import SegmentConfig

log = logging.getLogger(__name__)

JUMP_FALSE_RATE = 1e-3
"""The world rule's jump threshold is where the course score of a steady gaze (Gaussian noise of
the measured sd) exceeds it at this rate per sample: a Rayleigh tail, K = sqrt(2 ln(1 / rate)) = 3.7. A
false cut inside a fixation costs little: ``join_returns`` joins the two pieces again."""
JUMP_K = float(np.sqrt(2.0 * np.log(1.0 / JUMP_FALSE_RATE)))
HOLD_K = 1.5
"""A run of rays holds one point when their RMS angle to it is at most this many times the
noise's 2D sd (sqrt(2) x the per-axis noise): a run of 5 true fixation samples fails it about
once in 500 (chi-square with 7 degrees of freedom above 22.5)."""
RECENT_K = 2.0
"""... and the RMS angle of its latest ``window`` rays at most this many times (a step to the next
point shows there in full as soon as the window holds it)."""
CHAIN_MAX_WINDOW = 3
"""The chain splitter runs only where the window holds at most this many samples (eye rates up
to 26 Hz, ``SegmentConfig.for_rate``): there the course score's noise (over twice one sample's
at 2 samples a side) hides saccades of a few degrees, which held points then find. Above it the
score sees them, and the splitter would do harm: a pursuit seen by a travelling head can hold a
static point at another depth for a moment (parallax mimics the target's motion), so a pursuit
at these low rates may come out as static pieces, a known limit."""
MAX_HOLD_S = 2.0
"""A growing run is tested on its latest rays of this span, s (the cost per ray stays bounded)."""
NOISE_WINDOWS = 600
MIN_NOISE_WINDOWS = 10
DEFAULT_NOISE_DEG = 1.0 / np.sqrt(2.0)
"""The cyclopean direction's noise, degrees per axis, when the lines are too few to measure it:
1 deg per eye (``process``'s default sigma), averaged over two eyes."""


def binocular_rays(samples: BinocularSamples) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices (M,) of the samples with both eyes valid, their eyes' midpoints (M, 3) mm and
    cyclopean unit directions (M, 3)): one eye alone is off the cyclopean line by half the
    vergence, which is not a saccade."""
    ok = samples.left_valid & samples.right_valid
    idx = np.flatnonzero(ok)
    o = 0.5 * (samples.left_origin_mm[idx] + samples.right_origin_mm[idx])
    d = samples.left_direction[idx] + samples.right_direction[idx]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return idx, o, d


def course_scores(t_s: np.ndarray, directions: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """The world rule's saccade score: at each sample k (M,), the angle, degrees, between the
    straight-line courses of the unit directions (M, 3) over the ``w`` samples before k and the
    ``w`` from k, both taken to the time midway between samples k - 1 and k. A steady fixation's
    direction drifts smoothly as the head travels (the parallax) and a pursuit's as its target
    moves; only a saccade steps off the course.

    Each course is robust (Theil-Sen: the median of the pairwise slopes, the median intercept),
    so that one wild sample (a bad head pose, a blink's edge) does not read as a step, as the
    medians of the eye-in-head rule do not. Also the score's sd per axis for a per-axis noise of
    1: the two least-squares fits' variances at that time, times pi / 2 (the median's efficiency)
    for windows over 2 samples. Both are 0 where a window does not fit (the first and last ``w``
    samples)."""
    m = len(t_s)
    score, sd = np.zeros(m), np.zeros(m)
    if m < 2 * w:
        return score, sd
    tw = np.lib.stride_tricks.sliding_window_view(t_s, w)                 # (m - w + 1, w)
    dw = np.lib.stride_tricks.sliding_window_view(directions, w, axis=0)  # (m - w + 1, 3, w)
    k = np.arange(w, m - w + 1)
    tb = 0.5 * (t_s[k - 1] + t_s[k])
    i, j = np.triu_indices(w, 1)
    ends, var = [], []
    for rows in (k - w, k):
        x, y = tw[rows] - tb[:, None], dw[rows]
        dx = x[:, j] - x[:, i]
        with np.errstate(divide="ignore", invalid="ignore"):
            slopes = np.where(dx[:, None, :] > 1e-9, (y[:, :, j] - y[:, :, i]) / dx[:, None, :], np.nan)
        ok = np.isfinite(slopes).any(axis=2)
        slope = np.zeros(slopes.shape[:2])
        slope[ok] = np.nanmedian(slopes[ok], axis=1) if ok.any() else 0.0
        ends.append(np.median(y - slope[:, :, None] * x[:, None, :], axis=2))
        xm = x.mean(axis=1)
        sxx = np.sum((x - xm[:, None]) ** 2, axis=1)
        var.append(1.0 / w + np.where(sxx > 1e-12, xm ** 2 / np.maximum(sxx, 1e-12), 0.0))
    a, b = (e / np.linalg.norm(e, axis=1, keepdims=True) for e in ends)
    score[k] = np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))
    sd[k] = np.sqrt((var[0] + var[1]) * (np.pi / 2 if w > 2 else 1.0))
    return score, sd


def noise_window(t_s: np.ndarray, config: SegmentConfig) -> int:
    """The rays per window of the noise measurement: the samples of ``min_fixation_s`` at the
    median sample interval of times ``t_s`` (M,) s, at least 3."""
    dt = np.diff(t_s)
    dt = dt[dt > 0]
    return max(3, int(round(config.min_fixation_s / float(np.median(dt))))) if len(dt) else 3


COURSE_S = 8 / 60.0
"""The world rule's course spans this much on each side of a sample, s: ``window`` samples, or more
above 60 Hz (a straight line through 8 samples extrapolates their noise 1.25 times, so above
60 Hz the span, not the count, is kept: 16 samples at 120 Hz), up to ``MAX_COURSE_WINDOW``."""
MAX_COURSE_WINDOW = 16


def course_window(config: SegmentConfig, rate_hz: float | None) -> int:
    """The world rule's window, samples a side, at eye rate ``rate_hz`` (None: ``config.window``):
    ``config.window`` or the samples of ``COURSE_S``, whichever is more, at most
    ``MAX_COURSE_WINDOW``."""
    if not rate_hz:
        return config.window
    return max(config.window, min(MAX_COURSE_WINDOW, int(round(COURSE_S * rate_hz))))


def segment_world(samples: BinocularSamples, config: SegmentConfig) -> np.ndarray:
    """The world rule: fixation labels (N,) of view lines in the world frame, in time order, as
    ``segment_fixations``'s.

    Saccades are steps off the gaze's smooth course in the world (``course_scores``) above
    ``jump_deg`` or ``JUMP_K`` sd of the score for the noise, whichever is larger; gaps end a
    stretch too (``fixation_stretches``). A stretch whose rays hold one world point is one
    fixation however the head moved, else it is split into the runs that each hold one
    (``split_chain``) or, when those do not cover it, kept whole as a pursuit. Only samples with
    both eyes count; a one-eye sample between two samples of one fixation joins it. The noise is
    ``config.noise_deg``, else measured on the lines (``estimator.worldpoint.measured_noise_deg``),
    else ``DEFAULT_NOISE_DEG``.
    """
    n = len(samples)
    labels = np.full(n, -1)
    idx, o, d = binocular_rays(samples)
    if len(idx) == 0:
        return labels
    tv = samples.t_s[idx]
    dt = np.diff(tv)
    dt = dt[dt > 0]
    config = dataclasses.replace(config, window=course_window(config, 1.0 / float(np.median(dt)) if len(dt) else None))
    noise = config.noise_deg
    if noise is None:
        noise = measured_noise_deg(o, d, noise_window(tv, config)) or DEFAULT_NOISE_DEG
    score, sd = course_scores(tv, d, config.window)
    jump = np.maximum(config.jump_deg, JUMP_K * sd * noise)
    stretches, n_cuts, n_gaps = steady_stretches(tv, score, jump, config)
    stretches = join_returns(tv, o, d, stretches, HOLD_K * np.sqrt(2.0) * noise, config)
    label = 0
    for sel in stretches:
        for run in split_chain(tv, o, d, sel, noise, config):
            labels[idx[run]] = label
            label += 1
    fill_one_eye(labels, samples.left_valid & samples.right_valid)
    log.info("%d fixations in %d samples (%d binocular; %d saccades, %d time gaps; noise %.2f deg)", label, n,
             len(idx), n_cuts, n_gaps, noise)
    return labels


def saccade_peaks(score: np.ndarray, jump: np.ndarray, w: int) -> np.ndarray:
    """The samples (K,) at which a saccade is found: where ``score`` (M,) exceeds ``jump`` (M,)
    by most within ``w`` samples either side (two saccades ``w`` samples apart are two)."""
    over = np.flatnonzero(score > jump)
    excess = score - jump
    return np.array([k for k in over if excess[k] >= excess[max(0, k - w):k + w + 1].max()], int)


def steady_stretches(t_s: np.ndarray, score: np.ndarray, jump: np.ndarray,
                     config: SegmentConfig) -> tuple[list, int, int]:
    """The world rule's stretches between saccades and gaps: (index arrays into ``t_s`` (M,) s,
    saccades, gaps). Each saccade cuts at its peak (``saccade_peaks``); its tails go with
    ``trim_s`` at each end of a stretch (a course score stays high while either window holds the
    step, so the run above ``jump`` is wider than the saccade); a gap over ``max_gap_s`` ends a
    stretch; stretches shorter than ``min_fixation_s`` are dropped."""
    m = len(t_s)
    cuts = saccade_peaks(score, jump, config.window)
    gaps = np.flatnonzero(np.diff(t_s) > config.max_gap_s)
    bounds = sorted({0, m} | set(cuts.tolist()) | set((gaps + 1).tolist()))
    # trimmed: within trim_s of a saccade's time (midway between the samples either side of its
    # step), or at a gap within trim_s of its edge sample (as the eye-in-head rule); the session's
    # own first and last samples follow no saccade
    at = {int(k): 0.5 * (t_s[k - 1] + t_s[k]) for k in cuts if k > 0}
    out = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        sel = np.arange(a, b)
        t = t_s[sel]
        first = t - at[a] > config.trim_s - 1e-9 if a in at else (t >= t_s[a] + config.trim_s) | (a == 0)
        last = at[b] - t > config.trim_s - 1e-9 if b in at else (t <= t_s[b - 1] - config.trim_s) | (b == m)
        sel = sel[first & last]
        if len(sel) and t_s[sel[-1]] - t_s[sel[0]] >= config.min_fixation_s - 1e-9:
            out.append(sel)
    return out, len(cuts), len(gaps)


def join_returns(t_s, origins_mm, directions, stretches: list, tau_deg: float, config: SegmentConfig) -> list:
    """Consecutive stretches (index arrays into t_s (M,) s, origins (M, 3) mm, unit directions
    (M, 3)) less than ``min_fixation_s`` apart whose rays together hold one point (RMS angle at
    most ``tau_deg``), the later one's first ``window`` rays on the point the earlier one held
    (RMS within ``RECENT_K`` / ``HOLD_K`` of that: with the depth free, two bundles of rays from
    a travelling head also meet where their axes cross), joined into one, without the samples
    between them: the gaze came back to the point it held (a bad head pose or a blink's edge
    read as a step, or a glance too short to be a fixation), so the fixation went on."""
    out: list = []
    for sel in stretches:
        if out and t_s[sel[0]] - t_s[out[-1][-1]] < config.min_fixation_s:
            both = np.concatenate([out[-1], sel])
            u, rho, _ = hold_fit(origins_mm[out[-1]], directions[out[-1]])
            back = sel[:config.window]          # the first rays after: on the point held before?
            res = angles_to_point_deg(u, rho, origins_mm[out[-1]].mean(axis=0), origins_mm[back], directions[back])
            if (np.sqrt(np.mean(res ** 2)) <= tau_deg * RECENT_K / HOLD_K
                    and hold_rms_deg(origins_mm[both], directions[both]) <= tau_deg):
                out[-1] = both
                continue
        out.append(sel)
    return out


def fill_one_eye(labels: np.ndarray, binocular: np.ndarray) -> None:
    """Give each sample outside ``binocular`` (N,) bool the label of the binocular samples on both
    sides of it when they share one (in place)."""
    b = np.flatnonzero(binocular)
    if len(b) < 2:
        return
    for i in np.flatnonzero(~binocular):
        j = np.searchsorted(b, i)
        if 0 < j < len(b) and labels[b[j - 1]] >= 0 and labels[b[j - 1]] == labels[b[j]]:
            labels[i] = labels[b[j]]


def split_chain(t_s, origins_mm, directions, sel: np.ndarray, noise_deg: float, config: SegmentConfig) -> list:
    """A stretch ``sel`` (indices into t_s (M,) s, origins (M, 3) mm, unit directions (M, 3),
    world) as fixations: ``ChainSplitter`` fed its rays in time order (as ``live`` feeds them),
    each run it finishes and what follows the last split (itself when nothing was split) when it
    lasts ``min_fixation_s``."""
    splitter = ChainSplitter(noise_deg, config)
    out, start = [], 0
    for i in range(len(sel)):
        split = splitter.push(t_s[sel[i]], origins_mm[sel[i]], directions[sel[i]])
        if split is not None:
            (a, b), s = split
            out.append(sel[start + a:start + b + 1])
            start += s
    out.append(sel[start:])
    return [r for r in out if len(r) and t_s[r[-1]] - t_s[r[0]] >= config.min_fixation_s - 1e-9]


class ChainSplitter:
    """A stretch between saccades split where the eye rate hid the saccades (10 Hz: one falls
    between two samples), fed one ray at a time, the same offline (``split_chain``) and live.

    Runs of rays that each hold one point for at least ``min_fixation_s`` (``HOLD_K``,
    ``RECENT_K``) are found in time order: a run grows while its rays (the latest
    ``MAX_HOLD_S``) hold a point; once it does not, the search goes on over the latest
    ``min_fixation_s`` of rays. When a new run starts at most ``window`` rays after the last one
    ended and the two together hold no one point, the gaze went from one point to another:
    the rays up to the earlier run's end are a fixation of their own and the stretch goes on
    from the new run. A pursuit
    holds no point for long, so its runs are rare and far apart: it stays whole (the motion test
    makes it a moving target); a fixation that holds one point throughout is one run.
    """

    def __init__(self, noise_deg: float, config: SegmentConfig):
        self.tau = HOLD_K * np.sqrt(2.0) * noise_deg
        self.config = config
        self.t: list = []
        self.o: list = []
        self.d: list = []
        self.run: tuple | None = None        # (first, last) of the run holding now
        self.closed: tuple | None = None     # the last run that ended, if it lasted min_fixation_s

    def push(self, t_s: float, origin_mm, direction) -> tuple | None:
        """Add a ray at time ``t_s`` (s; origin (3,) mm, unit direction (3,), world). Returns
        None, or on a split ((first, last) of the finished fixation: the rays from the stretch's
        or the last split's first ray to the end of the run that held its point, the index of the
        ray from which the stretch goes on), indices counted from that first ray; the rays before
        the stretch goes on are then forgotten."""
        self.t.append(float(t_s))
        self.o.append(np.asarray(origin_mm, float))
        self.d.append(np.asarray(direction, float))
        if self.config.window > CHAIN_MAX_WINDOW:
            return None
        n = len(self.t) - 1
        t = self.t
        if self.run is not None:
            a = max(self.run[0], int(np.searchsorted(t, t[n] - MAX_HOLD_S)))
            if self._holds(a, n):
                self.run = (self.run[0], n)
                return None
            first, last = self.run
            self.closed = self.run if t[last] - t[first] >= self.config.min_fixation_s - 1e-9 else None
            self.run = None
        s = int(np.searchsorted(t, t[n] - self.config.min_fixation_s + 1e-9, side="right")) - 1
        if s < 0 or (self.closed is not None and s <= self.closed[1]) or not self._holds(s, n):
            return None
        self.run = (s, n)
        c = self.closed
        if c is None or s > c[1] + 1 + self.config.window or self._same_point(c, s, n):
            return None
        self._forget(s)
        return (0, c[1]), s

    def _forget(self, s: int) -> None:
        """Drop the rays before index ``s``; the run now holding starts at 0."""
        self.t, self.o, self.d = self.t[s:], self.o[s:], self.d[s:]
        self.run = (0, self.run[1] - s)
        self.closed = None

    def _same_point(self, c: tuple, s: int, n: int) -> bool:
        """Whether the run from ray ``s`` to ``n`` is on the point the run ``c`` (first, last)
        held: its rays within ``RECENT_K`` / ``HOLD_K`` of the hold angle of that point, and the
        two together holding one (with the depth free, two bundles of rays from a travelling
        head also meet where their axes cross: the first test rules that out)."""
        o, d = np.array(self.o), np.array(self.d)
        held = np.arange(c[0], c[1] + 1)
        u, rho, _ = hold_fit(o[held], d[held])
        res = angles_to_point_deg(u, rho, o[held].mean(axis=0), o[s:n + 1], d[s:n + 1])
        return bool(np.sqrt(np.mean(res ** 2)) <= self.tau * RECENT_K / HOLD_K and self._holds(c[0], n, recent=False))

    def _holds(self, a: int, b: int, recent: bool = True) -> bool:
        """Whether rays a..b hold one point (``_holds``; without ``recent``, only their RMS)."""
        run = np.arange(a, b + 1)
        o, d = np.array(self.o), np.array(self.d)
        if not recent:
            return hold_rms_deg(o[run], d[run]) <= self.tau
        return _holds(o, d, run, self.tau, self.config.window)


def _holds(origins_mm, directions, run: np.ndarray, tau: float, w: int) -> bool:
    """Whether rays ``run`` hold one point: RMS angle to it at most ``tau`` degrees, and that of
    the latest ``w`` rays at most ``RECENT_K`` / ``HOLD_K`` times that."""
    res = hold_fit(origins_mm[run], directions[run])[2]
    return bool(np.sqrt(np.mean(res ** 2)) <= tau and np.sqrt(np.mean(res[-w:] ** 2)) <= tau * RECENT_K / HOLD_K)


class NoiseMeter:
    """The world rule's noise measured as a stream goes (``OnlineSegmenter``): the noise of
    ``estimator.worldpoint.measured_noise_deg`` over the windows seen so far (the latest
    ``NOISE_WINDOWS``), ``config.noise_deg`` when given, ``DEFAULT_NOISE_DEG`` until
    ``MIN_NOISE_WINDOWS`` windows are in (at 10 Hz, the first 2.2 s). The window's length follows the rate
    (``noise_window``), set from the first ``MIN_NOISE_WINDOWS`` samples' times."""

    def __init__(self, config: SegmentConfig):
        self.config = config
        self.value = DEFAULT_NOISE_DEG if config.noise_deg is None else float(config.noise_deg)
        self.n: int | None = None
        self.rays: deque = deque(maxlen=MIN_NOISE_WINDOWS)
        self.sums: deque = deque(maxlen=NOISE_WINDOWS)

    def hold_deg(self) -> float:
        """The RMS angle, degrees, within which rays hold one point, for the noise so far."""
        return HOLD_K * np.sqrt(2.0) * self.value

    def push(self, t_s: float, origin_mm, direction) -> None:
        """Add a ray at time ``t_s`` (s; origin (3,) mm, unit direction (3,), world)."""
        if self.config.noise_deg is not None or origin_mm is None:
            return
        self.rays.append((float(t_s), origin_mm, direction))
        if self.n is None:
            if len(self.rays) < MIN_NOISE_WINDOWS:
                return
            self.n = noise_window(np.array([r[0] for r in self.rays]), self.config)
            self.rays = deque(self.rays, maxlen=self.n)
        if len(self.rays) < self.n:
            return
        o = np.array([r[1] for r in self.rays])
        d = np.array([r[2] for r in self.rays])
        self.sums.append(float(np.sum(hold_fit(o, d)[2] ** 2)))
        if len(self.sums) >= MIN_NOISE_WINDOWS:
            self.value = float(np.sqrt(np.median(self.sums) / chi2.ppf(0.5, 2 * self.n - 3)))
