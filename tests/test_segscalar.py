"""The online segmenter's plain-float maths (``estimator.segscalar``) against the numpy functions
it stands in for, one call at a time and over long streams: ``OnlineSegmenter`` against the numpy
implementation it had before (``NumpySegmenter`` below, its code as of seg27: the depth-bounded
test with the eyes' own lines), with the same scores, thresholds and depth bounds to 1e-9 and the
same decisions at every sample."""

import math
from collections import deque

import numpy as np
import pytest

from estimator.frames import angle_deg
from estimator.segdepth import LineSums, line_noise_deg, world_jump_deg
from estimator.segments import (
    MEDIAN_SD,
    SECOND_DIFF_MEDIAN,
    OnlineSegmenter,
    SegmentConfig,
    _diff_sd_deg,
    _second_angles,
    _unit,
)
from estimator.segscalar import (
    LineSums3,
    SlidingQuantile,
    angle3_deg,
    lines3,
    median3,
    second_angle3_deg,
    unit3,
    vec3,
    window_median,
    world_jump3_deg,
)


def _rays(rng, n, baseline_mm):
    """n random rays: origins within ``baseline_mm`` of 0 and unit directions, as (n, 3) arrays."""
    return rng.normal(0, baseline_mm, (n, 3)), _unit(rng.normal(size=(n, 3)))


@pytest.mark.parametrize("baseline_mm", [0.0, 5.0, 100.0, 2000.0])
def test_world_jump_of_one_pair_is_the_numpy_ones(baseline_mm):
    rng = np.random.default_rng(0)
    oa, da = _rays(rng, 3000, baseline_mm)
    ob, db = _rays(rng, 3000, baseline_mm)
    db[:1000] = _unit(da[:1000] + rng.normal(0, 0.03, (1000, 3)))       # near pairs: both branches
    ob[1000:1500] = oa[1000:1500]                                          # no baseline
    far = np.where(rng.random(3000) < 0.5, np.inf, rng.uniform(250.0, 5000.0, 3000))    # a far bound, or none
    far[:200] = 250.0                                                                      # one point
    want = world_jump_deg(oa, da, ob, db, 250.0, far)
    got = [world_jump3_deg(vec3(oa[k]), vec3(da[k]), vec3(ob[k]), vec3(db[k]), 250.0, far[k]) for k in range(len(oa))]
    assert np.max(np.abs(np.array(got) - want)) <= 1e-9
    assert np.all(world_jump_deg(oa, da, ob, db, 250.0)[far == np.inf] == want[far == np.inf])
    both = np.concatenate([want, angle_deg(db, da)])
    assert both.min() < 1.0 and both.max() > 90.0


def test_world_jump_and_angles_with_nan_and_degenerate_input_as_numpy():
    a, b = (0.0, 0.0, 1.0), (0.0, 0.6, 0.8)
    nan3 = (math.nan,) * 3
    with np.errstate(invalid="ignore", divide="ignore"):
        for oa, ob in ((nan3, (0.0,) * 3), ((0.0,) * 3, nan3), ((0.0, 0.0, -250.0), (0.0, 0.0, 0.0))):
            want = world_jump_deg(np.array(oa), np.array(a), np.array(ob), np.array(b), 250.0)[0]
            got = world_jump3_deg(oa, a, ob, b, 250.0)
            assert (math.isnan(got) and math.isnan(want)) or abs(got - want) <= 1e-9
        assert all(math.isnan(x) for x in unit3((0.0, 0.0, 0.0)))
        assert unit3((3.0, 0.0, 4.0)) == pytest.approx((0.6, 0.0, 0.8), abs=1e-15)
    assert angle3_deg(a, b) == pytest.approx(float(angle_deg(a, b)), abs=1e-12)
    assert angle3_deg(a, (0.0, 0.0, -2.0)) == pytest.approx(180.0, abs=1e-12)


@pytest.mark.parametrize("baseline_mm", [0.0, 30.0, 500.0])
def test_second_angle_of_one_triple_is_the_numpy_ones(baseline_mm):
    rng = np.random.default_rng(1)
    n = 2000
    point = rng.normal(0, 800, (n, 3)) + [0.0, 0.0, 1000.0]
    o = rng.normal(0, baseline_mm, (3, n, 3))
    d = _unit(point[None] - o + rng.normal(0, 5.0, (3, n, 3)))
    d[:, :300] = _unit(rng.normal(size=(3, 300, 3)))                     # rays that do not meet ahead
    o[1, 300:400] = np.nan                                                # an origin unknown
    o[0, 400:450] = np.nan
    with np.errstate(invalid="ignore"):
        want = _second_angles(o[0], d[0], o[1], d[1], o[2], d[2], 250.0)

    def ray(i, k, none):             # an unknown origin as None (as the segmenter keeps it) or NaN
        return (None if none and np.isnan(o[i, k, 0]) else vec3(o[i, k])), vec3(d[i, k])

    for none in (True, False):
        got = [second_angle3_deg(*ray(0, k, none), *ray(1, k, none), *ray(2, k, none), 250.0) for k in range(n)]
        assert np.max(np.abs(np.array(got) - want)) <= 1e-9
    assert np.sum(want > 10.0) > 100 and np.sum(want < 1.0) > 100


