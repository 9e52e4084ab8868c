"""Calibration (issue 4): camera intrinsics on OpenCV's own photos and on rendered boards, the
eye calibration (eq. 1-2) with wall tilt and eye centres, view lines, the CLI."""

import json

import cv2
import numpy as np
import pytest

from calibration.camera import BoardView, CameraCalibration, calibrate_camera, detect_board, parse_board
from calibration.eyes import (
    CalibrationError,
    calibrate_eye,
    estimate_center,
    fit_raw_map,
    plane_points,
    target_readings,
    wall_pose,
)
from estimator.frames import rotation_about_axis
from tracking.timeline import extrapolate_pose, interpolate_poses, pose_spikes
from wearable_gaze.cli import main
from wearable_gaze.formats.camera import load_camera
from wearable_gaze.formats.eyes import load_eyes
from wearable_gaze.formats.tables import read_table
from wearable_gaze.formats.viewlines import read_viewlines_csv
from wearable_gaze.sim.simulate import simulate_scenario

# --- real photos -------------------------------------------------------------------------------

def test_opencv_left_chessboards_reproduce_the_published_calibration(real_data):
    d = real_data / "opencv_stereo_chessboard_9x6"
    ref = json.loads((d / "reference_results.json").read_text())
    pub = ref["published_opencv_python_test"]
    spec = parse_board("chessboard:9x6:1")                  # square 1, as the published test
    views = [detect_board(cv2.imread(str(d / f), cv2.IMREAD_GRAYSCALE), spec, f) for f in ref["left_images_used"]]
    assert all(v.ok for v in views)
    cal = calibrate_camera(views, tuple(ref["image_size"]), spec)
    assert all(v["used"] for v in cal.views)                # no good view is thrown away
    assert abs(cal.rms_px - pub["rms"]) < pub["rms_tolerance"]
    assert np.abs(cal.camera_matrix - np.array(pub["camera_matrix"])).sum() < pub["camera_matrix_L1_tolerance"]


@pytest.mark.newest_opencv(reason="with 4 views fx is weakly determined: OpenCV 4.14's calibrateCamera "
                                  "gives 479.8 px on the same corners where 5.1 gives 457.3, the reference 452.5")
def test_opencv_charuco_tutorial_photos_calibrate_close_to_the_reference(real_data):
    d = real_data / "opencv_aruco_charuco_tutorial"
    ref = json.loads((d / "expected_results.json").read_text())["charuco_calibration_reference"]
    spec = parse_board("charuco:5x7:40:20:DICT_6X6_250")
    views = [detect_board(cv2.imread(str(d / f)), spec, f) for f in ref["images"]]
    assert [len(v.ids) for v in views] == [24, 24, 24, 24]
    cal = calibrate_camera(views, (640, 480), spec, reject=False)
    pub = ref["published"]
    # four views only: the focal length is weakly determined; OpenCV 5 also dropped a
    # +0.5 px ChArUco corner offset since the reference was made (PROVENANCE.md): ~1 %
    assert abs(cal.camera_matrix[0, 0] / pub["fx"] - 1) < 0.015
    assert abs(cal.camera_matrix[1, 1] / pub["fy"] - 1) < 0.015
    assert abs(cal.camera_matrix[0, 2] - pub["cx"]) < 3 and abs(cal.camera_matrix[1, 2] - pub["cy"]) < 4
    assert cal.rms_px < 0.25


def test_opencv_filestorage_camera_files_load(real_data):
    cam = load_camera(real_data / "opencv_stereo_chessboard_9x6" / "left_intrinsics.yml")
    assert abs(cam.camera_matrix[0, 0] - 535.9157) < 1e-3 and cam.image_size == (640, 480)
    assert abs(cam.dist_coeffs[0] + 0.26637) < 1e-4
    cam = load_camera(real_data / "opencv_aruco_charuco_tutorial" / "tutorial_camera_charuco.yml")
    assert abs(cam.camera_matrix[1, 1] - 456.767) < 1e-2 and len(cam.dist_coeffs) == 5


# --- rendered boards ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("cal") / "s"
    simulate_scenario({"base": "lab-walkabout", "duration_s": 4.0}, root, seed=21)
    return root


