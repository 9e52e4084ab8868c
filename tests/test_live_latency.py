"""What the live loop's per-sample path was made cheaper by (issue 29; docs/live.md, Latency): the
same results, with the work moved or cached. No timing is asserted here (the figures are
benchmarks/bench_live.py's)."""

import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from test_live_parts import _eye_items, _FakeEstimation, _loop, _pose

from estimator._checks import check_transform
from estimator.result import covariance_ellipsoid
from tracking.markermap import MarkerMap
from tracking.timeline import interpolate_poses, pose_between
from wearable_gaze.formats.devices.pupil_net import RaySample
from wearable_gaze.formats.eye_rays import ray_csv_line, ray_csv_lines, read_eye_rays
from wearable_gaze.formats.poses import pose_csv_line, pose_csv_lines, read_poses_csv
from wearable_gaze.formats.session import load_session
from wearable_gaze.live import loop as live_loop
from wearable_gaze.live.input_thread import InputThread
from wearable_gaze.live.loop import LiveSession
from wearable_gaze.live.record import DEVICE_FILES, Recorder
from wearable_gaze.live.sched import GAZE_SLICE_S, set_thread_slice, thread_slice_s


def _T(yaw_deg, x_mm):
    return _pose(yaw_deg, x_mm, -3.0)


def test_pose_rows_made_in_one_batch_are_the_rows_made_one_by_one():
    t = [0.5, 0.505, 0.51, 0.515]
    T = [_T(10.0, 1.0), None, np.full((4, 4), np.nan), _T(-33.3, 250.125)]
    lines = pose_csv_lines(t, [0, 1, 2, 3], T)
    assert lines == "".join(pose_csv_line(tk, k, Tk) for k, (tk, Tk) in enumerate(zip(t, T, strict=True)))
    rows = lines.splitlines()
    assert len(rows) == 4 and rows[1] == rows[1].split(",")[0] + ",1" + "," * 7
    assert pose_csv_lines([], [], []) == ""


def test_ray_rows_made_in_one_batch_are_the_rows_made_one_by_one():
    rng = np.random.default_rng(0)
    n = 5
    t = 0.25 + np.arange(n) / 200.0
    left, right = rng.normal(size=(n, 6)), rng.normal(size=(n, 6))
    lv, rv = [True, False, True, True, False], [True, True, False, True, False]
    lines = ray_csv_lines(t, left, lv, right, rv)
    assert lines == "".join(ray_csv_line(t[k], left[k], lv[k], right[k], rv[k]) for k in range(n))
    assert len(lines.splitlines()) == n and ray_csv_lines([], [], [], [], []) == ""


def test_the_recorder_writes_a_devices_rays_at_its_flush_in_order(tmp_path):
    (tmp_path / "c").write_text("{}")
    mm = MarkerMap("DICT_4X4_50", 80.0, {1: _pose()}, {})
    rec = Recorder(tmp_path / "rec", (64, 48), 30.0, tmp_path / "c", None, mm, flush_s=1.0, device="pupil-core")
    rng = np.random.default_rng(1)
    t = 0.2 + np.arange(6) / 200.0
    sent = []
    for k, tk in enumerate(t):
        o, d = rng.normal(size=(2, 3)) * [10.0, 1.0, 1.0], np.array([0.1, -0.2, 1.0])
        left, right = (*o[0], *(d / np.linalg.norm(d))), (*o[1], *(d / np.linalg.norm(d)))
        sent.append(RaySample(k, tk, left, right, k != 2, k != 4, 1.0))
        rec.eye_sample(tk, sent[-1])
        if k == 2:
            rec.flush()
    rec.close(complete=True)
    back = read_eye_rays(tmp_path / "rec" / DEVICE_FILES["eye_rays"])
    assert back.t_s == pytest.approx(t, abs=1e-6) and load_session(tmp_path / "rec").manifest["n_eye_samples"] == 6
    assert back.left_valid.tolist() == [k != 2 for k in range(6)]
    assert back.right_valid.tolist() == [k != 4 for k in range(6)]
    for k, r in enumerate(sent):
        if r.left_valid:
            assert np.allclose(back.left_origin_mm[k], r.left[:3], atol=1e-4)
            assert np.allclose(back.left_direction[k], r.left[3:], atol=1e-7)


