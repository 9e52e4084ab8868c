"""Gaze segmentation: which view lines belong to one fixated target.

A person looks at one thing, then jumps (a saccade) to the next. While a still target is
fixated the gaze ray holds on one point of the world; the head may move, and then the ray's
direction turns by the parallax (1 deg per 17 mm sideways at 1 m: a walking wearer's near
fixation turns by many degrees), while the eyes counter-rotate in the head. A saccade moves the
point. Single samples carry about 1 deg of noise per eye, so the test is made between windows:
at each sample, the median cyclopean ray (origin and direction) of the ``window`` valid samples
before it and of those after it, and the least angle at which the after-window's ray misses a
point of the before-window's ray at ``min_depth_mm`` or farther (``world_jump_deg``: the part
of the turn that no still point explains), and then, within each stretch, only at the depths
its own lines fix (``estimator.segdepth``). Without head motion that is the angle between the
two directions. Peaks above the threshold are saccades; the stretches between them are
fixations, kept when longer than ``min_fixation_s``. Blinks (both eyes invalid) are skipped,
not treated as saccades; a gap longer than ``max_gap_s`` ends a fixation.

The threshold follows the device's noise and the eye rate: ``noise_k`` standard deviations of
the difference of two window medians, measured on the session's own window medians
(``median_noise_deg``), never below ``jump_deg`` (the least saccade counted); measured, not
derived from the per-sample noise, it holds for devices that filter their samples in time
(a Tobii Pro Glasses 2: 0.39 deg, 0.03 from its per-sample noise). A saccade's own samples
(``saccade_samples``: those off both windows' directions by more than ``SAMPLE_K`` noise sd)
belong to no fixation; the fixations on either side keep the rest, so their boundaries are the
saccade's. Smooth pursuit of a moving target turns the gaze without a jump: it stays one
segment, which the motion test (``estimator.motion``) finds moving.

Defaults (documented in docs/processing.md, "Fixations"): window 8 samples (0.13 s at 60 Hz),
5 sd, least saccade 1.5 deg, nearest point 250 mm, minimum fixation 0.3 s, maximum gap 0.5 s.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from . import segscalar as sc
from .frames import angle_deg
from .lines import BinocularSamples
from .segdepth import MEDIAN_SD, line_noise_deg, mixed_positions, refine_cuts, stretches, window_medians, world_jump_deg
from .segdepth import at_gap as _at_gap
from .segdepth import peaks as _peaks

log = logging.getLogger(__name__)

MEDIAN_NOISE_QUANTILE = 0.25
"""``median_noise_deg`` reads this quantile of the window medians' second differences: a
saccade spoils the three windows around it, up to half of them where fixations are short (0.3 s
against 0.13 s windows), which moves the median but hardly the lower quartile."""
RAYLEIGH_Q25 = 0.7585
"""The lower quartile of a Rayleigh distribution in its scale (sqrt(-2 ln 0.75))."""
SECOND_DIFF_MEDIAN = 1.4420
"""The median angle between a sample and the mean of its two neighbours, in per-axis noise sd
(Rayleigh with scale sqrt(1.5): sqrt(1.5) * sqrt(2 ln 2)); ``sample_noise_deg`` divides by it."""
SAMPLE_K = 3.5
"""A sample more than this many per-axis noise sd (Rayleigh: 0.2 % of still samples) off a
window's direction is in a saccade (``saccade_samples``)."""


