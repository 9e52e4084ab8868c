"""The live session's parts, each alone with fake inputs (issue 13): head tracking (pose hold,
SLERP, waiting for a frame), estimation (world view lines, online fixations, target ids), the
message format, the recorder, and the loop composing fakes of them."""

import json
import queue
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.eyes import EyeCalibration, RawMap, plane_points
from estimator import BinocularSamples, estimate, perturb_directions
from estimator.frames import invert
from tracking.markermap import MarkerMap
from wearable_gaze.errors import UserError
from wearable_gaze.formats.eye_samples import read_eye_csv
from wearable_gaze.formats.jsonio import validate
from wearable_gaze.formats.markermap import load_marker_map
from wearable_gaze.formats.serial_protocol import EyeRecord
from wearable_gaze.formats.session import load_session
from wearable_gaze.live.camera_in import CameraStats
from wearable_gaze.live.clock import SessionClock
from wearable_gaze.live.head import HeadTracker, TrackingThread
from wearable_gaze.live.loop import LiveSession
from wearable_gaze.live.messages import estimate_message, target_message
from wearable_gaze.live.publish import Publisher
from wearable_gaze.live.record import FILES, Recorder
from wearable_gaze.live.serial_in import SerialStats
from wearable_gaze.pipeline.steps.live_estimation import GazeEstimation, LiveEstimate, TargetIds, world_sample
from wearable_gaze.pipeline.types import Target


def _pose(yaw_deg=0.0, x_mm=0.0, y_mm=0.0):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = [x_mm, y_mm, 0.0]
    return T


class _Pose:
    """What ``MarkerPoseEstimator.estimate`` returns, as far as the tracker reads it."""

    def __init__(self, T, markers):
        self.T_world_from_cam, self.markers, self.ok = T, markers, T is not None


# --- head tracking ---------------------------------------------------------------------------

def _tracker(poses, hold_s=0.05):
    """A tracker whose 'frames' are the poses themselves (fake detection and pose)."""
    return HeadTracker(detect=lambda gray: gray, estimate=lambda T: _Pose(T, [1, 2] if T is not None else []),
                       hold_s=hold_s), poses


def test_head_pose_between_frames_is_slerped_and_continued_after_the_last_for_hold_s_only():
    head, _ = _tracker(None)
    assert head.pose_at(0.0) is None and head.last_t is None
    assert head.track(0.0, _pose(0.0, 0.0)) and head.track(0.1, _pose(10.0, 100.0))
    assert head.markers_in_view == 2
    T = head.pose_at(0.025)
    assert Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)[1] == pytest.approx(2.5)
    assert T[:3, 3] == pytest.approx([25.0, 0.0, 0.0])
    T = head.pose_at(0.14)                                              # 40 ms after the last frame:
    assert Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)[1] == pytest.approx(14.0)  # the turn
    assert T[:3, 3] == pytest.approx([140.0, 0.0, 0.0])                # and the walk carried on
    assert head.pose_at(0.16) is None                                   # 60 ms: too old
    assert head.pose_at(-0.01) is None                                  # before the first frame
    assert not head.track(0.2, None) and head.markers_in_view == 0     # no pose: nothing kept
    assert head.last_t == 0.1


def test_head_pose_is_not_interpolated_across_a_gap():
    head, _ = _tracker(None)
    head.track(0.0, _pose())
    head.track(0.3, _pose(20.0))
    assert head.pose_at(0.15) is None
    assert np.array_equal(head.pose_at(0.33), _pose(20.0))             # nor continued from across it: held
    head.track(0.35, _pose(30.0))
    assert head.pose_at(0.32) is not None


def test_a_sample_newer_than_the_held_pose_waits_for_the_next_frame_but_not_forever():
    head, _ = _tracker(None)
    assert not head.must_wait(5.0, 0.0)                  # no frame yet: nothing to wait for
    head.track(1.0, _pose())
    assert not head.must_wait(1.04, 0.0)                 # the held pose serves it
    assert head.must_wait(1.06, 0.1)
    assert not head.must_wait(1.06, 0.25)                # waited 0.2 s: go on (it will have no pose)