def test_rendered_board_views_recover_the_true_intrinsics(session, tmp_path, capsys):
    out = tmp_path / "camera.json"
    assert main(["calibrate-camera", str(session / "calibration" / "camera"), "--board", "chessboard:9x6:30",
                 "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "RMS" in printed and "view_000.png" in printed
    cal = load_camera(out)
    truth = load_camera(session / "truth" / "camera.json")
    assert np.abs(cal.camera_matrix - truth.camera_matrix).max() < 2.0       # px, of f = 640
    # and within the uncertainty the calibration reports (3 sigma)
    K, Kt = cal.camera_matrix, truth.camera_matrix
    for (i, j), name in (((0, 0), "fx"), ((1, 1), "fy"), ((0, 2), "cx"), ((1, 2), "cy")):
        assert abs(K[i, j] - Kt[i, j]) < 3 * cal.std[name] + 0.05, name
    # the lens model, not its coefficients: a true ray lands within 1.5 px of where the calibrated
    # model puts it, over the part of the image the boards covered
    w, h = truth.image_size
    px = np.array([[0.15, 0.15], [0.85, 0.15], [0.85, 0.85], [0.15, 0.85], [0.5, 0.15], [0.15, 0.5],
                   [0.5, 0.5]]) * [w, h]
    n = truth.undistort_points(px)
    assert np.linalg.norm(cal.project(np.column_stack([n, np.ones(len(n))])) - px, axis=1).max() < 1.5
    assert cal.rms_px < 0.15
    assert (tmp_path / "camera_undistorted.png").is_file()


def test_a_bad_view_is_rejected_with_its_reason(session):
    spec = parse_board("chessboard:9x6:30")
    views = [detect_board(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), spec, p.name)
             for p in sorted((session / "calibration" / "camera").glob("*.png"))]
    bad = views[3]
    rng = np.random.default_rng(0)
    views[3] = BoardView(bad.name, bad.object_points, bad.image_points + rng.normal(0, 3, bad.image_points.shape),
                         bad.ids)
    views.append(BoardView("blank.png", np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, int), "no board found"))
    cal = calibrate_camera(views, (1280, 720), spec)
    rep = {v["view"]: v for v in cal.views}
    assert not rep[bad.name]["used"] and "reprojection RMS" in rep[bad.name]["reason"]
    assert not rep["blank.png"]["used"] and rep["blank.png"]["reason"] == "no board found"
    assert sum(v["used"] for v in cal.views) == len(views) - 2 and cal.rms_px < 0.15


