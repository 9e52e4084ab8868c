"""``pipeline.steps.live_replay``: ``process``'s re-run of a live ``--device`` session's estimation (issue
29). The end-to-end check (a session served by the Pupil Core emulator, recorded, processed) is
tests/test_live_pupil_core.py's; here the replay is fed a stream directly."""

import numpy as np
import pytest
from test_live_parts import _pose

from estimator import BinocularSamples, Status
from wearable_gaze.errors import UserError
from wearable_gaze.pipeline.steps.live_estimation import FinishedFixation, GazeEstimation, RayEyes
from wearable_gaze.pipeline.steps.live_replay import _result, replay
from wearable_gaze.pipeline.types import Target


def _stream(rng, fixations, rate=200.0):
    """Head-frame rays (``BinocularSamples``, frame 'head') of eyes 64 mm apart looking at each
    world point for its duration, and the head pose (4, 4) of each sample: a head swaying 40 mm
    sideways and turning a few degrees."""
    t, rows, poses = [], [], []
    k = 0
    for point, dur in fixations:
        for _ in range(int(dur * rate)):
            tk = k / rate
            T = _pose(4.0 * np.sin(tk), 40.0 * np.sin(0.7 * tk), 5.0 * np.cos(tk))
            row = []
            for x in (-32.0, 32.0):
                o = np.array([x, 30.0, -20.0])
                target_cam = np.linalg.inv(T) @ np.append(point, 1.0)
                d = target_cam[:3] - o
                d = d / np.linalg.norm(d) + rng.normal(0, np.deg2rad(0.5), 3)
                row.append((o, d / np.linalg.norm(d)))
            t.append(tk)
            rows.append(row)
            poses.append(T)
            k += 1
    rays = BinocularSamples.from_arrays(t, [r[0][0] for r in rows], [r[0][1] for r in rows],
                                        [r[1][0] for r in rows], [r[1][1] for r in rows], frame="head")
    return rays, np.array(poses)


def test_the_replay_gives_the_targets_the_live_estimation_gives_on_the_same_samples():
    A, B = np.array([100.0, -50.0, 1500.0]), np.array([-500.0, 150.0, 1200.0])
    rays, T = _stream(np.random.default_rng(3), [(A, 1.5), (B, 1.5), (A, 1.5)])
    T[100:140] = np.nan                                 # samples the session shed or had no pose for
    keep = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    live = GazeEstimation([RayEyes(), RayEyes()], "voxel")   # what the session ran, sample by sample
    done = []
    for k in np.flatnonzero(keep):
        rec = _Rec(np.r_[rays.left_origin_mm[k], rays.left_direction[k]],
                   np.r_[rays.right_origin_mm[k], rays.right_direction[k]])
        ended, _ = live.add(float(rays.t_s[k]), rec, T[k])
        done += [ended] if ended is not None else []
    done += [x] if (x := live.end_fixation()) is not None else []
    published = [tg for tg in (live.finish(d) for d in done) if tg is not None]
    res = replay(rays, rays.t_s, T)
    last = {tg.index: tg for tg in published}
    assert [tg.index for tg in res.targets] == sorted(last) == [0, 1]   # A, B, A again: two ids
    for tg in res.targets:
        assert np.array_equal(tg.position_mm, last[tg.index].position_mm) and tg.status == last[tg.index].status
    assert res.targets[0].fixations == (0, 2) and res.targets[1].fixations == (1,)
    assert len(res.samples) == keep.sum() and set(np.unique(res.labels)) == {-1, 0, 1, 2}
    assert np.all(res.target_labels[res.labels == 2] == 0)
    assert len(res.running["t"]) > 0.8 * keep.sum()


class _Rec:
    def __init__(self, left, right):
        self.left, self.right, self.left_valid, self.right_valid = left, right, True, True


def test_a_pose_at_a_time_with_no_eye_sample_is_refused():
    rays, T = _stream(np.random.default_rng(0), [(np.array([0.0, 0.0, 1000.0]), 0.2)])
    with pytest.raises(UserError, match="no eye sample at that time"):
        replay(rays, rays.t_s + 0.001, T)


def test_a_fixation_left_with_no_line_is_no_fixation_and_its_target_is_kept():
    est = GazeEstimation([RayEyes(), RayEyes()]).estimator.estimate()      # no usable estimate
    assert est.status is not Status.OK
    empty = FinishedFixation(0, (), est, 0.0, 0.5, 3)

    def target(i, fixation):
        return Target(i, np.array([1.0, 2.0, 3.0]), None, np.full(3, np.nan), "ok", 3, 0.0, 0.5, (fixation,),
                      "voxel", float("nan"))

    samples = BinocularSamples.from_arrays([1.0, 1.1], np.zeros((2, 3)), [[0, 0, 1.0]] * 2, np.zeros((2, 3)),
                                           [[0, 0, 1.0]] * 2)
    lined = FinishedFixation(1, tuple(samples.sample(i) for i in range(2)), est, 1.0, 1.1, 2)
    res = _result(samples, [(empty, target(0, 0)), (lined, target(1, 1))], [])
    assert [f.index for f in res.fixations] == [0] and res.labels.tolist() == [0, 0]
    assert [tg.index for tg in res.targets] == [0, 1] and res.targets[0].fixations == ()
    assert res.targets[1].fixations == (0,) and res.target_labels.tolist() == [1, 1]