@dataclass(frozen=True)
class SegmentConfig:
    """The fixation test's settings (docs/processing.md, "Fixations").

    Attributes:
        window: samples on each side whose median rays are compared.
        jump_deg: the least saccade found, degrees: a floor under the noise threshold.
        noise_k: the threshold in standard deviations of the difference of two window medians
            (measured on the session's window medians, ``median_noise_deg``).
        min_depth_mm: the nearest a fixated point can be, mm; the head's motion explains a turn
            of the gaze by parallax to points this near or farther.
        min_fixation_s: shorter fixations are dropped, seconds.
        max_gap_s: a gap in the data longer than this ends a fixation, seconds.
        trim_s: time cut from each end of a fixation beyond the saccade's own samples, seconds.
        settle_s: time cut from a fixation's ends next to a saccade, seconds, in whole samples
            (rounded down: none at 10 Hz, 1 at 30 Hz, 10 at 200 Hz): the saccade's onset and the eye's settling
            after it (post-saccadic oscillation, 10-40 ms), which the window test does not resolve
            at the noise of a single sample (docs/processing.md, "Segmentation").
    """

    window: int = 8
    jump_deg: float = 1.5
    noise_k: float = 5.0
    min_depth_mm: float = 250.0
    min_fixation_s: float = 0.3
    max_gap_s: float = 0.5
    trim_s: float = 0.0
    settle_s: float = 0.05

    @classmethod
    def for_rate(cls, rate_hz: float, **settings) -> SegmentConfig:
        """The settings for eye samples at ``rate_hz``. The window's job is to beat the
        per-sample noise, which takes a number of samples, not a time span: 8 as by default, but
        never more than 0.13 s (the default's span at 60 Hz) and at least 2, so a 0.5 s fixation
        of 5 samples at 10 Hz (Aria) is found (2 a side). At 200 Hz (Neon) it stays 8 (40 ms):
        a window of 0.13 s there (27 samples) straddles the short fixations and finds none on
        Neon's demo recording, 8 finds 7. ``settings`` override the others."""
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        return cls(window=min(cls.window, max(2, int(round(cls.window * rate_hz / 60.0)))), **settings)

    def threshold_deg(self, diff_sd_deg: float) -> float:
        """The saccade threshold, degrees, for a per-axis sd of the difference of two window
        medians of ``diff_sd_deg`` (``median_noise_deg``)."""
        return max(self.jump_deg, self.noise_k * diff_sd_deg)


def cyclopean_directions(samples: BinocularSamples) -> np.ndarray:
    """(N, 3) unit mean of the valid eyes' directions (NaN where neither is valid)."""
    return cyclopean_rays(samples)[1]


def cyclopean_rays(samples: BinocularSamples) -> tuple[np.ndarray, np.ndarray]:
    """((N, 3) origins, mm, (N, 3) unit directions) of each sample's cyclopean ray, in the samples'
    frame: the mean of the valid eyes' origins and directions (one eye alone: its own line),
    NaN where neither is valid."""
    o, d, n = np.zeros((len(samples), 3)), np.zeros((len(samples), 3)), np.zeros(len(samples))
    for org, dirs, valid in ((samples.left_origin_mm, samples.left_direction, samples.left_valid),
                             (samples.right_origin_mm, samples.right_direction, samples.right_valid)):
        o[valid] += org[valid]
        d[valid] += dirs[valid]
        n += valid
    oo, dd = np.full((len(samples), 3), np.nan), np.full((len(samples), 3), np.nan)
    ok = n > 0
    oo[ok] = o[ok] / n[ok, None]
    dd[ok] = d[ok] / np.linalg.norm(d[ok], axis=1, keepdims=True)
    return oo, dd


def sample_noise_deg(directions) -> float:
    """The per-axis noise sd, degrees, of unit directions (M, 3) in time order: the median angle
    between each and the mean of its two neighbours over ``SECOND_DIFF_MEDIAN`` (a steady turn,
    e.g. the parallax of a walking head, cancels; saccades are too few to move the median).
    NaN with fewer than 3."""
    d = np.asarray(directions, float)
    if len(d) < 3:
        return float("nan")
    return float(np.median(angle_deg(d[1:-1], d[:-2] + d[2:])) / SECOND_DIFF_MEDIAN)


