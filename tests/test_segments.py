"""Fixation segmentation, offline (``segment_fixations``) and online (``OnlineSegmenter``), on a
walking head looking at near and far targets: a near target's direction drifts by several
degrees while it is fixated, which is not a saccade."""

import numpy as np
import pytest

from estimator.likelihood import perturb_directions
from estimator.lines import BinocularSamples
from estimator.segments import OnlineSegmenter, SegmentConfig, cyclopean_directions, cyclopean_rays, segment_fixations

TARGETS = np.array([[0.0, 0.0, 650.0], [400.0, -100.0, 1500.0], [-300.0, 200.0, 3000.0], [100.0, 50.0, 800.0]])
FIX_S = 2.0          # each target fixated this long, saccades between
BLINK = (6.7, 7.35)  # both eyes closed for 0.65 s while the last target is looked at: two fixations


def _session(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(int(len(TARGETS) * FIX_S * 60)) / 60.0
    truth = np.minimum((t // FIX_S).astype(int), len(TARGETS) - 1)
    heads = np.column_stack([160 * np.sin(0.9 * t), 60 * np.sin(1.7 * t + 1), 120 * np.sin(0.6 * t)])
    half = np.array([32.5, 0.0, 0.0])
    X = TARGETS[truth]
    ld = perturb_directions(X - (heads - half), np.deg2rad(1.0), rng)
    rd = perturb_directions(X - (heads + half), np.deg2rad(1.0), rng)
    valid = ~((t >= BLINK[0]) & (t < BLINK[1]))
    s = BinocularSamples.from_arrays(t, heads - half, ld, heads + half, rd, valid, valid)
    truth = np.where(valid, truth, -1)
    truth[truth == 3] = np.where(t[truth == 3] < BLINK[0], 3, 4)      # the blink splits the last fixation
    return s, truth


def _online_labels(s):
    seg = OnlineSegmenter()
    o, d = cyclopean_rays(s)
    labels, k = np.full(len(s), -1), 0
    for i in range(len(s)):
        if not (s.left_valid[i] and s.right_valid[i]):
            continue
        if seg.update(s.t_s[i], d[i], o[i]):                # as live.estimation feeds it: with the eyes' midpoint
            k += 1
        if not seg.in_saccade:
            labels[i] = k
    # fixations shorter than the minimum are dropped, the rest renumbered in time order
    keep = [lab for lab in np.unique(labels[labels >= 0])
            if np.ptp(s.t_s[labels == lab]) >= SegmentConfig().min_fixation_s]
    out = np.full(len(s), -1)
    for j, lab in enumerate(keep):
        out[labels == lab] = j
    return out


def _check(labels, truth):
    """One found fixation per true one, each made of its samples, covering most of them."""
    w = SegmentConfig().window
    assert labels.max() + 1 == truth.max() + 1
    for j in range(truth.max() + 1):
        mine = labels == j
        assert np.sum(truth[mine] != j) <= w // 2                # at most the saccade-onset samples
        assert mine.sum() >= (truth == j).sum() - 2.5 * w        # less the saccades as the windows see them


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_offline_and_online_segmentation_find_the_fixations_a_walking_head_makes(seed):
    s, truth = _session(seed)
    # the near target drifts by far more than the jump threshold while it is fixated
    d = cyclopean_directions(s)[truth == 0]
    a, b = np.median(d[:10], 0), np.median(d[-10:], 0)
    drift = np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))
    assert drift > 2 * SegmentConfig().jump_deg
    _check(segment_fixations(s), truth)
    _check(_online_labels(s), truth)


def test_online_segmenter_ends_a_fixation_once_per_saccade_and_at_a_gap():
    seg = OnlineSegmenter(SegmentConfig(window=4, jump_deg=3.0, max_gap_s=0.5))
    a, b = np.array([0.0, 0.0, 1.0]), np.array([np.sin(0.2), 0.0, np.cos(0.2)])     # 11.5 deg apart
    ends, sacc = [], []
    for i, d in enumerate([a] * 10 + [b] * 12):
        ends.append(seg.update(i / 60, d))
        sacc.append(seg.in_saccade)
    # the jump is seen once half the after-window has moved (median of 4: the mean of the middle two)
    assert sum(ends) == 1 and ends.index(True) == 11
    assert all(sacc[11:16]) and not any(sacc[16:])              # until the before-window's median has moved
    assert seg.update(22 / 60 + 0.6, b) and not seg.in_saccade   # a gap: the fixation ends, the next starts


def test_online_segmenter_takes_the_heads_walk_out_and_still_sees_a_saccade():
    """A head walking sideways at 300 mm/s past a target 600 mm away turns its direction by
    3.8 deg between the windows' middles (0.13 s): on directions alone (no origin, the eye-in-
    world rule) that is a saccade; with the eyes' origins one still point explains both windows
    (the test needs no depth), and a 4 deg saccade up to a point at the same depth is still
    seen, once."""
    t = np.arange(120) / 60.0
    origin = np.column_stack([300.0 * t, np.zeros_like(t), np.zeros_like(t)])
    target = np.where((t < 1.0)[:, None], [[60.0, 0.0, 600.0]], [[60.0, -600 * np.tan(np.deg2rad(4.0)), 600.0]])
    d = target - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)

    def ends(with_origin, upto):
        seg = OnlineSegmenter()
        return [i for i in range(upto) if seg.update(t[i], d[i], origin[i] if with_origin else None)]

    assert ends(False, 60)                                   # directions alone: the walk is a false saccade
    assert ends(True, 60) == []
    assert len(ends(True, 120)) == 1