# --- the session clock -----------------------------------------------------------------------

def test_the_session_clock_takes_the_fastest_transport_path_and_never_goes_back():
    clock = SessionClock(lambda: 40.0)                       # the first frame came at monotonic 40 s
    assert clock.map(50.030, 10.0) == pytest.approx(10.030)  # the first record: its own offset (30 ms)
    assert clock.map(50.560, 10.5) == pytest.approx(10.530)  # a slower path: the offset is kept
    assert clock.map(50.629, 10.6) == pytest.approx(10.630)  # 1 ms faster: within 2 ms, kept
    assert clock.map(50.715, 10.7) == pytest.approx(10.715)  # 15 ms faster: the new offset
    assert clock.map(50.7061, 10.701) == pytest.approx(10.715 + 1e-4)   # faster still, but never back in time
    assert SessionClock(lambda: None).map(7.0, 2.0) == pytest.approx(0.0)   # no frame yet: arrival is the origin


# --- estimation ------------------------------------------------------------------------------

PLANE_MM = 1000.0


def _eyes():
    coef = np.zeros((6, 2))
    coef[1, 0] = coef[2, 1] = 1.0                        # raw = q: normalised image coordinates
    raw_map = RawMap("quadratic", np.zeros(2), 1.0, coef)
    return [EyeCalibration(name, np.array([x, 5.0, -20.0]), PLANE_MM, raw_map) for name, x in
            (("left", -32.0), ("right", 32.0))]


def _record(eyes, counter, t, T_world_from_cam, target_world, valid=(True, True), noise=None):
    """The raw readings of two eyes looking at ``target_world`` from head pose ``T``."""
    X_cam = invert(T_world_from_cam) @ np.append(target_world, 1.0)
    raw = [plane_points(X_cam[None, :3], e.center_mm, e.plane_mm)[0] for e in eyes]
    if noise is not None:
        raw = [r + n for r, n in zip(raw, noise, strict=True)]
    return EyeRecord(counter, t, tuple(raw[0]), tuple(raw[1]), valid[0], valid[1])


def test_world_sample_lines_pass_through_the_gazed_point():
    eyes = _eyes()
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = _pose(rng.uniform(-40, 40), *rng.normal(0, 300, 2))
        T[:3, :3] = T[:3, :3] @ Rotation.from_euler("x", rng.uniform(-20, 20), degrees=True).as_matrix()
        X = rng.normal(0, 500, 3) + T[:3, 3] + T[:3, :3] @ [0, 0, 1500.0]
        s = world_sample(eyes, 1.5, _record(eyes, 0, 1.5, T, X), T)
        for o, d, e in ((s.left_origin_mm, s.left_direction, eyes[0]), (s.right_origin_mm, s.right_direction, eyes[1])):
            assert o == pytest.approx(T[:3, :3] @ e.center_mm + T[:3, 3])          # the eye, moved by the head
            to_x = (X - o) / np.linalg.norm(X - o)
            assert np.linalg.norm(np.cross(d, to_x)) < 1e-9 and d @ to_x > 0     # and looking at X
    one = world_sample(eyes, 0.0, _record(eyes, 0, 0.0, T, X, valid=(False, True)), T)
    assert one.left_origin_mm is None and one.left_direction is None and one.right_direction is not None


def _walk(eyes, fixations, rate=60.0, rng=None):
    """Records and head poses of a wearer swaying sideways while fixating each point in turn for
    its duration: [(point (3,), seconds)]."""
    out, t, k = [], 0.0, 0
    for X, dur in fixations:
        for _ in range(int(dur * rate)):
            T = _pose(3.0 * np.sin(1.3 * t), 150.0 * np.sin(0.8 * t), 20.0 * np.sin(2.1 * t))
            noise = None if rng is None else rng.normal(0, 0.004, (2, 2))        # ~0.2 deg
            out.append((t, _record(eyes, k, t, T, X, noise=noise), T))
            t, k = t + 1 / rate, k + 1
    return out