def median_noise_deg(origins, directions, w: int, min_depth_mm: float) -> float:
    """The per-axis sd, degrees, of the difference of the medians of two adjacent windows of ``w``
    rays (M, 3) in time order (origins, mm, NaN: unknown; unit directions; world frame),
    measured: at each sample, the angle between the median direction of the ``w`` samples from
    it and the direction, from their median origin, to the point the median rays ``w`` samples
    before and after point at (``_second_angles``). A steady turn cancels, and so does the
    parallax of a head that sways or walks past a near point (a fixation's rays all pass through
    its point). Per axis that angle is sqrt(1.5) times one median's sd where the difference of two
    is sqrt(2) times it; its lower quartile is read as a Rayleigh quantile. For independent samples
    it is sqrt(2) ``MEDIAN_SD`` times the per-sample sd over sqrt(w); for samples filtered in time
    it is more. NaN with fewer than 3 windows."""
    d = np.asarray(directions, float)
    if len(d) < 3 * w:
        return float("nan")
    med_d, med_o = _unit(window_medians(d, w)), window_medians(np.asarray(origins, float), w)
    return _diff_sd_deg(_second_angles(med_o[:-2 * w], med_d[:-2 * w], med_o[w:-w], med_d[w:-w],
                                       med_o[2 * w:], med_d[2 * w:], min_depth_mm))


def _second_angles(o0, d0, o1, d1, o2, d2, min_depth_mm: float) -> np.ndarray:
    """(K,) degrees: the angle between directions ``d1`` (K, 3) and the direction from ``o1`` to the
    nearest approach of rays ``(o0, d0)`` and ``(o2, d2)`` when it is ``min_depth_mm`` or farther
    along both, else (or with NaN origins) the mean of ``d0`` and ``d2`` (``median_noise_deg``)."""
    b, base = (d0 * d2).sum(1), o0 - o2
    e0, e2 = (d0 * base).sum(1), (d2 * base).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        s0, s2 = (b * e2 - e0) / (1 - b * b), (e2 - b * e0) / (1 - b * b)
        point = 0.5 * (o0 + s0[:, None] * d0 + o2 + s2[:, None] * d2)
        ahead = np.isfinite(point).all(1) & np.isfinite(o1).all(1) & (s0 >= min_depth_mm) & (s2 >= min_depth_mm)
    aim = d0 + d2
    aim[ahead] = point[ahead] - o1[ahead]
    return angle_deg(d1, aim)


def _diff_sd_deg(second_deg) -> float:
    """The per-axis sd, degrees, of the difference of two window medians from the angles (K,) between
    window medians and the mean of the medians a window before and after (``median_noise_deg``)."""
    return _diff_sd_of_quantile(float(np.quantile(second_deg, MEDIAN_NOISE_QUANTILE)))


def _diff_sd_of_quantile(q_deg: float) -> float:
    """``_diff_sd_deg`` of angles whose ``MEDIAN_NOISE_QUANTILE`` quantile is ``q_deg``."""
    return float(np.sqrt(2.0 / 1.5) * q_deg / RAYLEIGH_Q25)


def session_noise_deg(origins, directions, w: int, min_depth_mm: float) -> tuple[float, float]:
    """(per-sample noise sd, sd of the difference of two window medians), degrees per axis, of
    rays (M, 3) in time order (``sample_noise_deg``, ``median_noise_deg``); with too few samples
    for the second, it is derived from the first as for independent samples (and either is 0
    with fewer than 3 samples)."""
    noise, diff_sd = sample_noise_deg(directions), median_noise_deg(origins, directions, w, min_depth_mm)
    noise = noise if np.isfinite(noise) else 0.0
    if not np.isfinite(diff_sd):
        diff_sd = np.sqrt(2.0) * MEDIAN_SD * noise / np.sqrt(w)
    return noise, float(diff_sd)


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def eye_rays(samples: BinocularSamples) -> tuple[np.ndarray, np.ndarray]:
    """((2, N, 3) origins, mm, (2, N, 3) unit directions) of the left [0] and right [1] eyes'
    lines, in the samples' frame, NaN where that eye is not valid."""
    o, d = np.full((2, len(samples), 3), np.nan), np.full((2, len(samples), 3), np.nan)
    for e, (org, dirs, valid) in enumerate(((samples.left_origin_mm, samples.left_direction, samples.left_valid),
                                            (samples.right_origin_mm, samples.right_direction, samples.right_valid))):
        o[e, valid], d[e, valid] = org[valid], dirs[valid]
    return o, d