@pytest.mark.parametrize("depth_mm", [300.0, 1500.0, 6000.0, 1e6])
def test_line_sums_and_their_depth_bounds_are_the_numpy_ones(depth_mm):
    """Both eyes' lines at a point ``depth_mm`` ahead of a swaying head, a few with one eye, one
    with no valid origin first (the sums' centre is the first finite origin), a few not finite:
    the same sums and the same (near, far) along rays toward, beside and away from the point,
    at each count of lines, at a low and a high noise (a misfit that inflates the interval)."""
    rng = np.random.default_rng(int(depth_mm))
    point = np.array([100.0, -50.0, depth_mm])
    fast, ref = LineSums3(), LineSums()
    fast.add(lines3(np.full((2, 3), np.nan), np.full((2, 3), np.nan)))
    assert fast.center is None and fast.bounds((0.0,) * 3, (0.0, 0.0, 1.0), 1.0, 250.0) == (250.0, math.inf)
    finite = 0
    for k in range(60):
        eo = rng.normal(0, 20.0, 3) + np.array([[-32.0, 0.0, 0.0], [32.0, 0.0, 0.0]])
        ed = _unit(point - eo + rng.normal(0, 0.01 * depth_mm, (2, 3)))
        if k % 7 == 3:
            eo[k % 2] = np.nan                                            # one eye's line
        if k == 0:
            eo[0], ed[1, 2] = np.nan, np.inf                              # no first origin; a bad direction
        fast.add(lines3(eo, ed))
        ref.add(eo, ed)
        assert fast.n == ref.n and fast.center == tuple(ref.center)
        assert np.allclose(np.reshape(fast.A, (3, 3)), ref.A, rtol=1e-12, atol=1e-12 * max(1, ref.n))
        assert fast.c == pytest.approx(ref.c, rel=1e-11, abs=1e-9)
        for o_a, aim in ((eo[1], point), (rng.normal(0, 50, 3), point + [400.0, 0.0, 0.0]), (eo[1], -point)):
            o_a = np.nan_to_num(o_a)
            d_a = _unit(aim - o_a)
            for noise in (0.05, 2.0):
                want = ref.bounds(o_a, d_a, noise, 250.0)
                assert fast.bounds(vec3(o_a), vec3(d_a), noise, 250.0) == pytest.approx(want, rel=1e-9)
                finite += np.isfinite(want[1]) and want[0] > 250.0
    assert finite > 100 if depth_mm < 2000 else finite == 0         # bounded near, open far


def test_medians_and_sliding_quantile_are_numpys_bit_for_bit():
    rng = np.random.default_rng(2)
    for n in (1, 2, 7, 8, 9):
        rows = [vec3(x) for x in rng.normal(size=(n, 3))]
        assert median3(rows) == tuple(np.median(np.array(rows), axis=0))
    assert math.isnan(median3([(1.0, 2.0, 3.0), (math.nan, 2.0, 3.0)])[0])
    rows = [(math.inf, -math.inf, 1.0), (-math.inf, 2.0, math.inf), (0.0, 1.0, -math.inf)]
    for n in (2, 3):
        with np.errstate(invalid="ignore"):
            want = np.median(np.array(rows[:n]), axis=0)
        assert all((math.isnan(x) and math.isnan(y)) or x == y for x, y in zip(median3(rows[:n]), want, strict=True))
    items = [(unit3(vec3(d)), vec3(o)) for d, o in zip(rng.normal(size=(8, 3)), rng.normal(size=(8, 3)), strict=True)]
    o, d = window_median(items)
    assert o == tuple(np.median([x[1] for x in items], axis=0))
    assert np.max(np.abs(np.array(d) - _unit(np.median([x[0] for x in items], axis=0)))) <= 1e-15
    assert window_median(items[:3] + [(items[3][0], None)])[0] is None
    sq, ref = SlidingQuantile(50), deque(maxlen=50)
    values = np.round(rng.exponential(size=400), 2)                       # ties
    values[[100, 130]] = np.nan
    for k, x in enumerate(values):
        sq.append(float(x))
        ref.append(float(x))
        arr = np.array(ref)
        for q in (0.0, 0.25, 0.5, 0.9, 1.0):
            want = np.quantile(arr, q)
            assert (math.isnan(want) and math.isnan(sq.quantile(q))) or sq.quantile(q) == want, (k, q)
        want = np.median(arr)
        assert (math.isnan(want) and math.isnan(sq.median())) or sq.median() == want
        assert len(sq) == len(ref)
    assert not math.isnan(sq.quantile(0.25))                                # the NaNs have left the window


