"""What held the live loop for 20-130 ms now and then (issue 29; docs/live.md, "Stalls"): the
target worker's motion and merge tests in the session's interpreter, the garbage collector's
full collections, the video encoder's bursts and the checks of every device ray. Each change is
tested for giving the same results; no timing is asserted here (the figures are
benchmarks/bench_live.py's)."""

import gc
import os
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_live_parts import _eye_items, _FakeEstimation, _loop, _pose
from test_live_replay import _Rec, _stream

from estimator import ViewLines, view_lines_to_world
from tracking.markermap import MarkerMap
from wearable_gaze.formats.devices.pupil_net import RaySample
from wearable_gaze.live.record import VIDEO_NICE, Recorder
from wearable_gaze.live.target_process import RemoteTargets
from wearable_gaze.pipeline.steps.live_estimation import GazeEstimation, RayEyes, thin_fixation, world_sample


def _finished_fixations():
    """The finished fixations of a stream looking at A, B, then A again (two target ids)."""
    A, B = np.array([100.0, -50.0, 1500.0]), np.array([-500.0, 150.0, 1200.0])
    rays, T = _stream(np.random.default_rng(3), [(A, 1.5), (B, 1.5), (A, 1.5)])
    live = GazeEstimation([RayEyes(), RayEyes()], "voxel")
    done = []
    for k in range(len(rays)):
        rec = _Rec(np.r_[rays.left_origin_mm[k], rays.left_direction[k]],
                   np.r_[rays.right_origin_mm[k], rays.right_direction[k]])
        ended, _ = live.add(float(rays.t_s[k]), rec, T[k])
        done += [ended] if ended is not None else []
    return done + [live.end_fixation()]


def test_the_target_process_makes_the_targets_the_worker_thread_makes():
    done = _finished_fixations()
    here = GazeEstimation([RayEyes(), RayEyes()], "voxel")
    want = [here.finish(d) for d in done]
    remote = RemoteTargets("voxel")
    try:
        remote.ready()
        got = [remote.finish(d) for d in done]
        assert remote.n_ids == len(here.targets) == 2
    finally:
        remote.close()
    assert not remote.proc.is_alive()
    assert [t.index for t in got] == [t.index for t in want] == [0, 1, 0]
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g.position_mm, w.position_mm) and np.array_equal(g.covariance_mm2, w.covariance_mm2)
        assert g.status == w.status and g.fixations == w.fixations and g.t_end == w.t_end


def test_a_fixation_is_sent_to_the_target_process_thinned_as_finish_thins_it():
    done = _finished_fixations()[0]
    thin = thin_fixation(done)
    assert len(done.lines) > 240 and len(thin.samples) == len(done.lines[::-(-len(done.lines) // 240)]) <= 240
    assert thin.t_last_line == done.lines[-1].t_s and thin.samples.t_s[0] == done.lines[0].t_s


def _checked(rec, T):
    """``world_sample``'s lines through ``RayEyes.lines`` and ``view_lines_to_world`` (the checks)."""
    eyes = [RayEyes(), RayEyes()]
    valid = [e for e, ok in enumerate((rec.left_valid, rec.right_valid)) if ok]
    cam = [eyes[e].lines(np.array([(rec.left, rec.right)[e]], float)) for e in valid]
    world = view_lines_to_world(ViewLines(np.concatenate([c.origins_mm for c in cam]),
                                          np.concatenate([c.directions for c in cam]), "cam"), T_world_from_cam=T)
    parts = [None] * 4
    for k, e in enumerate(valid):
        parts[2 * e:2 * e + 2] = world.origins_mm[k], world.directions[k]
    return parts


def test_a_devices_rays_become_the_world_lines_of_the_checked_path_bit_for_bit():
    rng = np.random.default_rng(0)

    def ray():
        d = rng.normal(0, 1, 3) + [0, 0, 3]
        return tuple(np.r_[rng.normal(0, 30, 3), d / np.linalg.norm(d) * rng.uniform(0.9, 1.1)])

    for k in range(300):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rotation.random(random_state=k).as_matrix(), rng.normal(0, 500, 3)
        lv, rv = [(True, True), (True, False), (False, True)][k % 3]
        rec = RaySample(k, 0.0, ray() if lv else (np.nan,) * 6, ray() if rv else (np.nan,) * 6, lv, rv, 1.0)
        got, want = world_sample([RayEyes(), RayEyes()], 0.5, rec, T)[1:], _checked(rec, T)
        assert all((g is None and w is None) or np.array_equal(g, w) for g, w in zip(got, want, strict=True))
    bad = RaySample(0, 0.0, (1.0, 2.0, 3.0, 0.0, 0.0, 0.0), (np.nan,) * 6, True, False, 1.0)
    with pytest.raises(ValueError, match="direction must be finite and non-zero"):
        world_sample([RayEyes(), RayEyes()], 0.5, bad, np.eye(4))       # said as before
    with pytest.raises(ValueError, match="proper rotation"):
        world_sample([RayEyes(), RayEyes()], 0.5, rec, np.diag([1.0, 1.0, -1.0, 1.0]))


def test_the_session_freezes_the_objects_it_started_with_and_thaws_them_at_its_end():
    seen = []

    class _Watching(_FakeEstimation):
        def add(self, t_s, rec, T):
            seen.append(gc.get_freeze_count())
            return super().add(t_s, rec, T)

    before = gc.get_freeze_count()
    session, _, _ = _loop(_eye_items([0.52, 0.55]), [(0.5, _pose()), (0.6, _pose())], _Watching(end_at=None))
    session.run(duration_s=1.0)
    assert seen and min(seen) > before + 1000 and gc.get_freeze_count() == before


def test_the_video_encoder_runs_nicer_than_the_session(tmp_path):
    if not hasattr(os, "getpriority"):
        pytest.skip("no thread priorities here")
    (tmp_path / "c").write_text("{}")
    rec = Recorder(tmp_path / "rec", (64, 48), 30.0, tmp_path / "c", None,
                   MarkerMap("DICT_4X4_50", 80.0, {1: _pose()}, {}), device="pupil-core")
    try:
        th = next(t for t in threading.enumerate() if t.name == "recorder-video")
        end = time.monotonic() + 5.0
        while os.getpriority(os.PRIO_PROCESS, th.native_id) == os.getpriority(os.PRIO_PROCESS, 0) and \
                time.monotonic() < end:
            time.sleep(0.01)
        assert os.getpriority(os.PRIO_PROCESS, th.native_id) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + VIDEO_NICE)
    finally:
        rec.close()