def test_estimation_finds_each_fixation_and_gives_a_target_seen_again_its_id():
    eyes = _eyes()
    A, B = np.array([100.0, -50.0, 1500.0]), np.array([-500.0, 150.0, 1200.0])
    est = GazeEstimation(eyes, "voxel")
    targets, running = [], []
    for t, rec, T in _walk(eyes, [(A, 1.5), (B, 1.5), (A, 1.5)], rng=np.random.default_rng(0)):
        ended, e = est.add(t, rec, T)
        targets += [est.finish(ended)] if ended is not None else []
        running += [e] if e is not None else []
    targets.append(est.finish(est.end_fixation()))
    assert [x.index for x in targets] == [0, 1, 0]                      # A, B, A again: A's id
    assert [x.fixations for x in targets] == [(0,), (1,), (2,)]
    for x, truth in zip(targets, (A, B, A), strict=True):
        assert np.linalg.norm(x.position_mm - truth) < 30.0
        assert x.t_end - x.t_start > 1.0 and x.n_samples > 60 and x.method == "voxel"
    assert len(est.targets) == 2
    fixation_0 = [r for r in running if r.fixation == 0]
    assert [r.n_samples for r in fixation_0] == list(range(fixation_0[0].n_samples, fixation_0[-1].n_samples + 1))
    assert {r.fixation for r in running} == {0, 1, 2}


def test_a_monocular_sample_neither_ends_a_fixation_nor_is_lost():
    eyes = _eyes()
    A = np.array([0.0, 0.0, 1000.0])
    est = GazeEstimation(eyes, "voxel")
    stream = _walk(eyes, [(A, 1.0)])
    for i, (t, rec, T) in enumerate(stream):
        if i % 3 == 0:
            rec = rec._replace(right_valid=False)
        ended, _ = est.add(t, rec, T)
        assert ended is None
    target = est.finish(est.end_fixation())
    assert target is not None and target.n_samples == len(stream)


def test_a_short_fixation_gives_no_target():
    eyes = _eyes()
    est = GazeEstimation(eyes, "voxel")
    for t, rec, T in _walk(eyes, [(np.array([0.0, 0.0, 1000.0]), 0.2)]):
        est.add(t, rec, T)
    assert est.end_fixation() is None and est.fixation == 1 and len(est.targets) == 0


def _fixation_lines(point, t0, rng, n=60):
    """``n`` samples at 60 Hz from ``t0`` of a head swaying 300 mm sideways while looking at
    ``point`` (3,), 0.2 deg of noise: world-frame ``BinocularSamples``, their estimate."""
    head = np.column_stack([150.0 * np.sin(np.linspace(0, np.pi, n)), np.zeros(n), np.zeros(n)])
    lo, ro = head - [32.0, 0, 0], head + [32.0, 0, 0]
    s = BinocularSamples.from_arrays(t0 + np.arange(n) / 60.0, lo, perturb_directions(point - lo, np.deg2rad(0.2), rng),
                                     ro, perturb_directions(point - ro, np.deg2rad(0.2), rng))
    return s, estimate(s, "voxel")


def test_target_ids_merge_what_is_one_target_seen_twice_and_never_reuse_an_id():
    """Static fixations get the id of the target whose lines theirs join (``TargetMerger``); a
    moving one's id is its own, between them; an id given is never given to another target."""
    rng = np.random.default_rng(4)
    ids = TargetIds("voxel")
    A, B = np.array([0.0, 0, 2000]), np.array([300.0, 0, 2000])
    assert ids.id_for(*_fixation_lines(A, 0.0, rng)) == 0
    assert ids.new_own() == 1                                            # a moving target
    assert ids.id_for(*_fixation_lines(B, 2.0, rng)) == 2
    assert ids.id_for(*_fixation_lines(A, 4.0, rng), key="third") == 0     # A again
    assert ids.id_for(*_fixation_lines(B, 6.0, rng)) == 2
    assert len(ids) == 3 and [g.members for g in ids.merger.groups] == [[None, "third"], [None, None]]