class NumpySegmenter:
    """``OnlineSegmenter`` as seg27 wrote it, in numpy: its code verbatim (but this docstring)."""

    NOISE_SAMPLES = 600

    def __init__(self, config: SegmentConfig):
        self.config = config
        self.buf: deque = deque(maxlen=2 * config.window)      # (direction (3,), origin (3,) or None, lines)
        self.medians: deque = deque(maxlen=2 * config.window + 1)    # (origin, direction) medians of the last windows
        self.seconds: deque = deque(maxlen=self.NOISE_SAMPLES)  # median_noise_deg's angle at each window
        self.turns: deque = deque(maxlen=self.NOISE_SAMPLES)    # angle of each sample off its neighbours' mean
        self.sums = LineSums()          # the current fixation's lines before the after-window
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
        d = _unit(np.asarray(direction, float))
        o = None if origin is None else np.asarray(origin, float)
        item = (d, o, (None if o is None else (o[None], d[None])) if lines is None else lines)
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
            self.sums.add(*self.buf[-w - 1][2])           # it has left the after-window
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
            self.turns.append(float(angle_deg(buf[-2][0], buf[-3][0] + buf[-1][0])))
        if len(buf) < w:
            return
        last = list(buf)[-w:]
        origin = None if any(x[1] is None for x in last) else np.median([x[1] for x in last], axis=0)
        self.medians.append((np.full(3, np.nan) if origin is None else origin,
                             _unit(np.median([x[0] for x in last], axis=0))))
        if len(self.medians) == 2 * w + 1:
            (o0, d0), (o1, d1), (o2, d2) = (self.medians[i] for i in (0, w, 2 * w))
            self.seconds.append(float(_second_angles(o0[None], d0[None], o1[None], d1[None], o2[None], d2[None],
                                                     self.config.min_depth_mm)[0]))

    def noise_deg(self) -> tuple[float, float] | None:
        """(per-sample noise, sd of the difference of two window medians), degrees, as measured
        so far (``session_noise_deg``: the second derived from the first until ``2 window``
        measures of it have come); None before ``2 window`` samples."""
        w = self.config.window
        if len(self.turns) < 2 * w:
            return None
        noise = float(np.median(self.turns)) / SECOND_DIFF_MEDIAN
        if len(self.seconds) >= 2 * w:
            return noise, _diff_sd_deg(np.array(self.seconds))
        return noise, float(np.sqrt(2.0) * MEDIAN_SD * noise / np.sqrt(w))

    def threshold_deg(self) -> float:
        """The saccade threshold now, degrees (``SegmentConfig.threshold_deg`` of ``noise_deg``'s
        second figure), twice ``jump_deg`` before ``2 window`` samples."""
        noise = self.noise_deg()
        return 2.0 * self.config.jump_deg if noise is None else self.config.threshold_deg(noise[1])

    def score(self, noise: tuple[float, float] | None) -> float:
        """The window test on the full buffer, degrees (``world_jump_deg`` between the depths the
        fixation's lines fix, ``LineSums.bounds``, at the ``noise_deg`` given; None: from
        ``min_depth_mm`` on)."""
        w = self.config.window
        d = np.array([x[0] for x in self.buf])
        da, db = _unit(np.median(d[:w], axis=0)), _unit(np.median(d[w:], axis=0))
        if any(x[1] is None for x in self.buf):
            return float(angle_deg(da, db))
        o = np.array([x[1] for x in self.buf])
        oa = np.median(o[:w], axis=0)
        near, far = (self.config.min_depth_mm, np.inf) if noise is None else \
            self.sums.bounds(oa, da, line_noise_deg(*noise, w), self.config.min_depth_mm)
        return float(world_jump_deg(oa, da, np.median(o[w:], axis=0), db, near, far)[0])


