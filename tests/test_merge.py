"""Merging the static fixations of one target across revisits (issue 15, ``estimator.merge``):
the test on the pooled lines, the groups it keeps, and ``process`` and the live session giving
the same fixations the same partition into targets."""


import numpy as np
import pytest

from estimator import BinocularSamples, PooledEstimate, estimate, perturb_directions
from estimator.merge import MERGE_LR_THRESHOLD, MERGE_POSE_DEG, STILL_HEAD_MERGE_S, TargetMerger, merge_statistic
from estimator.result import Status, failed
from tests.helpers import same_target
from tests.test_live_parts import _eyes, _pose, _record
from wearable_gaze.pipeline.steps.estimate import DEFAULT_ERROR_MODEL
from wearable_gaze.pipeline.steps.fixations import merge_fixations
from wearable_gaze.pipeline.steps.live_estimation import SIGMA_DEG, GazeEstimation
from wearable_gaze.pipeline.types import Fixation

RATE = 60.0
A = np.array([300.0, 0.0, 2400.0])


def _off(point, deg, dist_mm):
    """A point ``deg`` sideways of ``point``'s direction from the origin, ``dist_mm`` away."""
    u = point / np.linalg.norm(point)
    side = np.cross(u, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    return dist_mm * (np.cos(np.deg2rad(deg)) * u + np.sin(np.deg2rad(deg)) * side)


def _fixation(point, t0, rng, still=False, n=90):
    """``n`` samples at 60 Hz from ``t0`` looking at ``point`` (3,) mm with 0.2 deg of noise, from
    a head swaying 300 mm sideways (or still: depth from vergence alone): world-frame lines."""
    x = np.zeros(n) if still else 150.0 * np.sin(np.linspace(0, 2 * np.pi, n))
    head = np.column_stack([x, np.zeros(n), np.zeros(n)])
    lo, ro = head - [32.0, 0, 0], head + [32.0, 0, 0]
    noise = np.deg2rad(0.2)
    return BinocularSamples.from_arrays(t0 + np.arange(n) / RATE, lo, perturb_directions(point - lo, noise, rng),
                                        ro, perturb_directions(point - ro, noise, rng))


def test_the_statistic_is_small_for_one_point_seen_twice_and_large_for_two_points_two_degrees_apart():
    rng = np.random.default_rng(0)
    a1, a2, b = _fixation(A, 0.0, rng), _fixation(A, 3.0, rng), _fixation(_off(A, 2.0, 2400.0), 6.0, rng)
    same = merge_statistic(([a1], estimate(a1).position_mm), ([a2], estimate(a2).position_mm), SIGMA_DEG)
    other = merge_statistic(([a1], estimate(a1).position_mm), ([b], estimate(b).position_mm), SIGMA_DEG)
    assert 0.0 <= same < MERGE_LR_THRESHOLD < other


def _est(lines):
    """The estimate of ``lines`` as the pipeline makes one (``ml``, the default error model)."""
    return estimate(lines, "ml", error_model=DEFAULT_ERROR_MODEL)


class _Spy:
    """The merger's group estimators (``PooledEstimate`` of ``ml`` with the default error model):
    records the pooled lines each join is estimated from."""

    def __init__(self, fail=False):
        self.calls, self.fail = [], fail

    def __call__(self):
        spy = self

        class Pooled(PooledEstimate):
            def add(self, samples):
                e = super().add(samples)
                spy.calls.append(BinocularSamples.concatenate(self.parts))
                return failed("ml", Status.DEGENERATE, "planted", 1, 2) if spy.fail else e

        return Pooled("ml", SIGMA_DEG, error_model=DEFAULT_ERROR_MODEL)


def test_a_revisit_joins_its_target_which_is_estimated_again_and_a_poorly_fixed_fixation_does_not():
    """A, then B seen from a still head (its depth vague: a metre) 4.5 deg off A and farther,
    then A again: B's estimate and A's agree within their covariances (``same_target``), but B's
    lines do not fit A's point; A's revisit joins group 0, whose estimate is made again from both
    fixations' lines in time order. Ids are the groups' indices and do not change."""
    rng = np.random.default_rng(1)
    lines = [_fixation(A, 0.0, rng), _fixation(_off(A, 4.5, 5000.0), 2.0, rng, still=True), _fixation(A, 4.0, rng)]
    ests = [_est(x) for x in lines]
    assert same_target(ests[0].position_mm, ests[0].covariance_mm2, ests[1].position_mm, ests[1].covariance_mm2)
    spy = _Spy()
    merger = TargetMerger(spy, SIGMA_DEG)
    assert [merger.add(x, e, key=k) for k, (x, e) in enumerate(zip(lines, ests, strict=True))] == [0, 1, 0]
    assert [g.members for g in merger.groups] == [[0, 2], [1]]
    (pooled,) = spy.calls
    assert np.array_equal(pooled.t_s, np.concatenate([lines[0].t_s, lines[2].t_s]))
    assert merger.groups[0].estimate.position_mm == pytest.approx(_est(pooled).position_mm)
    assert merger.groups[1].estimate is ests[1]
    assert np.linalg.norm(merger.groups[0].estimate.position_mm - A) < 30.0


def test_without_head_poses_a_revisit_joins_only_a_target_seen_within_the_still_head_time():
    """A still head's frame is the world only for a while (``STILL_HEAD_MERGE_S``): A, B, then A
    again 1.5 s after A's fixation ended joins A; the same revisit 10 s later starts a target of
    its own; with no bound (head poses) it joins A whenever it comes."""
    rng = np.random.default_rng(3)
    a1, b = _fixation(A, 0.0, rng, still=True), _fixation(_off(A, 8.0, 1500.0), 1.6, rng, still=True)
    soon, late = _fixation(A, 3.0, rng, still=True), _fixation(A, 11.5, rng, still=True)
    for revisit, within_s, want in ((soon, STILL_HEAD_MERGE_S, [0, 1, 0]), (late, STILL_HEAD_MERGE_S, [0, 1, 2]),
                                    (late, np.inf, [0, 1, 0])):
        merger = TargetMerger(_Spy(), SIGMA_DEG, within_s=within_s)
        assert [merger.add(x, _est(x), key=k) for k, x in enumerate((a1, b, revisit))] == want


def test_a_fixation_whose_pooled_estimate_fails_starts_its_own_group_and_an_unusable_one_is_refused():
    rng = np.random.default_rng(2)
    a1, a2 = _fixation(A, 0.0, rng), _fixation(A, 2.0, rng)
    merger = TargetMerger(_Spy(fail=True), SIGMA_DEG)
    assert merger.add(a1, estimate(a1, "ml")) == 0 and merger.add(a2, estimate(a2, "ml")) == 1
    with pytest.raises(ValueError, match="usable estimate"):
        merger.add(a1, failed("ml", Status.DEGENERATE, "none", 0, 0))


def _walk_with_still_fixation(eyes, fixations, rng):
    """Records and exact head poses of a wearer looking at each point for 1.5 s, the head swaying
    300 mm sideways (back where it started at each fixation's end) or still: [(point, still)]."""
    out, t, k = [], 0.0, 0
    for X, still in fixations:
        for _ in range(int(1.5 * RATE)):
            phase = 2 * np.pi * t / 1.5
            T = _pose(0.0, 0.0, 0.0) if still else _pose(0.0, 150.0 * np.sin(phase), 20.0 * np.sin(phase))
            out.append((t, _record(eyes, k, t, T, X, noise=rng.normal(0, 0.004, (2, 2))), T))
            t, k = t + 1 / RATE, k + 1
    return out


def test_live_ids_partition_the_fixations_as_process_merges_the_same_lines():
    """A simulated live session: A, then B 4.5 deg off and 5 m away from a still head, then A.
    The ids live publishes split the fixations as ``process``'s merge of the same fixations'
    lines and estimates does, and as the truth does: {0, 2}, {1}. The old rule (two estimates
    within their joint uncertainty, ``same_target``) put B with A."""
    eyes, rng = _eyes(), np.random.default_rng(0)
    B = _off(A, 4.5, 5000.0)
    est = GazeEstimation(eyes, "voxel")
    fed, add = [], est.targets.merger.add

    def spy(lines, e, key=None):
        fed.append((lines, e))
        return add(lines, e, key)
    est.targets.merger.add = spy
    targets = []
    for t, rec, T in _walk_with_still_fixation(eyes, [(A, False), (B, True), (A, False)], rng):
        done, _ = est.add(t, rec, T)
        targets += [est.finish(done)] if done is not None else []
    targets.append(est.finish(est.end_fixation()))
    assert [tg.fixations for tg in targets] == [(0,), (1,), (2,)] and len(fed) == 3
    live = [tg.index for tg in targets]
    assert live == [0, 1, 0]
    e0, e1 = fed[0][1], fed[1][1]
    assert same_target(e0.position_mm, e0.covariance_mm2, e1.position_mm, e1.covariance_mm2, origin=[0, 0, 0])
    samples = BinocularSamples.concatenate([lines for lines, _ in fed])
    bounds = np.cumsum([0] + [len(lines) for lines, _ in fed])
    fixations = [Fixation(k, np.arange(bounds[k], bounds[k + 1]), e) for k, (_, e) in enumerate(fed)]
    groups = merge_fixations(fixations, samples, "voxel", SIGMA_DEG, DEFAULT_ERROR_MODEL)
    offline = {f: i for i, g in enumerate(groups) for f in g.fixations}
    assert [offline[k] for k in range(3)] == live


def test_a_revisit_whose_lines_the_head_pose_turned_both_alike_still_merges():
    """A head pose 0.8 deg off in pitch over one fixation turns both eyes' lines alike: the
    per-fixation offset shared by the eyes (``MERGE_POSE_DEG``, for tracked poses) explains it;
    without it (0: a device's SLAM poses) the per-eye offsets of 0.1 deg cannot, and the revisit
    is a new target."""
    rng = np.random.default_rng(4)
    a1 = _fixation(A, 0.0, rng, n=120)
    a2 = _fixation(A, 3.0, rng, n=120)
    pitch = np.deg2rad(0.8)
    R = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    a2 = BinocularSamples.from_arrays(a2.t_s, a2.left_origin_mm, a2.left_direction @ R.T, a2.right_origin_mm,
                                      a2.right_direction @ R.T)
    args = (([a1], estimate(a1).position_mm), ([a2], estimate(a2).position_mm), SIGMA_DEG)
    assert merge_statistic(*args, pose_deg=MERGE_POSE_DEG) < MERGE_LR_THRESHOLD
    assert merge_statistic(*args, pose_deg=0.0) > MERGE_LR_THRESHOLD