def jump_scores(o: np.ndarray, d: np.ndarray, config: SegmentConfig,
                eyes: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M,) the window test at each valid sample k (``world_jump_deg`` of the median rays of the
    ``window`` samples before k and of those from k on; 0 where a window is incomplete), and the
    (M, 3) median directions before and after each k (NaN where incomplete).

    Args:
        o, d: (M, 3) the valid samples' cyclopean origins (mm; NaN: unknown, then the test is
            the angle between directions) and unit directions, time order.
        eyes: the same samples' per-eye lines (``eye_rays``); given, where the two windows do
            not all have the same eyes the test compares like with like (``_mixed_score``).
    """
    w, m = config.window, len(d)
    score = np.zeros(m)
    before, after = np.full((m, 3), np.nan), np.full((m, 3), np.nan)
    if m < 2 * w:
        return score, before, after
    med_d = _unit(window_medians(d, w))                 # row j: samples j .. j + w - 1
    med_o = window_medians(o, w)
    k = np.arange(w, m - w + 1)
    before[k], after[k] = med_d[k - w], med_d[k]
    oa, ob = med_o[k - w], med_o[k]
    posed = np.all(np.isfinite(oa), axis=1) & np.all(np.isfinite(ob), axis=1)
    score[k] = angle_deg(before[k], after[k])
    if posed.any():
        kp = k[posed]
        score[kp] = world_jump_deg(oa[posed], before[kp], ob[posed], after[kp], config.min_depth_mm)
    if eyes is not None:
        for j in np.flatnonzero(mixed_positions(eyes[1], w)):     # windows j - w .. j + w - 1
            mixed = _mixed_score(eyes, slice(j - w, j), slice(j, j + w), config.min_depth_mm)
            score[j] = angle_deg(before[j], after[j]) if mixed is None else mixed
    return score, before, after


def _mixed_score(eyes: tuple[np.ndarray, np.ndarray], a: slice, b: slice, min_depth_mm: float) -> float | None:
    """The window test between samples ``a`` and ``b`` (two windows, or a window and one sample)
    whose samples do not all have the same eyes (``eyes``: (2, M, 3) per-eye origins and
    directions, NaN where invalid). A cyclopean ray switching between eyes moves by up to an
    eye's spacing (64 mm from one eye to the other) and turns by the vergence: a baseline the
    world test would take for the head's and let explain turns of up to 14 deg at 250 mm (the
    Tufts table's one-eye lines of both eyes were one fixation so). So each side's ray is made
    of the same eyes: the mean of the per-eye median rays of the eyes valid in at least half of
    each side's samples. With no such eye (one eye's lines before, the other's after) None: the
    caller takes the angle between the cyclopean directions, no parallax allowed (the vergence
    counts as a turn, as the eye-in-head rule counted it)."""
    eo, ed = eyes
    common = [e for e in range(2) if all(2 * np.isfinite(ed[e, win, 0]).sum() >= win.stop - win.start
                                         for win in (a, b))]
    if not common:
        return None
    oa, da, ob, db = (np.mean([np.nanmedian(x[e, win], axis=0) for e in common], axis=0)
                      for win in (a, b) for x in (eo, ed))
    da, db = _unit(da), _unit(db)
    if not (np.all(np.isfinite(oa)) and np.all(np.isfinite(ob))):
        return float(angle_deg(da, db))
    return float(world_jump_deg(oa, da, ob, db, min_depth_mm)[0])


def saccade_samples(o: np.ndarray, d: np.ndarray, cut: tuple[int, int, int], w: int, off_deg: float,
                    min_depth_mm: float, eyes: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[int, int]:
    """The saccade's samples around a run of the window test above its threshold ``cut``
    (first, last, peak): [first, last] indices into the rays ``(o, d)`` (M, 3), from the last
    sample before the peak whose ray passes within ``off_deg`` of a point of the before-window's
    median ray (``world_jump_deg``, points at ``min_depth_mm`` or farther; the window's own
    parallax is no saccade) to the first after it within ``off_deg`` of the after-window's,
    each looked for up to ``w`` samples away; then once more with the windows moved off the
    saccade's samples so found (a window holding some is pulled toward them). A run longer than
    a clean jump's (about ``w`` samples) keeps its middle, more than ``w`` samples from either
    end, in the saccade too (the gaze moved all along it). ``eyes`` (``eye_rays`` of the same
    samples): a sample whose eyes are not the window's is compared like with like
    (``_mixed_score``)."""
    k0, k1, c = cut
    code = None if eyes is None else np.isfinite(eyes[1][0, :, 0]) + 2 * np.isfinite(eyes[1][1, :, 0])

    def miss(j: int, window: slice, direction: np.ndarray) -> float:
        if code is not None and eyes is not None and np.any(code[window] != code[j]):
            mixed = _mixed_score(eyes, window, slice(j, j + 1), min_depth_mm)
            return float(angle_deg(d[j], direction)) if mixed is None else mixed
        origin = np.median(o[window], axis=0)
        if not (np.all(np.isfinite(origin)) and np.all(np.isfinite(o[j]))):
            return float(angle_deg(d[j], direction))
        return float(world_jump_deg(origin, direction, o[j], d[j], min_depth_mm)[0])

    first, last = c, c - 1
    for _ in range(2):          # again with windows clear of the saccade's samples the first pass found
        win_a, win_b = slice(max(first - w, 0), first), slice(last + 1, last + 1 + w)
        if win_a.stop - win_a.start < 1 or win_b.stop > len(d):
            break
        dir_a, dir_b = _unit(np.median(d[win_a], axis=0)), _unit(np.median(d[win_b], axis=0))
        end_a = c - 1
        while end_a >= max(c - w, 0) and miss(end_a, win_a, dir_a) > off_deg:
            end_a -= 1
        start_b = c
        while start_b < min(c + w, len(d)) and miss(start_b, win_b, dir_b) > off_deg:
            start_b += 1
        first, last = end_a + 1, start_b - 1
    return min(first, k0 + w), max(last, k1 - w)


def segment_fixations(samples: BinocularSamples, config: SegmentConfig = SegmentConfig()) -> np.ndarray:
    """Fixation labels (N,) int: 0, 1, 2... in time order, -1 for saccades, blinks and short
    or broken-off stretches.

    Args:
        samples: view lines in the world frame (a still head's, or the head frame's: the test
            is then the angle between directions), in time order.
    """
    n = len(samples)
    labels = np.full(n, -1)
    o, d = cyclopean_rays(samples)
    idx = np.flatnonzero(np.all(np.isfinite(d), axis=1))
    if len(idx) == 0:
        return labels
    ov, dv, tv = o[idx], d[idx], samples.t_s[idx]
    eo, ed = eye_rays(samples)
    m, w = len(idx), config.window
    noise, diff_sd = session_noise_deg(ov, dv, w, config.min_depth_mm)
    threshold = config.threshold_deg(diff_sd)
    score, _, _ = jump_scores(ov, dv, config, (eo[:, idx], ed[:, idx]))
    cuts = [_at_gap(cut, tv) for cut in _peaks(score, threshold)]
    gaps = np.flatnonzero(np.diff(tv) > config.max_gap_s) + 1
    # the second pass: the parallax each stretch's own lines allow (estimator.segdepth)
    more = refine_cuts(ov, dv, (eo[:, idx], ed[:, idx]), stretches(cuts, gaps, m, w), w, threshold,
                       line_noise_deg(noise, diff_sd, w), config.min_depth_mm)
    cuts = sorted(cuts + [_at_gap(cut, tv) for cut in more], key=lambda c: c[2])
    off = SAMPLE_K * np.hypot(noise, diff_sd / np.sqrt(2.0))
    in_fix = np.ones(m, bool)
    for cut in cuts:
        a, b = saccade_samples(ov, dv, cut, w, max(off, 0.5 * threshold), config.min_depth_mm, (eo[:, idx], ed[:, idx]))
        in_fix[a:b + 1] = False
    # each cut's peak starts a new stretch; so does a gap in time (long blinks, lost samples)
    peaks = {c[2] for c in cuts}
    bounds = sorted({0, m} | peaks | set(gaps.tolist()))
    settle = int(np.floor(config.settle_s / np.median(np.diff(tv)) + 1e-6)) if m > 1 else 0    # whole samples
    label = 0
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        sel = np.arange(a, b)[in_fix[a:b]]
        if len(sel) == 0:
            continue
        sel = sel[(tv[sel] >= tv[sel[0]] + config.trim_s) & (tv[sel] <= tv[sel[-1]] - config.trim_s)]
        if len(sel) == 0 or tv[sel[-1]] - tv[sel[0]] < config.min_fixation_s:
            continue
        sel = sel[settle if a in peaks else 0:len(sel) - (settle if b in peaks else 0)]     # long enough: settled
        labels[idx[sel]] = label
        label += 1
    log.info("%d fixations in %d samples (%d valid; %d saccades over %.2f deg, %d of them within the depth "
             "the lines showed; noise %.2f deg a sample, %.2f deg between window medians; %d time gaps)", label, n,
             m, len(cuts), threshold, len(more), noise, diff_sd, len(gaps))
    return labels


class OnlineSegmenter:
    """``segment_fixations`` one sample at a time, for a live stream.

    The same test, made as soon as the window after a sample is full: how far the median
    cyclopean ray of the ``window`` samples after it misses every point of the median ray of the
    ``window`` before it between the depths the fixation's lines so far fix (``LineSums3``, running
    sums since the fixation began, ``estimator.segdepth``; ``min_depth_mm`` to infinity while they
    fix none; ``world_jump_deg``; without origins the angle between the directions), against the
    same threshold (``SegmentConfig.threshold_deg`` of the window medians' noise measured as
    ``median_noise_deg`` measures it, on the last ``NOISE_SAMPLES`` samples; twice ``jump_deg``
    until ``2 window`` of those measures have come). Crossing it ends the fixation; the samples
    until the test falls back under it (the saccade, as the windows see it) belong to no
    fixation, and the next fixation's lines start where it clears. A gap over ``max_gap_s`` ends a
    fixation too, and the sample after it starts the next. A still target's point stays put
    however the head moves, so the walk's parallax is no saccade; a saccade moves the point.

    Feed it the binocular samples' cyclopean rays (one eye alone is off the cyclopean line by
    half the vergence, which is not a saccade), and the eyes' own lines for the depth.
    """

    NOISE_SAMPLES = 600

    def __init__(self, config: SegmentConfig = SegmentConfig()):
        self.config = config
        self.buf: deque = deque(maxlen=2 * config.window)      # (direction, origin or None, lines or None)
        self.medians: deque = deque(maxlen=2 * config.window + 1)    # (origin or None, direction) of the last windows
        self.seconds = sc.SlidingQuantile(self.NOISE_SAMPLES)   # median_noise_deg's angle at each window
        self.turns = sc.SlidingQuantile(self.NOISE_SAMPLES)     # angle of each sample off its neighbours' mean
        self.sums = sc.LineSums3()      # the current fixation's lines before the after-window
        self.in_saccade = False
        self.run = 0                    # positions since the current saccade's crossing
        self.last_t: float | None = None

    def update(self, t_s: float, direction, origin=None, lines=None) -> bool:
        """Add a sample at time ``t_s`` (s) with unit cyclopean direction (3,) and its origin (3,)
        (world frame, mm; the eyes' midpoint; None: unknown, the test is then on directions),
        and its eyes' lines (origins (E, 3), mm, and unit directions (E, 3), world; None: the
        cyclopean ray alone).

        Returns:
            True when this sample ends the current fixation. Afterwards ``in_saccade`` tells
            whether the sample (and the ones after it, until it clears) belongs to no fixation.
        """
        w = self.config.window
        gap = self.last_t is not None and t_s - self.last_t > self.config.max_gap_s
        self.last_t = t_s
        d = sc.unit3(sc.vec3(direction))    # plain float 3-tuples (estimator.segscalar)
        o = None if origin is None else sc.vec3(origin)
        item = (d, o, (None if o is None else ((o, d),)) if lines is None else sc.lines3(*lines))
        if gap:
            self.buf.clear()
            self.medians.clear()
            self.sums.reset()
            self.buf.append(item)
            self.in_saccade = False
            return True
        self.buf.append(item)
        self._measure_noise()
        if len(self.buf) > w and not self.in_saccade and self.buf[-w - 1][2] is not None:
            self.sums.add(self.buf[-w - 1][2])            # it has left the after-window
        if len(self.buf) < 2 * w:
            return False
        noise = self.noise_deg()
        threshold = 2.0 * self.config.jump_deg if noise is None else self.config.threshold_deg(noise[1])
        if not self.in_saccade:
            jumped, self.run = self.score(noise) > threshold, 0
        else:                                            # the lines frozen at its start (segdepth.run_end)
            self.run += 1
            jumped = self.score(None) > threshold or (self.run < w and self.score(noise) > threshold)
            if not jumped:                               # the saccade is over: the next fixation's lines start
                self.sums.reset()
        ended = jumped and not self.in_saccade
        self.in_saccade = jumped
        return ended

    def _measure_noise(self) -> None:
        """The noise measures after a sample: its angle off its neighbours' mean
        (``sample_noise_deg``) and, once ``2 window + 1`` window medians have come since the
        last gap, ``median_noise_deg``'s angle at the window ``window`` samples back."""
        w, buf = self.config.window, self.buf
        if len(buf) >= 3:
            self.turns.append(sc.angle3_deg(buf[-2][0], sc.add3(buf[-3][0], buf[-1][0])))
        if len(buf) < w:
            return
        self.medians.append(sc.window_median(list(buf)[-w:]))
        if len(self.medians) == 2 * w + 1:
            (o0, d0), (o1, d1), (o2, d2) = (self.medians[i] for i in (0, w, 2 * w))
            self.seconds.append(sc.second_angle3_deg(o0, d0, o1, d1, o2, d2, self.config.min_depth_mm))

    def noise_deg(self) -> tuple[float, float] | None:
        """(per-sample noise, sd of the difference of two window medians), degrees, as measured
        so far (``session_noise_deg``: the second derived from the first until ``2 window``
        measures of it have come); None before ``2 window`` samples."""
        w = self.config.window
        if len(self.turns) < 2 * w:
            return None
        noise = self.turns.median() / SECOND_DIFF_MEDIAN
        if len(self.seconds) >= 2 * w:
            return noise, _diff_sd_of_quantile(self.seconds.quantile(MEDIAN_NOISE_QUANTILE))
        return noise, float(np.sqrt(2.0) * MEDIAN_SD * noise / np.sqrt(w))

    def threshold_deg(self) -> float:
        """The saccade threshold now, degrees (``SegmentConfig.threshold_deg`` of ``noise_deg``'s
        second figure), twice ``jump_deg`` before ``2 window`` samples."""
        noise = self.noise_deg()
        return 2.0 * self.config.jump_deg if noise is None else self.config.threshold_deg(noise[1])

    def score(self, noise: tuple[float, float] | None) -> float:
        """The window test on the full buffer, degrees (``world_jump_deg`` between the depths the
        fixation's lines fix, ``LineSums3.bounds``, at the ``noise_deg`` given; None: from
        ``min_depth_mm`` on). Its two windows' medians are the latest and the one ``window``
        samples before (kept by ``_measure_noise``; not kept for window 1 just after a gap)."""
        w = self.config.window
        ob, db = self.medians[-1]
        oa, da = self.medians[-1 - w] if len(self.medians) > w else sc.window_median(list(self.buf)[:w])
        if oa is None or ob is None:
            return sc.angle3_deg(da, db)
        near, far = (self.config.min_depth_mm, math.inf) if noise is None else \
            self.sums.bounds(oa, da, line_noise_deg(*noise, w), self.config.min_depth_mm)
        return sc.world_jump3_deg(oa, da, ob, db, near, far)