# --- messages --------------------------------------------------------------------------------

def test_messages_have_the_version_1_format_to_the_byte():
    cov = np.diag([1.0, 4.0, 9.0])                          # 95 %: sqrt(9 * chi2(0.95, 3)) = 8.4 mm
    e = LiveEstimate(1.23456, 3, np.array([1.04, -2.06, 1500.149]), cov, 17)
    assert Publisher.encode(estimate_message(e, 4.5678)) == (
        b'{"version":1,"type":"estimate","t":1.2346,"fixation":3,"position_mm":[1.0,-2.1,1500.1],'
        b'"radius95_mm":8.4,"n_samples":17,"latency_ms":4.57}\n')
    assert estimate_message(LiveEstimate(0.0, 0, np.zeros(3), None, 1), 0.0)["radius95_mm"] is None
    t = Target(index=2, position_mm=np.array([10.0, 20.04, 3000.0]), covariance_mm2=np.eye(3),
               axes95_mm=np.array([1.01, 2.06, 30.0]), status="ok", n_samples=90, t_start=4.00001, t_end=5.55555,
               fixations=(7,), method="voxel", crb_mm=float("nan"))
    # the fields of version 1's first release, then those of the target record (issue 17) added at the end
    assert Publisher.encode(target_message(t)) == (
        b'{"version":1,"type":"target","target":2,"fixation":7,"t_start":4.0,"t_end":5.5556,'
        b'"position_mm":[10.0,20.0,3000.0],"ellipsoid95_radii_mm":[1.0,2.1,30.0],"n_samples":90,"method":"voxel",'
        b'"status":"ok","covariance_mm2":[[1.0,0.0,0.0],[0.0,1.0,0.0],[0.0,0.0,1.0]],"crb_mm":null,"fixations":[7]}\n')
    no_cov = Target(2, t.position_mm, None, np.full(3, np.nan), "ok", 90, 4.0, 5.0, (7,), "voxel", float("nan"))
    assert target_message(no_cov)["ellipsoid95_radii_mm"] is None
    # the message is the target's record (targets.json's fields) with version, type and fixation
    assert {k: v for k, v in target_message(t).items() if k not in ("version", "type", "fixation")} == t.row(True)
    for m in (target_message(t), target_message(no_cov), estimate_message(e, 1.0)):
        validate(json.loads(Publisher.encode(m)), "live-message", "message")


# --- the recorder ----------------------------------------------------------------------------

def test_the_recorder_writes_a_session_folder_that_reads_back(tmp_path):
    (tmp_path / "camera.json").write_text("{\"camera\": 1}")
    (tmp_path / "eyes.json").write_text("{\"eyes\": 2}")
    mm = MarkerMap("DICT_4X4_50", 80.0, {3: _pose(30.0, 100.0), 1: _pose()}, {3: "door"})
    root = tmp_path / "rec"
    rec = Recorder(root, (64, 48), 30.0, tmp_path / "camera.json", tmp_path / "eyes.json", mm, flush_s=0.05)
    gray = np.zeros((48, 64), np.uint8)
    for i in range(5):
        rec.frame(i / 30.0, i, gray + 40 * i)
    records = [EyeRecord(10 + i, i / 60.0, (2000.0 + i, 1990.5), (2010.25, 1980.0), True, i % 2 == 0)
               for i in range(7)]
    for i, r in enumerate(records):
        rec.eye_sample(0.5 + i / 60.0, r)
    rec.raw_bytes(b"\x00raw")
    rec.message(b'{"a":1}\n')
    rec.close(complete=True)
    sess = load_session(root)
    assert sess.manifest["complete"] is True
    assert (sess.manifest["n_frames"], sess.manifest["n_eye_samples"], sess.manifest["n_messages"]) == (5, 7, 1)
    assert sess.frame_times() == pytest.approx(np.arange(5) / 30.0, abs=1e-6)
    eye, _ = read_eye_csv(root / FILES["eye_samples"])
    assert eye.counter.tolist() == [r.counter for r in records]
    assert eye.t == pytest.approx(0.5 + np.arange(7) / 60.0, abs=1e-6)
    assert eye.valid[:, 1].tolist() == [r.right_valid for r in records] and eye.raw[3, 0, 0] == 2003.0
    back = load_marker_map(root / FILES["marker_map"])
    assert back.labels == {3: "door"} and np.allclose(back.poses[3], mm.poses[3])
    assert (root / FILES["camera"]).read_text() == "{\"camera\": 1}"
    assert (root / FILES["eye_serial"]).read_bytes() == b"\x00raw"
    assert (root / FILES["live_messages"]).read_bytes() == b'{"a":1}\n'