def _stream(seed, n, rate_hz=200.0):
    """A wearer swaying and walking at 200 Hz, fixating points 0.3-4 m ahead of where the head
    was when each fixation began, for 0.1-2 s each, with saccades between; each eye's line
    (origins 32 mm either side of the head's) with 0.8 deg of noise a sample; gaps (blinks over
    ``max_gap_s``), a few samples far off (outliers), and stretches of each way ``live`` or
    another caller may feed the segmenter (``mode``: 0 both eyes' lines, 1 the left eye's line
    alone (the right's NaN), 2 the right's alone, 3 no lines (the cyclopean ray alone), 4 no
    origin). Returns (t (n,), cyclopean directions (n, 3), origins (n, 3), eye origins (n, 2, 3),
    eye directions (n, 2, 3), mode (n,))."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.where(rng.random(n) < 0.002, rng.uniform(0.3, 1.5, n), 1.0 / rate_hz))
    head = np.column_stack([300 * np.sin(0.4 * t), 40 * np.sin(2.1 * t), 600 * np.sin(0.15 * t + 1)])
    head += rng.normal(0, 0.5, (n, 3))
    fix = np.cumsum(rng.random(n) < 1.0 / (rate_hz * rng.uniform(0.1, 2.0)))
    first = np.searchsorted(fix, np.arange(fix.max() + 1))
    points = rng.normal(0, 700, (fix.max() + 1, 3))
    points[:, 2] = rng.uniform(300, 4000, len(points))
    points += head[first]
    eo = head[:, None] + np.array([[-32.0, 0.0, 0.0], [32.0, 0.0, 0.0]]) + rng.normal(0, 0.2, (n, 2, 3))
    ed = _unit(_unit(points[fix][:, None] - eo) + rng.normal(0, np.deg2rad(0.8), (n, 2, 3)))
    off = rng.random(n) < 0.003
    ed[off] = _unit(rng.normal(size=(off.sum(), 2, 3)))
    mode = np.cumsum(rng.random(n) < 0.02) % 8
    mode = np.where(mode < 4, 0, mode - 3)
    d, o = _unit(ed[:, 0] + ed[:, 1]), 0.5 * (eo[:, 0] + eo[:, 1])
    for m, e in ((1, 0), (2, 1)):
        d[mode == m], o[mode == m] = ed[mode == m, e], eo[mode == m, e]
        eo[mode == m, 1 - e], ed[mode == m, 1 - e] = np.nan, np.nan
    return t, d, o, eo, ed, mode


def _window_ray(seg):
    """The median origin and unit median direction of ``NumpySegmenter`` ``seg``'s before-window
    (None when an origin is unknown)."""
    first = list(seg.buf)[:seg.config.window]
    if any(x[1] is None for x in first):
        return None
    return np.median([x[1] for x in first], axis=0), _unit(np.median([x[0] for x in first], axis=0))


@pytest.mark.parametrize(("seed", "window"), [(0, 8), (1, 8), (2, 3), (3, 2), (4, 1)])
def test_online_segmenter_scores_thresholds_and_decisions_are_the_numpy_ones(seed, window):
    config = SegmentConfig(window=window)
    t, d, o, eo, ed, mode = _stream(seed, 5000 if window == 8 else 2500)
    fast, ref = OnlineSegmenter(config), NumpySegmenter(config)
    ends = scored = in_saccade = bounded = 0
    worst = 0.0
    for k in range(len(t)):
        origin = None if mode[k] == 4 else o[k]
        lines = None if mode[k] >= 3 else (eo[k], ed[k])
        e = fast.update(t[k], d[k], origin, lines)
        assert e == ref.update(t[k], d[k], origin, lines), k
        assert fast.in_saccade == ref.in_saccade and fast.run == ref.run, k
        ends += e
        in_saccade += fast.in_saccade
        if len(ref.buf) == 2 * window:
            noise = ref.noise_deg()
            assert (noise is None) == (fast.noise_deg() is None)
            worst = max(worst, abs(fast.score(None) - ref.score(None)), abs(fast.threshold_deg() - ref.threshold_deg()))
            if noise is not None:
                worst = max(worst, abs(fast.score(noise) - ref.score(noise)),
                            *np.abs(np.subtract(fast.noise_deg(), noise)))
                ray = _window_ray(ref)
                if ray is not None:
                    want = ref.sums.bounds(*ray, line_noise_deg(*noise, window), config.min_depth_mm)
                    got = fast.sums.bounds(vec3(ray[0]), vec3(ray[1]), line_noise_deg(*noise, window),
                                           config.min_depth_mm)
                    assert got == pytest.approx(want, rel=1e-9), k
                    bounded += np.isfinite(want[1]) and want[0] > config.min_depth_mm
            scored += 1
    assert worst <= 1e-9
    assert scored > 0.9 * len(t) and ends >= 10 and in_saccade >= 10     # fixations, saccades and gaps were seen
    assert bounded > (0.05 * len(t) if window > 1 else -1)                # the lines fixed a depth interval
    assert all(np.sum(mode == m) > 0.03 * len(t) for m in range(5))


def test_online_segmenter_takes_lists_and_arrays_alike():
    config = SegmentConfig(window=2)
    a, b = OnlineSegmenter(config), OnlineSegmenter(config)
    rng = np.random.default_rng(5)
    d = _unit(rng.normal([0, 0, 1], 0.1, (40, 3)))
    for k in range(40):
        assert a.update(k / 60, d[k], np.zeros(3)) == b.update(k / 60, d[k].tolist(), [0.0, 0.0, 0.0])
        assert a.in_saccade == b.in_saccade
