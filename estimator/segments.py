"""Gaze segmentation: which view lines belong to one fixated target.

A person looks at one thing, then jumps (a saccade) to the next. Two rules:

- The world rule, for lines in the world frame with the head's poses
  (``estimator.worldsegments.segment_world``, ``segment_fixations(world=True)``): a fixation is
  the gaze ray held on a point in the world while the head moves (docs/processing.md).
- The eye-in-head rule, for lines without poses (a still head assumed: the directions are the
  eyes' in the head): the direction stays put while a target is fixated, drifts smoothly while
  a moving one is pursued, and jumps at a saccade. Single samples carry about 1 deg of noise per
  eye, so the test is made between windows: at each sample, the angle between the median
  cyclopean direction of the ``window`` valid samples before it and of those after it. Peaks of
  that angle above ``jump_deg`` are saccades; the stretches between them are fixations, kept
  when longer than ``min_fixation_s``. Blinks (both eyes invalid) are skipped, not treated as
  saccades; a gap longer than ``max_gap_s`` ends a fixation. (Applied to world lines, it is the
  rule ``process`` used before the world rule: a walk's parallax reads as saccades.)

Defaults (documented in docs/processing.md): window 8 samples (0.13 s at 60 Hz), jump 3 deg,
minimum fixation 0.3 s, maximum gap 0.5 s.
"""
from __future__ import annotations

import dataclasses
import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from .frames import angle_deg
from .lines import BinocularSamples
from .worldsegments import JUMP_K, ChainSplitter, NoiseMeter, course_scores, course_window, segment_world

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SegmentConfig:
    """The fixation test's settings (docs/processing.md).

    Attributes:
        window: samples on each side whose median directions are compared.
        jump_deg: the angle between the two medians above which a saccade is found, degrees.
        min_fixation_s: shorter fixations are dropped, seconds.
        max_gap_s: a gap in the data longer than this ends a fixation, seconds.
        trim_s: time cut from each end of a fixation (the saccade's tails), seconds.
        noise_deg: the world rule's noise, one sample's cyclopean direction's sd per axis,
            degrees; None: measured on the lines (``segment_world``).
    """

    window: int = 8
    jump_deg: float = 3.0
    min_fixation_s: float = 0.3
    max_gap_s: float = 0.5
    trim_s: float = 0.05
    noise_deg: float | None = None

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


def cyclopean_directions(samples: BinocularSamples) -> np.ndarray:
    """(N, 3) unit mean of the valid eyes' directions (NaN where neither is valid)."""
    d = np.zeros((len(samples), 3))
    n = np.zeros(len(samples))
    for dirs, valid in ((samples.left_direction, samples.left_valid), (samples.right_direction, samples.right_valid)):
        d[valid] += dirs[valid]
        n += valid
    out = np.full((len(samples), 3), np.nan)
    ok = n > 0
    out[ok] = d[ok] / np.linalg.norm(d[ok], axis=1, keepdims=True)
    return out


def segment_fixations(samples: BinocularSamples, config: SegmentConfig = SegmentConfig(),
                      world: bool = False) -> np.ndarray:
    """Fixation labels (N,) int: 0, 1, 2... in time order, -1 for saccades, blinks and short
    or broken-off stretches.

    Args:
        samples: view lines in time order: in the world frame (head poses known) or in the head
            frame (no poses: the eye-in-head directions).
        world: the world rule (``segment_world``: the rays hold a point in the world while the
            head moves), for lines in the world frame; False: the eye-in-head rule, the jump
            between the median directions of the windows on either side of each sample (the
            module's docstring), the rule for lines without head poses.
    """
    if world:
        return segment_world(samples, config)
    n = len(samples)
    labels = np.full(n, -1)
    d = cyclopean_directions(samples)
    valid = np.all(np.isfinite(d), axis=1)
    idx = np.flatnonzero(valid)
    if len(idx) == 0:
        return labels
    dv, tv = d[idx], samples.t_s[idx]
    w = config.window
    m = len(idx)
    score = np.zeros(m)
    for k in range(w, m - w + 1):
        a = np.median(dv[k - w:k], axis=0)
        b = np.median(dv[k:k + w], axis=0)
        score[k] = angle_deg(a, b)
    stretches, n_cuts, n_gaps = fixation_stretches(tv, score, np.full(m, config.jump_deg), config)
    for label, sel in enumerate(stretches):
        labels[idx[sel]] = label
    log.info("%d fixations in %d samples (%d valid; %d saccades, %d time gaps)", len(stretches), n, m, n_cuts, n_gaps)
    return labels