def test_a_recording_not_closed_cleanly_says_so(tmp_path):
    (tmp_path / "c").write_text("{}")
    mm = MarkerMap("DICT_4X4_50", 80.0, {1: _pose()}, {})
    rec = Recorder(tmp_path / "rec", (64, 48), 30.0, tmp_path / "c", tmp_path / "c", mm)
    rec.close(complete=False)
    assert json.loads((tmp_path / "rec" / "session.json").read_text())["complete"] is False
    with pytest.raises(UserError, match="not empty"):
        Recorder(tmp_path / "rec", (64, 48), 30.0, tmp_path / "c", tmp_path / "c", mm)


# --- the loop, over fakes of its parts -------------------------------------------------------

class _FakeThread:
    def __init__(self):
        self.queue: queue.Queue = queue.Queue()
        self.failure = None
        self.started = self.stopped = False

    def start(self):
        self.started = True

    def stop(self):
        self.stopped = True

    def is_alive(self):
        return False


class _FakeReader(_FakeThread):
    port = "fake://eye"

    def __init__(self, items):
        super().__init__()
        self.stats, self.error, self.connected = SerialStats(records=len(items)), None, threading.Event()
        self.connected.set()
        for it in items:
            self.queue.put(it)


class _OneAtATime:
    """A camera queue that has one frame ready at each look (a frame arrives per loop pass)."""

    def __init__(self, items):
        self.items, self.gave = list(items), False

    def get_nowait(self):
        if self.gave or not self.items:
            self.gave = False
            raise queue.Empty
        self.gave = True
        return self.items.pop(0)

    def empty(self):
        return not self.items


class _FakeCamera(_FakeThread):
    def __init__(self, frames, t0=100.0):
        super().__init__()
        self.stats, self.t0, self.finished = CameraStats(frames=len(frames)), t0, threading.Event()
        self.queue = _OneAtATime((t0 + t, i, T, None) for i, (t, T) in enumerate(frames))
        self.finished.set()                              # a file: read to its end, frames waiting


class _FakeEstimation:
    """Every sample gives an estimate; the sample at ``end_at`` ends a fixation, whose target
    ``finish`` makes (in the loop's target worker; ``finish_fails``: it raises)."""

    def __init__(self, end_at, fail_at=None, finish_fails=False):
        self.end_at, self.fail_at, self.seen, self.targets = end_at, fail_at, [], []
        self.finish_fails = finish_fails
        self.current_mm = None

    def _target(self, k):
        return Target(k, np.array([1.0, 2.0, 3.0]), None, np.full(3, np.nan), "ok", 10, 0.0, 1.0, (k,), "fake",
                      float("nan"))

    def add(self, t_s, rec, T):
        if rec.counter == self.fail_at:
            raise IndexError("list index out of range")
        self.seen.append((t_s, rec.counter, T))
        ended = 0 if rec.counter == self.end_at else None
        return ended, LiveEstimate(t_s, 0, np.array([1.0, 2.0, 3.0]), None, len(self.seen))

    def end_fixation(self):
        return 1

    def finish(self, k):
        if self.finish_fails:
            raise ZeroDivisionError("float division by zero")
        self.targets.append(k)
        return self._target(k)