def test_the_recorder_writes_each_samples_pose_at_its_flush_in_order(tmp_path):
    (tmp_path / "c").write_text("{}")
    mm = MarkerMap("DICT_4X4_50", 80.0, {1: _pose()}, {})
    rec = Recorder(tmp_path / "rec", (64, 48), 30.0, tmp_path / "c", None, mm, flush_s=1.0, device="pupil-core")
    t = 0.2 + np.arange(7) / 200.0
    T = [_T(k, 10.0 * k) if k != 3 else None for k in range(7)]
    for tk, Tk in zip(t[:4], T[:4], strict=True):
        rec.sample_pose(tk, Tk)
    assert (tmp_path / "rec" / DEVICE_FILES["live_poses"]).read_text().count("\n") <= 1     # no row before a flush
    rec.flush()
    for tk, Tk in zip(t[4:], T[4:], strict=True):
        rec.sample_pose(tk, Tk)
    rec.close(complete=True)
    t_back, frame, T_back, _ = read_poses_csv(tmp_path / "rec" / DEVICE_FILES["live_poses"])
    assert t_back == pytest.approx(t, abs=1e-6) and frame.tolist() == list(range(7))
    assert np.all(np.isnan(T_back[3]))
    for k in (0, 1, 2, 4, 5, 6):
        assert np.allclose(T_back[k], T[k], atol=1e-6)


def test_the_ellipsoid_takes_the_chi_square_quantile_of_its_level():
    C = np.diag([4.0, 9.0, 25.0])
    for p in (0.95, 0.5, 0.95, 0.99):
        r = covariance_ellipsoid(np.zeros(3), C, p).radii_mm
        assert np.allclose(r, np.sqrt(np.array([4.0, 9.0, 25.0]) * chi2.ppf(p, 3)))


def test_a_transform_is_checked_as_before():
    T = _T(20.0, 5.0)
    assert check_transform(T) is not None
    near = T.copy()
    near[0, 0] += 5e-7                                  # within np.allclose's tolerance: accepted
    check_transform(near)
    for bad in (T @ np.diag([1, 1, -1, 1.0]), T + np.diag([1e-4, 0, 0, 0]), np.where(np.eye(4, dtype=bool), np.nan, T)):
        with pytest.raises(ValueError, match="proper rotation"):
            check_transform(bad)
    last = T.copy()
    last[3, 0] = 1e-3
    with pytest.raises(ValueError, match="last row"):
        check_transform(last)


def test_the_session_runs_with_a_short_thread_switch_interval_and_restores_it():
    seen = []

    class _Watching(_FakeEstimation):
        def add(self, t_s, rec, T):
            seen.append(sys.getswitchinterval())
            return super().add(t_s, rec, T)

    before = sys.getswitchinterval()
    session, pub, _ = _loop(_eye_items([0.52, 0.55]), [(0.5, _pose()), (0.6, _pose())], _Watching(end_at=None))
    assert isinstance(session, LiveSession)
    session.run(duration_s=2.0)
    assert seen and all(s == pytest.approx(live_loop.SWITCH_INTERVAL_S) for s in seen)
    assert live_loop.SWITCH_INTERVAL_S < before and sys.getswitchinterval() == pytest.approx(before)


def test_the_gaze_paths_threads_ask_for_short_time_slices_and_the_caller_gets_its_own_back():
    if thread_slice_s() is None or not set_thread_slice(thread_slice_s()):
        pytest.skip("no sched_setattr here (not Linux, or refused)")
    seen = {}

    class _Reader(InputThread):
        def _run(self):
            seen["reader"] = thread_slice_s()

    class _Watching(_FakeEstimation):
        def add(self, t_s, rec, T):
            seen["loop"] = thread_slice_s()
            return super().add(t_s, rec, T)

    r = _Reader("reader")
    r.start()
    r.join()
    before = thread_slice_s()
    session, _, _ = _loop(_eye_items([0.52]), [(0.5, _pose()), (0.6, _pose())], _Watching(end_at=None))
    session.run(duration_s=1.0)
    assert seen["reader"] == pytest.approx(GAZE_SLICE_S) and seen["loop"] == pytest.approx(GAZE_SLICE_S)
    assert GAZE_SLICE_S < before and thread_slice_s() == pytest.approx(before)


def test_the_pose_between_two_frames_is_interpolate_poses_answer():
    rng = np.random.default_rng(4)
    for _ in range(20):
        Ta, Tb = np.eye(4), np.eye(4)                   # any two rotations 0-30 deg apart, any translations
        Ta[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        Tb[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * 0.25).as_matrix() @ Ta[:3, :3]
        Ta[:3, 3], Tb[:3, 3] = rng.uniform(-300, 300, 3), rng.uniform(-300, 300, 3)
        ta, tb = 1.0, 1.0 + rng.uniform(0.01, 0.2)
        for t in (ta, ta + 0.3 * (tb - ta), tb - 1e-6):
            want, ok = interpolate_poses([ta, tb], np.stack([Ta, Tb]), [t], max_gap_s=0.2)
            assert ok[0] and np.allclose(pose_between(ta, Ta, tb, Tb, t), want[0], atol=1e-9)
    with pytest.raises(ValueError, match="between"):
        pose_between(1.0, Ta, 1.1, Tb, 1.2)
