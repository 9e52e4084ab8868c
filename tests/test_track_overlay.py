"""``track --overlay`` (issue 12): the world axes are drawn whatever the pose (points far outside
the view crashed OpenCV with "Can't parse 'pt2'"), and a failure while tracking leaves neither a
partial overlay nor partial poses under their final names."""

import types

import cv2
import numpy as np
import pytest

import wearable_gaze.pipeline.steps.track as track_cmd
from calibration.camera import CameraCalibration
from estimator.frames import rotation_about_axis
from wearable_gaze.cli import main
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.pipeline.steps.track import track_video_files as track_video
from wearable_gaze.sim.simulate import simulate_scenario

# the simulated lab camera at 640x360: 90 degrees across, strong barrel distortion
CAMERA = CameraCalibration(np.array([[320.0, 0, 320], [0, 320, 180], [0, 0, 1]]),
                           np.array([-0.28, 0.09, 0.0, 0.0, -0.012]), (640, 360))
RED = (0, 0, 255)


def _pose(T_cam_from_world):
    return types.SimpleNamespace(ok=True, T_world_from_cam=np.linalg.inv(T_cam_from_world), reason="")


def _T(R=None, t=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def _red(img):
    return np.all(img == RED, axis=2)


def test_world_axes_far_outside_the_view_are_not_drawn_and_do_not_crash():
    frame = np.zeros((360, 640, 3), np.uint8)
    # the world origin 51 mm in front of the camera and 1.8 m to its left: 35 times the focal
    # length off the axis, where the distortion polynomial gives pixels beyond 32-bit integers
    img = track_cmd._draw_overlay(frame, [], _pose(_T(t=(-1800.0, 0.0, 51.0))), CAMERA)
    assert not _red(img).any()                   # nothing of the axes is in the view: nothing drawn
    # every pose a walking head takes: the axes are drawn or not, never an error
    rng = np.random.default_rng(12)
    drawn = 0
    for _ in range(400):
        R = rotation_about_axis(rng.normal(size=3), rng.uniform(0, np.pi))
        img = track_cmd._draw_overlay(frame, [], _pose(_T(R, rng.uniform(-3000, 3000, 3))), CAMERA)
        drawn += _red(img).any()
    assert drawn > 0


def test_an_axis_is_drawn_where_it_projects_and_cut_where_it_leaves_the_view():
    frame = np.zeros((360, 640, 3), np.uint8)
    img = track_cmd._draw_overlay(frame, [], _pose(_T(t=(0.0, 0.0, 1000.0))), CAMERA)
    u, v = CAMERA.project(np.array([[150.0, 0.0, 1000.0]]))[0]          # half way along the x axis
    assert _red(img[int(v) - 2:int(v) + 3, int(u) - 2:int(u) + 3]).any()
    # x axis pointing back past the camera: its start is in view, its end behind the camera
    R = rotation_about_axis(np.array([0.0, 1.0, 0.0]), np.deg2rad(120.0))
    img = track_cmd._draw_overlay(frame, [], _pose(_T(R, (0.0, 0.0, 200.0))), CAMERA)
    u0, v0 = CAMERA.project(np.array([[0.0, 0.0, 200.0]]))[0]
    assert _red(img[int(v0) - 3:int(v0) + 4, int(u0) - 3:int(u0) + 4]).any()


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    root = tmp_path_factory.mktemp("trk") / "s"
    simulate_scenario({"base": "lab-walkabout", "duration_s": 1.0, "camera": {"resolution": [640, 360]},
                       "calibration": {"eye": False, "camera_views": 0}}, root, seed=3)
    return root


def _args(root):
    return (root / "scene.mp4", root / "truth" / "camera.json")


@pytest.mark.parametrize("error", [RuntimeError("drawing failed"), KeyboardInterrupt()])
def test_a_failure_while_tracking_leaves_no_partial_overlay_and_no_poses(short, tmp_path, monkeypatch, error):
    ov, out = tmp_path / "ov.mp4", tmp_path / "poses.csv"
    ov.write_bytes(b"an earlier overlay")
    out.write_bytes(b"earlier poses")
    calls = []
    real = track_cmd._draw_overlay

    def failing(*args):
        calls.append(1)
        if len(calls) == 10:
            raise error
        return real(*args)
    monkeypatch.setattr(track_cmd, "_draw_overlay", failing)
    with pytest.raises(type(error)):
        track_video(*_args(short), out, markers=short / "markers.json", overlay=ov)
    assert len(calls) == 10
    assert ov.read_bytes() == b"an earlier overlay" and out.read_bytes() == b"earlier poses"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ov.mp4", "poses.csv"]     # no temporary left


def test_an_overlay_that_cannot_be_written_is_one_line_and_writes_nothing(short, tmp_path, capsys):
    out = tmp_path / "poses.csv"
    video, cam = _args(short)
    assert main(["track", str(video), "--camera", str(cam), "--markers", str(short / "markers.json"), "-o", str(out),
                 "--overlay", str(tmp_path / "ov.unknown-format")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--overlay" in err
    assert list(tmp_path.iterdir()) == []


def test_tracking_one_frame_in_two_keeps_the_tracked_poses_and_interpolates_the_rest(short, tmp_path):
    video, cam = _args(short)
    every1 = track_video(video, cam, tmp_path / "p1.csv", markers=short / "markers.json")
    every2 = track_video(video, cam, tmp_path / "p2.csv", markers=short / "markers.json", every=2)
    assert every1["frames"] == every2["frames"] == 30
    t1, f1, T1, x1 = read_poses_csv(tmp_path / "p1.csv")
    t2, f2, T2, x2 = read_poses_csv(tmp_path / "p2.csv")
    assert np.array_equal(f1, f2) and np.array_equal(t1, t2)
    assert np.array_equal(T1[::2], T2[::2]) and list(x2["status"][1:-1:2]) == ["interpolated"] * 14
    assert np.array_equal(T1[-1], T2[-1]) and x2["status"][-1] == "ok"   # the last frame (29) is tracked too
    w = ((t2[1:-1:2] - t2[0:-2:2]) / (t2[2::2] - t2[0:-2:2]))[:, None]   # linear in translation, SLERP in rotation
    assert np.allclose(T2[1:-1:2, :3, 3], (1 - w) * T2[0:-2:2, :3, 3] + w * T2[2::2, :3, 3], atol=1e-3)
    assert np.abs(T1[1:-1:2, :3, 3] - T2[1:-1:2, :3, 3]).max() < 20.0       # mm: and near the tracked pose
    with_overlay = track_video(video, cam, tmp_path / "p3.csv", markers=short / "markers.json", every=2,
                               overlay=tmp_path / "ov.mp4")
    assert with_overlay == every1                                     # an overlay tracks every frame
    assert (tmp_path / "p3.csv").read_bytes() == (tmp_path / "p1.csv").read_bytes()
    cap = cv2.VideoCapture(str(tmp_path / "ov.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 30
    cap.release()


class _FrameSource:
    """A cv2.VideoCapture stand-in: ``n`` black frames."""

    def __init__(self, n):
        self.n, self.i = n, 0

    def read(self):
        if self.i >= self.n:
            return False, None
        self.i += 1
        return True, np.zeros((8, 8, 3), np.uint8)

    def grab(self):
        return self.read()[0]


def test_a_tracked_pose_that_jumps_off_the_heads_path_and_back_is_rejected(tmp_path):
    """A head walking at 0.6 m/s, tracked one frame in two at 30 fps; one tracked pose is 400 mm
    off (a single marker's wrong solution): it is rejected, with the reason, and the frames
    around it have no pose rather than one SLERPed toward it; its tracked neighbours are kept."""
    from tracking.pose import OK, PoseResult
    poses = [_T(t=(20.0 * i, 0.0, 0.0)) for i in range(30)]
    poses[12] = _T(t=(240.0, 400.0, 0.0))
    tracked = iter([*range(0, 30, 2), 29])                # one in two, and the last

    def locate(gray):
        i = next(tracked)
        return PoseResult(poses[i], OK, markers=[1], n_points=4, reproj_rms_px=0.1), []
    res = track_cmd.track_poses(_FrameSource(30), 30.0, 30, locate, every=2)
    status = list(res.columns["status"])
    assert status[12].startswith("rejected: a spike, 400 mm")
    assert np.isnan(res.T_world_from_cam[11:14]).all() and status[11] == status[13] != "interpolated"
    assert all(status[k] == "ok" for k in range(0, 30, 2) if k != 12)
    assert all(status[k] == "interpolated" for k in range(1, 29, 2) if k not in (11, 13))
    assert np.allclose(res.T_world_from_cam[10, :3, 3], [200.0, 0.0, 0.0])
    assert np.allclose(res.T_world_from_cam[14, :3, 3], [280.0, 0.0, 0.0])