class _FakePublisher:
    def __init__(self):
        self.lines, self.closed, self.dropped = [], False, 0

    def send(self, msg):
        line = Publisher.encode(msg)
        self.lines.append(line)
        return line

    def close(self, timeout_s=1.0):
        self.closed = True


class _FakeRecorder:
    root = "REC"

    def __init__(self):
        self.lines, self.complete = [], None

    def message(self, line):
        if self.complete is None:                        # as ``Recorder``: nothing once closed
            self.lines.append(line)

    def close(self, complete=True):
        self.complete = complete


def _loop(records, frames, estimation):
    reader, camera = _FakeReader(records), _FakeCamera(frames)
    head = HeadTracker(detect=lambda T: T, estimate=lambda T: _Pose(T, [7]))
    pub, rec = _FakePublisher(), _FakeRecorder()
    return LiveSession(reader, camera, head, estimation, pub, rec), pub, rec


def _eye_items(times, invalid=()):
    now = time.monotonic()                               # they have just arrived
    return [(now, t, EyeRecord(k, t, (1.0, 2.0), (3.0, 4.0), k not in invalid, k not in invalid))
            for k, t in enumerate(times)]


def test_the_loop_estimates_with_the_pose_at_each_samples_time_publishes_and_records_in_order():
    frames = [(0.5, _pose(0.0, 0.0)), (0.6, _pose(0.0, 100.0))]
    items = _eye_items([0.2, 0.57, 0.58, 0.6, 0.62, 0.7], invalid=(2,))
    est = _FakeEstimation(end_at=3)
    session, pub, rec = _loop(items, frames, est)
    st = session.run(duration_s=5.0)
    assert [c for _, c, _ in est.seen] == [1, 3, 4]         # 0: before any frame (no pose), 2: both eyes invalid,
    assert st.no_pose == 2 and st.samples == 6              # 5: 0.1 s after the last frame (no pose)
    assert est.seen[0][2][0, 3] == pytest.approx(70.0)      # 0.57 s waited for the next frame: interpolated
    assert est.seen[1][2][0, 3] == pytest.approx(100.0)     # 0.6 s: the frame's own
    assert est.seen[2][2][0, 3] == pytest.approx(120.0)     # 0.62 s: the walk of the last two frames carried on
    msgs = [json.loads(x) for x in pub.lines]
    assert [m["t"] for m in msgs if m["type"] == "estimate"] == [0.57, 0.6, 0.62]
    assert [m["target"] for m in msgs if m["type"] == "target"] == [0, 1]   # in the order the fixations ended,
    assert rec.lines == pub.lines and rec.complete is True                   # the last at the session's end
    assert st.published == 5 and st.targets == 2 and st.latency_all.n == 3 and st.distinct_targets == 2
    assert st.end_reason == "the camera ended" and pub.closed
    assert session.reader.stopped and session.frames.stopped


def test_an_error_inside_the_loop_ends_it_with_a_user_error_and_an_incomplete_recording():
    session, pub, rec = _loop(_eye_items([0.5, 0.51, 0.52]), [(0.5, _pose())], _FakeEstimation(None, fail_at=1))
    with pytest.raises(UserError, match=r"IndexError: list index out of range\).*REC is kept, marked incomplete"):
        session.run(duration_s=5.0)
    assert rec.complete is False and pub.closed


def test_an_error_in_the_target_worker_ends_the_session_with_a_user_error():
    session, pub, rec = _loop(_eye_items([0.5, 0.51, 0.52]), [(0.5, _pose())], _FakeEstimation(1, finish_fails=True))
    with pytest.raises(UserError, match=r"the target worker failed: ZeroDivisionError: float division by zero"):
        session.run(duration_s=5.0)
    assert rec.complete is False and pub.closed and not session.worker.is_alive()
    assert not [x for x in pub.lines if b'"target"' in x]