def fixation_stretches(t_s: np.ndarray, score: np.ndarray, jump: np.ndarray,
                       config: SegmentConfig) -> tuple[list, int, int]:
    """The stretches between saccades and gaps: (index arrays into ``t_s``, saccades, gaps).

    A saccade is a run of ``score`` (M,) degrees above ``jump`` (M,) degrees, cut at its peak;
    a gap in ``t_s`` (M,) s over ``max_gap_s`` also ends a stretch. The samples of a saccade's
    run (and ``window`` // 2 either side) and ``trim_s`` at each end are left out; stretches
    shorter than ``min_fixation_s`` are dropped."""
    m, w = len(t_s), config.window
    cuts = []
    k = 0
    while k < m:
        if score[k] > jump[k]:
            j = k
            while j + 1 < m and score[j + 1] > jump[j + 1]:
                j += 1
            cuts.append((k, j, k + int(np.argmax(score[k:j + 1] - jump[k:j + 1]))))
            k = j + 1
        else:
            k += 1
    gaps = np.flatnonzero(np.diff(t_s) > config.max_gap_s)
    bounds = sorted({0, m} | {c[2] for c in cuts} | set((gaps + 1).tolist()))
    out = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        ta, tb = t_s[a] + config.trim_s, t_s[b - 1] - config.trim_s
        sel = np.arange(a, b)
        for c0, c1, _ in cuts:
            sel = sel[(sel < c0 - w // 2) | (sel > c1 + w // 2)] if c0 - w // 2 <= sel.max(initial=-1) else sel
        sel = sel[(t_s[sel] >= ta) & (t_s[sel] <= tb)]
        if len(sel) and t_s[sel[-1]] - t_s[sel[0]] >= config.min_fixation_s:
            out.append(sel)
    return out, len(cuts), len(gaps)


RATE_SAMPLES = 10
"""``OnlineSegmenter`` without settings takes the eye rate from this many sample intervals."""


class OnlineSegmenter:
    """Fixations found one sample at a time, for a live stream.

    The world rule (``world``, the lines in the world with the head's poses), as
    ``segment_world``: the course score (``course_scores``) of the ``window`` samples before and
    the ``window`` after a sample, made as soon as the window after it is full, against the same
    threshold (``jump_deg``, or ``JUMP_K`` sd of the score for the noise: ``config.noise_deg``,
    else measured as the stream goes, ``NoiseMeter``); ``chain`` (a ``ChainSplitter``, renewed
    at each saccade and gap) splits a stretch where the eye rate hid a saccade, as
    ``split_chain`` does offline. The caller feeds ``chain`` the samples of the fixation.

    The eye-in-head rule (``world`` False): the angle between the median cyclopean direction of
    the ``window`` samples before and of the ``window`` after (``segment_fixations``'s). Crossing
    the threshold ends the fixation; the samples until the score falls back under it (the
    saccade, as the windows see it) belong to no fixation. A gap over ``max_gap_s`` ends a
    fixation too, and the sample after it starts the next. The reference thus follows a target
    whose direction drifts as the head moves, as the offline test does; only a jump counts.

    Feed it the binocular samples' cyclopean directions (one eye alone is off the cyclopean line
    by half the vergence, which is not a saccade).
    """

    def __init__(self, config: SegmentConfig | None = None, world: bool = False):
        self.rate_times: list | None = None if config is not None else []
        self.config = config if config is not None else SegmentConfig()
        self.world = world
        self.buf: deque = deque(maxlen=2 * self.config.window)     # (direction (3,), origin (3,) or None, t)
        self.in_saccade = False
        self.last_t: float | None = None
        self.cut_t: float | None = None     # the world rule: the time of the last saccade's step, s
        self.peak: tuple | None = None      # ... the saccade being seen: (excess, its time, samples since)
        self.noise = NoiseMeter(self.config)
        self.chain = ChainSplitter(self.noise.value, self.config)

    def _learn_rate(self, t_s: float) -> None:
        """Without a config, the settings of the eye rate (``SegmentConfig.for_rate``) once the
        first ``RATE_SAMPLES`` samples' times give it (one over their median interval), as
        ``process`` takes them from the session's rate."""
        self.rate_times.append(float(t_s))
        dt = np.diff(self.rate_times)
        dt = dt[dt > 0]
        if len(dt) < RATE_SAMPLES:
            return
        rate = 1.0 / float(np.median(dt))
        self.config = SegmentConfig.for_rate(rate)
        if self.world:
            self.config = dataclasses.replace(self.config, window=course_window(self.config, rate))
        self.rate_times = None
        self.buf = deque(self.buf, maxlen=2 * self.config.window)
        self.noise.config = self.chain.config = self.config

    def update(self, t_s: float, direction, origin=None, depth_mm: float = np.inf) -> bool:
        """Add a sample at time ``t_s`` (s) with unit cyclopean direction (3,) (world frame).

        ``origin`` (3,) (world, mm; the eyes' midpoint): the world rule needs it. With the
        eye-in-head rule, it and ``depth_mm`` (the fixated point's distance from it, when known)
        take the head's translation out of the test: each buffered sample's gaze is taken to the
        point ``depth_mm`` along it, and the directions compared are to those points from the
        newest origin (too near a depth over-corrects, too far one under-corrects, down to no
        correction: the default, infinity).

        Returns:
            True when this sample ends the current fixation. Afterwards, with the eye-in-head
            rule, ``in_saccade`` tells whether the sample (and the ones after it, until it
            clears) belongs to no fixation; with the world rule, ``cut_t`` is the time of the
            saccade's step (midway between the samples either side of it): the samples after it
            start the next fixation, as offline.
        """
        if self.rate_times is not None:
            self._learn_rate(t_s)
        w = self.config.window
        gap = self.last_t is not None and t_s - self.last_t > self.config.max_gap_s
        self.last_t = t_s
        item = (np.asarray(direction, float), None if origin is None else np.asarray(origin, float), float(t_s))
        if self.world:
            self.noise.push(t_s, item[1], item[0])
            self.chain.tau = self.noise.hold_deg()
        if gap:
            self.buf.clear()
            self.buf.append(item)
            self.in_saccade = False
            self.peak, self.cut_t = None, None
            self.chain = ChainSplitter(self.noise.value, self.config)
            return True
        self.buf.append(item)
        if len(self.buf) < 2 * w:
            return False
        if self.world:
            return self._world_step(w)
        b = self._directions(depth_mm)
        jumped = angle_deg(np.median(b[:w], axis=0), np.median(b[w:], axis=0)) > self.config.jump_deg
        ended = jumped and not self.in_saccade
        self.in_saccade = jumped
        return ended

    def _world_step(self, w: int) -> bool:
        """The world rule's test on the full buffer: a saccade ends the fixation at its peak, as
        offline (``saccade_peaks``): an excess of the score over its threshold with no larger one
        in the ``w`` samples after it (so seen ``w`` samples late); ``cut_t`` is that boundary's
        time."""
        t = np.array([x[2] for x in self.buf])
        score, sd = course_scores(t, np.array([x[0] for x in self.buf]), w)
        excess = float(score[w] - max(self.config.jump_deg, JUMP_K * sd[w] * self.noise.value))
        boundary_t = 0.5 * (t[w - 1] + t[w])
        self.in_saccade = excess > 0
        if excess > 0 and (self.peak is None or excess > self.peak[0]):
            self.peak = (excess, boundary_t, 0)
            return False
        if self.peak is None:
            return False
        self.peak = (self.peak[0], self.peak[1], self.peak[2] + 1)
        if self.peak[2] < w:
            return False
        self.cut_t = self.peak[1]
        self.peak = None
        self.chain = ChainSplitter(self.noise.value, self.config)
        return True

    def _directions(self, depth_mm: float) -> np.ndarray:
        """(2 window, 3) the buffered directions, or with a finite depth and every origin known the
        directions from the newest origin to the points ``depth_mm`` along them."""
        d = np.array([x[0] for x in self.buf])
        if not np.isfinite(depth_mm) or any(x[1] is None for x in self.buf):
            return d
        o = np.array([x[1] for x in self.buf])
        p = o + depth_mm * d / np.linalg.norm(d, axis=1, keepdims=True) - o[-1]
        return p / np.linalg.norm(p, axis=1, keepdims=True)


def same_target(p1, cov1, p2, cov2, origin=None, floor_deg: float = 0.5, threshold: float = 11.34) -> bool:
    """Whether two estimates (3,) with covariances (3, 3) mm^2 are one target seen twice:
    Mahalanobis distance below the chi-square 99 % point (3 dof). Each covariance gets an
    isotropic floor of ``floor_deg`` times the distance from ``origin`` (the head, default the
    world origin): calibration biases shift a whole fixation's lines together, which the
    covariance of its random noise does not cover. Without covariances: within 5 % of the
    distance."""
    p1, p2 = np.asarray(p1, float), np.asarray(p2, float)
    o = np.zeros(3) if origin is None else np.asarray(origin, float)
    dist = 0.5 * (np.linalg.norm(p1 - o) + np.linalg.norm(p2 - o))
    if cov1 is None or cov2 is None:
        return bool(np.linalg.norm(p1 - p2) < 0.05 * dist)
    floor = (np.deg2rad(floor_deg) * dist) ** 2 * np.eye(3)
    d = p1 - p2
    return bool(d @ np.linalg.solve(np.asarray(cov1) + np.asarray(cov2) + 2 * floor, d) < threshold)