def test_the_worst_of_projected_views_is_the_one_rejected_and_the_rest_give_the_intrinsics():
    """Eight views of a 9x6 board projected with known intrinsics (0.1 px noise, no rendering),
    one with 3 px noise: that view, and only it, is rejected for its reprojection RMS, and the
    others recover fx, fy within 0.5 % (issue 30, planted fault ``camera-reject-best``)."""
    rng = np.random.default_rng(37)
    spec = parse_board("chessboard:9x6:30")
    obj = spec.object_points()
    K = np.array([[900.0, 0.0, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
    D = np.array([-0.1, 0.05, 0.0, 0.0, 0.0])
    views = []
    for i in range(8):
        rvec = rng.uniform(-0.5, 0.5, 3)
        R, _ = cv2.Rodrigues(rvec)
        tvec = -R @ obj.mean(axis=0) + [rng.uniform(-80, 80), rng.uniform(-50, 50), rng.uniform(600, 900)]
        px = cv2.projectPoints(obj, rvec, tvec, K, D)[0].reshape(-1, 2)
        px += rng.normal(0, 3.0 if i == 5 else 0.1, px.shape)
        views.append(BoardView(f"view{i}", obj, px, np.arange(len(obj))))
    cal = calibrate_camera(views, (1280, 720), spec)
    assert [v["view"] for v in cal.views if not v["used"]] == ["view5"]
    assert "reprojection RMS" in cal.views[5]["reason"]
    np.testing.assert_allclose(np.diag(cal.camera_matrix)[:2], [900.0, 905.0], rtol=0.005)


# --- eye calibration ---------------------------------------------------------------------------

def _grid(n=3, span=0.35):
    g = np.linspace(-span, span, n)
    return np.array([[x, y] for y in g for x in g])


def test_quadratic_raw_map_is_exact_on_quadratic_data_and_refuses_degenerate_designs():
    rng = np.random.default_rng(0)
    raw = 2000 + 800 * _grid() + rng.normal(0, 5, (9, 2))
    C = rng.normal(size=(6, 2))
    r = (raw - 2000) / 800
    q = np.column_stack([np.ones(9), r[:, 0], r[:, 1], r[:, 0] ** 2, r[:, 0] * r[:, 1], r[:, 1] ** 2]) @ C
    m = fit_raw_map(raw, q)
    assert np.abs(m(raw) - q).max() < 1e-9
    a, b = m.paper_coefficients()                         # eq. 1-2 on raw counts reproduce it
    x, y = raw[:, 0], raw[:, 1]
    X = a[0] + a[1] * x + a[2] * y + a[3] * x * x + a[4] * x * y + a[5] * y * y
    assert np.abs(X - q[:, 0]).max() < 1e-6
    with pytest.raises(CalibrationError, match="at least 6"):
        fit_raw_map(raw[:5], q[:5])
    line = np.column_stack([np.linspace(1000, 3000, 9), np.linspace(1000, 3000, 9)])
    with pytest.raises(CalibrationError, match="line"):
        fit_raw_map(line, q)


def test_transposed_inputs_are_refused_naming_the_shape():
    """A (2, 9) array where (9, 2) is meant used to be reshaped into 9 scrambled rows: every public
    function of calibration and tracking now checks the shape and names the one it received."""
    from calibration.camera import undistort_points
    from calibration.eyes import plane_points
    from tracking.corners import refine_markers
    from tracking.timeline import smooth_poses

    rng = np.random.default_rng(0)
    model, _, P = _eye_setup(rng)
    model.sigma_deg = 0.05
    raw, _, _ = model.measure(P, rng, with_bias=False)
    raw = raw[:, 0]                                                      # (9, 2)
    cal = calibrate_eye("left", raw, P, model.centers[0])
    assert cal.directions(raw).shape == (9, 3)
    q = cal.image_points(raw)
    bad = r"must have shape \(N, 2\), got \(2, 9\)"
    for call in (lambda: cal.directions(raw.T), lambda: cal.image_points(raw.T), lambda: cal.lines(raw.T),
                 lambda: fit_raw_map(raw.T, q), lambda: fit_raw_map(raw, q.T),
                 lambda: calibrate_eye("left", raw.T, P, model.centers[0]),
                 lambda: estimate_center(raw.T, P, model.centers[0]),
                 lambda: wall_pose(P[:, :2].T, q), lambda: wall_pose(P[:, :2], q.T),
                 lambda: target_readings(np.arange(9), raw.T, np.ones(9, bool)),
                 lambda: undistort_points(q.T, np.eye(3), np.zeros(5))):
        with pytest.raises(ValueError, match=bad):
            call()
    with pytest.raises(ValueError, match=r"targets_cam_mm must have shape \(N, 3\), got \(3, 9\)"):
        calibrate_eye("left", raw, P.T, model.centers[0])
    with pytest.raises(ValueError, match=r"targets_cam_mm must have shape \(N, 3\), got \(3, 9\)"):
        plane_points(P.T, model.centers[0], 1000.0)
    with pytest.raises(ValueError, match=r"one row per target, got 9 and 8"):
        calibrate_eye("left", raw, P[:8], model.centers[0])
    with pytest.raises(ValueError, match=r"corners must have shape \(N, 4, 2\), got \(2, 4, 3\)"):
        refine_markers(np.zeros((50, 50), np.uint8), np.zeros((2, 4, 3)), 6)
    T = np.tile(np.eye(4), (5, 1, 1))
    with pytest.raises(ValueError, match=r"T_src must have shape \(N, 4, 4\), got \(4, 4, 5\)"):
        interpolate_poses(np.arange(5.0), T.transpose(1, 2, 0), [1.5])
    with pytest.raises(ValueError, match=r"t and T must have one entry per pose, got 4 and 5"):
        smooth_poses(np.arange(4.0), T, 1.0)


def _eye_setup(rng, tilt_deg=10.0):
    from wearable_gaze.sim.eyes import EyeModel
    from wearable_gaze.sim.world import CalibrationWall

    model = EyeModel.make(rng)
    wall = CalibrationWall(1000.0, tilt_deg)
    P = wall.to_world(wall.targets_wall())
    return model, wall, P


def test_calibrate_eye_reports_residuals_loo_and_flags_an_outlier_target():
    rng = np.random.default_rng(1)
    model, _, P = _eye_setup(rng)
    model.sigma_deg = 0.05
    raw, _, _ = model.measure(P, rng, with_bias=False)
    cal = calibrate_eye("left", raw[:, 0], P, model.centers[0], focal_px=640.0)
    rep = cal.report
    assert rep["rms_deg"] < 0.15 and rep["loo_rms_deg"] < 0.4 and rep["outliers"] == []
    assert len(rep["residual_px"]) == 9
    bad = raw[:, 0].copy()
    bad[4] += 60.0                                        # ~3.5 deg off at the centre target
    rep = calibrate_eye("left", bad, P, model.centers[0]).report
    assert rep["outliers"] == [4]
    with pytest.raises(CalibrationError, match="left eye"):
        calibrate_eye("left", np.full((9, 2), np.nan), P, model.centers[0])
    collinear = P.copy()
    collinear[:, 1] = 0.0
    with pytest.raises(CalibrationError, match="collinear"):
        calibrate_eye("right", raw[:, 1], collinear, model.centers[1])


def test_plane_points_put_each_target_on_its_line_from_the_eye_centre():
    """Eq. 3-4 from ``plane_points``' q: the point (q l_c, l_c) on the calibration plane lies on
    the line from the eye centre through the target, for targets nearer and farther than the
    plane (issue 30, planted fault ``eye-plane-centre-depth``)."""
    rng = np.random.default_rng(38)
    for _ in range(20):
        e = rng.uniform(-40.0, 40.0, 3)
        P = np.column_stack([rng.uniform(-800.0, 800.0, (30, 2)), rng.uniform(500.0, 4000.0, 30)])
        lc = rng.uniform(800.0, 2500.0)
        q = plane_points(P, e, lc)
        p = np.column_stack([q * lc, np.full(len(q), lc)])
        u, v = p - e, P - e
        np.testing.assert_allclose(u / np.linalg.norm(u, axis=1, keepdims=True),
                                   v / np.linalg.norm(v, axis=1, keepdims=True), atol=1e-12)


def test_an_eye_calibrated_at_two_wall_distances_reproduces_every_target():
    """Readings that are the tangents of the true directions from the eye centre (a map the
    quadratic model holds exactly), targets at 1 m and 2 m, the plane at either: every target's
    direction is reproduced to 1e-6 deg (with the plane's points taken from the camera's origin
    instead of the eye centre they miss by about 0.1 deg)."""
    e = np.array([-32.0, 30.0, -20.0])
    g = _grid(3, 0.35)
    P = np.vstack([np.column_stack([g * d + [40.0, -25.0], np.full(9, d)]) for d in (1000.0, 2000.0)])
    v = P - e
    raw = 2000.0 + 1500.0 * v[:, :2] / v[:, 2:3]
    for plane in (1000.0, 2000.0):
        cal = calibrate_eye("left", raw, P, e, plane_mm=plane)
        assert cal.report["rms_deg"] < 1e-6, cal.report["rms_deg"]
        d = cal.directions(raw)
        np.testing.assert_allclose(d, v / np.linalg.norm(v, axis=1, keepdims=True), atol=1e-9)


def test_wall_pose_recovers_distance_and_tilt():
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis([0, 1, 0], np.deg2rad(10)) @ rotation_about_axis([1, 0, 0], np.deg2rad(3))
    T[:3, 3] = [30, -20, 1200]
    W = np.array([[x, y] for x in (-600, -480, 480, 600) for y in (-400, -280, 280, 400)], float)
    P = W @ T[:3, :2].T + T[:3, 3]
    wp = wall_pose(W, P[:, :2] / P[:, 2:3])
    assert np.abs(wp.T_cam_from_wall - T).max() < 1e-6
    assert abs(wp.tilt_deg - np.degrees(np.arccos(T[2, 2]))) < 1e-6


def test_target_readings_skip_the_saccade_and_blinks():
    t = np.arange(180) / 60.0
    target = np.repeat(np.arange(3), 60)
    raw = np.repeat(np.array([[100.0, 200.0], [300.0, 400.0], [500.0, 600.0]]), 60, axis=0)
    raw[60:66] = [200.0, 300.0]                                # still travelling
    valid = np.ones(180, bool)
    valid[150:160] = False
    raw[150:160] = 0.0
    ids, vals, counts = target_readings(target, raw, valid, t)
    assert list(ids) == [0, 1, 2] and np.allclose(vals, [[100, 200], [300, 400], [500, 600]])
    assert counts[2] == 60 - 12 - 10


def test_calibration_study_meets_the_issue_targets():
    """Done-when: mean view-direction error <= 0.15 deg with both corrections (paper error sources),
    each correction helps, and the two-distance centres land within 3 mm (median)."""
    from wearable_gaze.paper.calstudy import run_calibration_study

    r = run_calibration_study(trials=12, seed=3)
    e = {k: float(np.mean(v)) for k, v in r.errors_deg.items()}
    assert e["both"] <= 0.15
    assert e["no correction"] > 3 * e["both"] and e["undistortion only"] > e["both"]
    assert np.median(r.center_errors_mm) < 3.0
    # the reported uncertainty is honest: errors are of the size it says
    assert 0.3 < np.median(r.center_errors_mm / r.center_sigma_mm) < 2.0
    assert "| both |" in r.format()


def test_estimate_centre_needs_two_distances():
    rng = np.random.default_rng(2)
    model, _, P = _eye_setup(rng)
    raw, _, _ = model.measure(P, rng, with_bias=False)
    with pytest.raises(CalibrationError, match="two wall distances"):
        estimate_center(raw[:, 0], P, [-32, 30, -20])


# --- end to end on a session -------------------------------------------------------------------

def test_calibrate_eyes_and_viewlines_on_a_rendered_session(session, tmp_path, capsys):
    eyes = tmp_path / "eyes.json"
    assert main(["calibrate-eyes", str(session), "--camera", str(session / "truth" / "camera.json"),
                 "-o", str(eyes)]) == 0
    out = capsys.readouterr().out
    assert "two-distance" in out and "tilt 12.0 deg" in out
    truth = json.loads((session / "truth" / "eyes.json").read_text())
    cals = load_eyes(eyes)
    for e in range(2):
        assert np.linalg.norm(cals[e].center_mm - truth["centres_mm"][e]) < 3.0
    vl = tmp_path / "viewlines.csv"
    assert main(["viewlines", str(session / "eye.csv"), "--eyes", str(eyes), "--poses",
                 str(session / "truth" / "head_poses.csv"), "-o", str(vl)]) == 0
    seg = read_viewlines_csv(vl)[0].samples
    g = read_table(session / "truth" / "gaze.csv", ["t"], ("phase",))
    idx = np.round(seg.t_s * 60).astype(int)
    for side in ("left", "right"):
        meas = np.column_stack([g[f"{side}_meas_d{a}"] for a in "xyz"])[idx]
        d, v = getattr(seg, f"{side}_direction"), getattr(seg, f"{side}_valid")
        ang = np.degrees(np.arccos(np.clip((d[v] * meas[v]).sum(1), -1, 1)))
        assert ang.mean() < 0.15                          # the calibration's own error, on top of the noise
        assert not v.all()                                # blinks stay marked


def test_interpolate_poses_slerps_and_refuses_gaps():
    t = np.array([0.0, 1.0, 2.0, 5.0])
    T = np.tile(np.eye(4), (4, 1, 1))
    for i, a in enumerate([0.0, 20.0, 40.0, 100.0]):
        T[i, :3, :3] = rotation_about_axis([0, 1, 0], np.deg2rad(a))
        T[i, :3, 3] = [10 * a, 0, 0]
    T[2] = np.nan                                          # no pose at t = 2
    Tq, ok = interpolate_poses(t, T, [0.5, 1.5, 3.0, 6.0], max_gap_s=1.0)
    assert list(ok) == [True, False, False, False]
    assert np.allclose(Tq[0, :3, :3], rotation_about_axis([0, 1, 0], np.deg2rad(10.0)))
    assert np.allclose(Tq[0, :3, 3], [100, 0, 0])
    Tq, ok = interpolate_poses(t, T, [1.5], max_gap_s=5.0)
    assert ok[0] and np.allclose(Tq[0, :3, :3], rotation_about_axis([0, 1, 0], np.deg2rad(20 + 80 * 0.5 / 4)))


def test_extrapolate_pose_carries_the_turn_and_the_walk_on_at_their_rate():
    from scipy.spatial.transform import Rotation
    R0 = Rotation.from_euler("xyz", [20, -35, 10], degrees=True)          # not about the turn's axis
    step = Rotation.from_rotvec(np.deg2rad(3.0) * np.array([0.3, 0.9, -0.3]) / np.linalg.norm([0.3, 0.9, -0.3]))
    Ta, Tb = np.eye(4), np.eye(4)
    Ta[:3, :3], Tb[:3, :3] = R0.as_matrix(), (step * R0).as_matrix()      # a world-frame turn of 3 deg in 30 ms
    Ta[:3, 3], Tb[:3, 3] = [0.0, 0.0, 0.0], [6.0, -1.5, 3.0]
    T = extrapolate_pose(1.00, Ta, 1.03, Tb, 1.045)                       # half a step on
    half = Rotation.from_rotvec(0.5 * step.as_rotvec())
    assert np.allclose(T[:3, :3], (half * step * R0).as_matrix(), atol=1e-12)
    assert np.allclose(T[:3, 3], [9.0, -2.25, 4.5]) and np.allclose(T[3], [0, 0, 0, 1])
    assert np.allclose(extrapolate_pose(1.00, Ta, 1.03, Tb, 1.03), Tb)
    with pytest.raises(ValueError, match="t_b must come after t_a"):
        extrapolate_pose(1.03, Ta, 1.03, Tb, 1.05)


def test_pose_spikes_are_the_poses_that_jump_off_a_smooth_head_and_back():
    """A walking, turning head at 15 poses a second (every other frame at 30 fps) with 2 mm and
    0.1 deg of tracking noise, speeding up to 1.5 m/s and 120 deg/s: no spike. A pose 300 mm
    off, one turned 8 deg, and one 300 mm off just after a gap (compared with the two after it,
    continued back) are found, and not their neighbours."""
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(3)
    t = np.arange(0, 6, 1 / 15)
    x = 250.0 * t ** 2 / 2 / 6 * 6                    # 250 mm/s^2: 1.5 m/s at the end
    yaw = 10.0 * t ** 2                               # 120 deg/s at the end
    T = np.tile(np.eye(4), (len(t), 1, 1))
    for i in range(len(t)):
        T[i, :3, :3] = (Rotation.from_rotvec(np.deg2rad(0.1) * rng.normal(size=3))
                        * Rotation.from_euler("y", yaw[i], degrees=True)).as_matrix()
        T[i, :3, 3] = [x[i], 0.0, 1000.0] + rng.normal(0, 2.0, 3)
    spike, off_mm, off_deg = pose_spikes(t, T)
    assert not spike.any() and np.nanmax(off_mm) < 25 and np.nanmax(off_deg) < 1.0
    T[20, :3, 3] += [0.0, 300.0, 0.0]
    T[50, :3, :3] = Rotation.from_euler("x", 8.0, degrees=True).as_matrix() @ T[50, :3, :3]
    T[70:73] = np.nan                                 # a gap of 0.27 s: pose 73 is next to it
    T[73, :3, 3] += [300.0, 0.0, 0.0]
    spike, off_mm, off_deg = pose_spikes(t, T)
    assert list(np.flatnonzero(spike)) == [20, 50, 73]
    assert off_mm[20] == pytest.approx(300.0, abs=10) and off_deg[50] == pytest.approx(8.0, abs=0.5)
    assert off_mm[73] == pytest.approx(300.0, abs=15) and np.isnan(off_mm[70])


def test_calibration_cli_errors_are_one_line(tmp_path, capsys):
    cases = [
        (["calibrate-camera", str(tmp_path), "--board", "chess:9x6", "-o", str(tmp_path / "c.json")], "chessboard:"),
        (["calibrate-camera", str(tmp_path / "none"), "--board", "chessboard:9x6:25", "-o", str(tmp_path / "c.json")],
         "no such file"),
        (["calibrate-eyes", str(tmp_path), "--camera", str(tmp_path / "c.json"), "-o", str(tmp_path / "e.json")],
         "eye_calibration.csv"),
        (["viewlines", str(tmp_path / "eye.csv"), "--eyes", str(tmp_path / "e.json"), "--poses",
          str(tmp_path / "p.csv"), "-o", str(tmp_path / "v.csv")], "no such file"),
    ]
    for argv, needle in cases:
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err, err
    (tmp_path / "bad.json").write_text('{"camera_matrix": [[1, 0], [0, 1]]}')
    with pytest.raises(ValueError):
        CameraCalibration.from_dict(json.loads((tmp_path / "bad.json").read_text()))
    assert main(["calibrate-eyes", str(tmp_path), "--camera", str(tmp_path / "bad.json"), "-o", "x"]) == 2


def test_calibrate_camera_from_a_video_picks_views_for_coverage_and_fits_fisheye(session, tmp_path):
    from wearable_gaze.pipeline.steps.calibrate import calibrate_camera_files

    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
              for p in sorted((session / "calibration" / "camera").glob("*.png"))]
    video = tmp_path / "boards.avi"
    w = cv2.VideoWriter(str(video), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1280, 720), isColor=False)
    for f in frames:
        for _ in range(3):                                 # each view held for 3 frames, as a slow sweep
            w.write(f)
    w.release()
    cal, _ = calibrate_camera_files([video], "chessboard:9x6:30", tmp_path / "cam.json", max_views=8)
    used = [v for v in cal.views if v["used"]]
    assert len(used) == 8 and all("#" in v["view"] for v in cal.views)
    skipped = [v for v in cal.views if not v["used"]]
    assert skipped and all("coverage" in v["reason"] for v in skipped)
    assert cal.rms_px < 0.5 and abs(cal.camera_matrix[0, 0] - 640) < 6
    fish, _ = calibrate_camera_files([session / "calibration" / "camera"], "chessboard:9x6:30",
                                     tmp_path / "fish.json", model="fisheye")
    assert fish.model == "fisheye" and len(fish.dist_coeffs) == 4 and fish.rms_px < 1.0
    assert load_camera(tmp_path / "fish.json").model == "fisheye"


def test_to_grey_is_opencv_luma_of_bgr_and_leaves_grey_images_alone():
    """One conversion for every image: BGR (OpenCV's channel order) to luma 0.299 R + 0.587 G +
    0.114 B; a grey image passes through untouched (the same array)."""
    from calibration.images import to_gray

    img = np.zeros((2, 3, 3), np.uint8)
    img[0, 0] = (255, 0, 0)            # blue
    img[0, 1] = (0, 0, 255)            # red
    img[0, 2] = (0, 255, 0)            # green
    img[1] = (10, 200, 90)
    g = to_gray(img)
    assert g.shape == (2, 3) and g.dtype == np.uint8
    assert g[0].tolist() == [29, 76, 150]
    assert g[1, 0] == round(0.299 * 90 + 0.587 * 200 + 0.114 * 10)
    gray = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert to_gray(gray) is gray


def test_eye_calibration_logs_its_fit_and_outliers(caplog):
    """The library says what it fitted (for ``-v``): the eye, target count, RMS and the outliers."""
    import logging

    rng = np.random.default_rng(1)
    model, _, P = _eye_setup(rng)
    model.sigma_deg = 0.05
    raw, _, _ = model.measure(P, rng, with_bias=False)
    bad = raw[:, 0].copy()
    bad[4] += 60.0
    with caplog.at_level(logging.INFO, logger="calibration"):
        rep = calibrate_eye("left", bad, P, model.centers[0]).report
    lines = [r.getMessage() for r in caplog.records if r.name == "calibration.eyes"]
    assert len(lines) == 1
    assert lines[0].startswith("left eye (quadratic): 9 targets, RMS ") and lines[0].endswith("outliers [4]")
    assert f"RMS {rep['rms_deg']:.3f} deg" in lines[0]