def test_a_failed_reader_thread_ends_the_session():
    session, _, rec = _loop([], [], _FakeEstimation(None))
    session.frames.finished.clear()
    session.reader.failure = "OSError: gone"
    with pytest.raises(UserError, match="the eye reader failed: OSError: gone"):
        session.run(duration_s=5.0)
    assert rec.complete is False


def test_a_camera_that_ends_without_eye_data_ends_the_session_saying_so():
    session, _, rec = _loop([], [(0.0, _pose())], _FakeEstimation(None))
    st = session.run(duration_s=5.0)
    assert "no eye data ever arrived from fake://eye" in st.end_reason and rec.complete is True


def test_frames_skipped_counts_the_camera_queues_drops_and_the_loops_own_skips():
    """``frames_skipped``: frames tracking never saw, whether the camera's queue had no room for
    them or the loop passed over them for a newer one (each counted once)."""
    session, _, _ = _loop([], [(0.5, _pose()), (0.6, _pose())], _FakeEstimation(None))
    session.frames.stats.skipped = 3                     # dropped by the camera before the loop
    session.tracking_skipped = 2                         # passed over by the loop
    assert session.update_stats().frames_skipped == 5
    assert session.update_stats().frames_skipped == 5    # copied, not added up again


class _ExactHead:
    """Head tracking faked: the exact pose at each sample's time, no waiting for frames."""

    markers_in_view = 1

    def __init__(self, poses):
        self.poses = dict(poses)

    def track(self, t, gray):
        pass

    def must_wait(self, t_s, waited_s):
        return False

    def pose_at(self, t_s):
        return self.poses[t_s]


class _WatchingPublisher(_FakePublisher):
    """Sets ``next_fixation`` once an estimate of a fixation after the first is sent."""

    def __init__(self):
        super().__init__()
        self.next_fixation = threading.Event()

    def send(self, msg):
        if msg["type"] == "estimate" and msg["fixation"] >= 1:
            self.next_fixation.set()
        return super().send(msg)


def test_a_slow_fixation_end_does_not_hold_the_next_samples_and_every_target_is_published(monkeypatch):
    """The motion test (here held until the loop has published an estimate of the next fixation,
    then slow) runs in the target worker: the loop goes on estimating meanwhile, and at the
    session's end it waits for the worker, so every target is published and recorded, in
    fixation order with the ids ``process`` would give (A, B, A: 0, 1, 0)."""
    import wearable_gaze.pipeline.steps.live_estimation as estimation

    eyes = _eyes()
    A, B = np.array([100.0, -50.0, 1500.0]), np.array([-500.0, 150.0, 1200.0])
    stream = _walk(eyes, [(A, 1.5), (B, 1.5), (A, 1.5)], rng=np.random.default_rng(0))
    now = time.monotonic()
    reader, camera = _FakeReader([(now, t, rec) for t, rec, _ in stream]), _FakeCamera([])
    pub, rec = _WatchingPublisher(), _FakeRecorder()
    session = LiveSession(reader, camera, _ExactHead((t, T) for t, _, T in stream), GazeEstimation(eyes, "voxel"),
                          pub, rec)
    real, calls = estimation.classify_lines, []

    def held_classifier(*args, **kw):
        calls.append(pub.next_fixation.wait(30.0))       # False: the loop was held (the old way)
        time.sleep(0.3)
        return real(*args, **kw)
    monkeypatch.setattr(estimation, "classify_lines", held_classifier)
    st = session.run(duration_s=60.0)
    msgs = [json.loads(x) for x in pub.lines]
    first_target = next(i for i, m in enumerate(msgs) if m["type"] == "target")
    assert msgs[first_target]["fixation"] == 0
    assert any(m["type"] == "estimate" and m["fixation"] == 1 for m in msgs[:first_target])   # not held
    targets = [m for m in msgs if m["type"] == "target"]
    assert [(m["fixation"], m["target"]) for m in targets] == [(0, 0), (1, 1), (2, 0)]
    assert calls == [True, True, True] and st.targets == 3 and st.distinct_targets == 2
    assert rec.lines == pub.lines and rec.complete is True and not session.worker.is_alive()


