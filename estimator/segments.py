"""Gaze segmentation: which view lines belong to one fixated target.

A person looks at one thing, then jumps (a saccade) to the next. In the world frame the gaze
direction stays put while a fixed target is fixated (the head may move; the parallax is small),
drifts smoothly while a moving one is pursued, and jumps at a saccade. Single samples carry
about 1 deg of noise per eye, so the test is made between windows: at each sample, the angle
between the median cyclopean direction of the ``window`` valid samples before it and of those
after it. Peaks of that angle above ``jump_deg`` are saccades; the stretches between them are
fixations, kept when longer than ``min_fixation_s``. Blinks (both eyes invalid) are skipped,
not treated as saccades; a gap longer than ``max_gap_s`` ends a fixation.

Defaults (documented in docs/processing.md): window 8 samples (0.13 s at 60 Hz), jump 3 deg,
minimum fixation 0.3 s, maximum gap 0.5 s.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from .frames import angle_deg
from .lines import BinocularSamples

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
    """

    window: int = 8
    jump_deg: float = 3.0
    min_fixation_s: float = 0.3
    max_gap_s: float = 0.5
    trim_s: float = 0.05

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


def segment_fixations(samples: BinocularSamples, config: SegmentConfig = SegmentConfig()) -> np.ndarray:
    """Fixation labels (N,) int: 0, 1, 2... in time order, -1 for saccades, blinks and short
    or broken-off stretches.

    Args:
        samples: view lines in the world frame, in time order.
    """
    n_samples = len(samples)
    labels = np.full(n_samples, -1)
    directions = cyclopean_directions(samples)
    valid = np.all(np.isfinite(directions), axis=1)
    idx = np.flatnonzero(valid)
    if len(idx) == 0:
        return labels
    dv, tv = directions[idx], samples.t_s[idx]
    window = config.window
    n_valid = len(idx)
    score = np.zeros(n_valid)
    for k in range(window, n_valid - window + 1):
        before = np.median(dv[k - window:k], axis=0)
        after = np.median(dv[k:k + window], axis=0)
        score[k] = angle_deg(before, after)
    # saccades: local maxima of the score above the threshold (one per jump)
    cuts = []
    k = 0
    while k < n_valid:
        if score[k] > config.jump_deg:
            j = k
            while j + 1 < n_valid and score[j + 1] > config.jump_deg:
                j += 1
            cuts.append((k, j, k + int(np.argmax(score[k:j + 1]))))
            k = j + 1
        else:
            k += 1
    # gaps in time (long blinks, lost samples) also end a fixation
    gaps = np.flatnonzero(np.diff(tv) > config.max_gap_s)
    bounds = sorted({0, n_valid} | {c[2] for c in cuts} | set((gaps + 1).tolist()))
    label = 0
    for start, stop in zip(bounds[:-1], bounds[1:], strict=True):
        # drop the samples inside the jump region around each cut and trim the ends
        ta, tb = tv[start] + config.trim_s, tv[stop - 1] - config.trim_s
        sel = np.arange(start, stop)
        for c0, c1, _ in cuts:
            if c0 - window // 2 <= sel.max(initial=-1):
                sel = sel[(sel < c0 - window // 2) | (sel > c1 + window // 2)]
        sel = sel[(tv[sel] >= ta) & (tv[sel] <= tb)]
        if len(sel) == 0 or tv[sel[-1]] - tv[sel[0]] < config.min_fixation_s:
            continue
        labels[idx[sel]] = label
        label += 1
    log.info("%d fixations in %d samples (%d valid; %d saccades, %d time gaps)", label, n_samples, n_valid, len(cuts),
             len(gaps))
    return labels


class OnlineSegmenter:
    """``segment_fixations`` one sample at a time, for a live stream.

    The same test, made as soon as the window after a sample is full: the angle between the
    median cyclopean direction of the ``window`` samples before and of the ``window`` after.
    Crossing ``jump_deg`` ends the fixation; the samples until the angle falls back under it
    (the saccade, as the windows see it) belong to no fixation. A gap over ``max_gap_s`` ends a
    fixation too, and the sample after it starts the next. The reference thus follows a target
    whose direction drifts as the head moves, as the offline test does; only a jump counts.

    Feed it the binocular samples' cyclopean directions (one eye alone is off the cyclopean line
    by half the vergence, which is not a saccade).
    """

    def __init__(self, config: SegmentConfig = SegmentConfig()):
        self.config = config
        self.buf: deque = deque(maxlen=2 * config.window)      # (direction (3,), origin (3,) or None)
        self.in_saccade = False
        self.last_t: float | None = None

    def update(self, t_s: float, direction, origin=None, depth_mm: float = np.inf) -> bool:
        """Add a sample at time ``t_s`` (s) with unit cyclopean direction (3,) (world frame).

        ``origin`` (3,) (world, mm; the eyes' midpoint) and ``depth_mm`` (the fixated point's
        distance from it, when known) take the head's translation out of the test: each
        buffered sample's gaze is taken to the point ``depth_mm`` along it, and the directions
        compared are to those points from the newest origin. A still target's point stays put
        however the head moves, where its direction turns by the parallax (1 deg per 17 mm
        sideways at 1 m), which eats into the margin below ``jump_deg``. A saccade moves the
        point by its amplitude. The caller gives a depth no nearer than the point can be
        (``live.estimation``: the far end of its interval): too near a depth over-corrects, too
        far one under-corrects, down to no correction (the default, infinity).

        Returns:
            True when this sample ends the current fixation. Afterwards ``in_saccade`` tells
            whether the sample (and the ones after it, until it clears) belongs to no fixation.
        """
        w = self.config.window
        gap = self.last_t is not None and t_s - self.last_t > self.config.max_gap_s
        self.last_t = t_s
        item = (np.asarray(direction, float), None if origin is None else np.asarray(origin, float))
        if gap:
            self.buf.clear()
            self.buf.append(item)
            self.in_saccade = False
            return True
        self.buf.append(item)
        if len(self.buf) < 2 * w:
            return False
        b = self._directions(depth_mm)
        before, after = np.median(b[:w], axis=0), np.median(b[w:], axis=0)
        jumped = angle_deg(before, after) > self.config.jump_deg
        ended = jumped and not self.in_saccade
        self.in_saccade = jumped
        return ended

    def _directions(self, depth_mm: float) -> np.ndarray:
        """(2 window, 3) the buffered directions, or with a finite depth and every origin known the
        directions from the newest origin to the points ``depth_mm`` along them."""
        d = np.array([x[0] for x in self.buf])
        if not np.isfinite(depth_mm) or any(x[1] is None for x in self.buf):
            return d
        o = np.array([x[1] for x in self.buf])
        p = o + depth_mm * d / np.linalg.norm(d, axis=1, keepdims=True) - o[-1]
        return p / np.linalg.norm(p, axis=1, keepdims=True)