class _QueueCamera(_FakeThread):
    """A device's frames: a real queue the tracking thread waits on; the stream does not end."""

    def __init__(self, frames, t0=100.0):
        super().__init__()
        self.stats, self.t0, self.finished = CameraStats(frames=len(frames)), t0, threading.Event()
        self.queue = queue.Queue()
        for i, (t, T) in enumerate(frames):
            self.queue.put((t0 + t, i, T, None))


def test_with_frames_tracked_in_their_own_thread_no_eye_sample_waits_for_a_slow_frame():
    """A device session (``track_in_thread``): a frame whose tracking takes 0.4 s does not hold
    up the eye samples waiting meanwhile; each is estimated at once with the newest pose there
    is (the last tracked frame's, held), and the pose each took is recorded for ``process``.
    (Tracked in the loop's thread, as the serial session does, they wait the 0.4 s.)"""
    def slow(T):
        time.sleep(0.4)
        return T
    head = HeadTracker(detect=lambda T: T, estimate=lambda T: _Pose(T, [7]), max_age_s=0.2)
    head.track(0.0, _pose(0.0, 10.0))                    # a pose before the session: the frame at 0 s
    head.detect = slow
    est = _FakeEstimation(None)
    rec = _FakeRecorder()
    rec.poses = []
    rec.sample_pose = lambda t, T: rec.poses.append((t, T))
    camera = _QueueCamera([(0.033, _pose())])
    session = LiveSession(_FakeReader(_eye_items([0.01, 0.02, 0.03, 0.15, 0.3])), camera, head, est, _FakePublisher(),
                          rec, tracker=TrackingThread(camera, head))
    st = session.run(duration_s=0.3)
    assert [c for _, c, _ in est.seen] == [0, 1, 2, 3]       # 0.3 s: 0.3 s after the last pose, none
    assert st.latency_all.percentile(100) < 150.0, st.latency_all.percentile(100)
    assert all(T[0, 3] == 10.0 for _, _, T in est.seen)     # the pose of the frame at 0 s, held
    assert [t for t, _ in rec.poses] == [0.01, 0.02, 0.03, 0.15, 0.3] and rec.poses[-1][1] is None
    assert st.no_pose == 1 and session.tracker.tracked <= 1


def test_with_frames_tracked_in_their_own_thread_a_sample_too_late_is_not_estimated_but_recorded_as_such():
    """On a core too busy for the eye rate, samples that reach the loop more than
    ``SHED_AFTER_S`` after their device time are passed over (counted, recorded without a pose,
    so ``process`` passes over them too): the backlog, and the latency, stay bounded."""
    from wearable_gaze.live.loop import SHED_AFTER_S
    head = HeadTracker(detect=lambda T: T, estimate=lambda T: _Pose(T, [7]), max_age_s=0.2)
    head.track(0.0, _pose(0.0, 10.0))
    est, rec = _FakeEstimation(None), _FakeRecorder()
    rec.poses = []
    rec.sample_pose = lambda t, T: rec.poses.append((t, T))
    now = time.monotonic()
    items = [(now - 2 * SHED_AFTER_S, 0.01, EyeRecord(0, 0.01, (1.0, 2.0), (3.0, 4.0), True, True)),
             (now, 0.02, EyeRecord(1, 0.02, (1.0, 2.0), (3.0, 4.0), True, True))]
    camera = _QueueCamera([])
    session = LiveSession(_FakeReader(items), camera, head, est, _FakePublisher(), rec,
                          tracker=TrackingThread(camera, head))
    st = session.run(duration_s=0.2)
    assert [c for _, c, _ in est.seen] == [1] and st.shed == 1 and st.samples == 2
    assert rec.poses[0] == (0.01, None) and rec.poses[1][1] is not None
