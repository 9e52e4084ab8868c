"""Head pose without markers (issue 16): the features, the matching and the pose of
``tracking.localise`` on synthetic ground truth, then a markerless map built by ``map
--markerless`` from a short rendered survey and frames of it localised against the simulator's
truth (benchmarks/bench_sfm.py measures the full-length survey and a walkabout)."""

import contextlib
import csv
import io
import json
import shutil

import cv2
import numpy as np
import pytest
from helpers import TimedLog, slow_down
from scipy.spatial.transform import Rotation

from calibration.camera import CameraCalibration
from estimator.frames import invert
from tracking.localise import FeatureLocalizer, FeatureMap, image_features, root_sift, triangulate
from tracking.pose import rotation_angle_deg
from wearable_gaze.cli import main
from wearable_gaze.formats.camera import load_camera
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.sfmmap import load_sfm_map
from wearable_gaze.pipeline.steps.track import track_video
from wearable_gaze.sim.simulate import simulate_scenario

K = np.array([[640.0, 0, 639.5], [0, 640.0, 359.5], [0, 0, 1]])
CAM = CameraCalibration(K, np.zeros(5), (1280, 720))


def _pose(rng) -> np.ndarray:
    """A random T_cam_from_world looking at points around the origin from about 2 m."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
    T[:3, 3] = rng.normal(0, 100, 3) + [0, 0, 2000]
    return T


def test_triangulate_finds_a_point_from_its_exact_views():
    rng = np.random.default_rng(0)
    X = np.array([120.0, -40.0, 300.0])
    Ts = np.array([_pose(rng) for _ in range(5)])
    x = np.array([(T[:3, :3] @ X + T[:3, 3])[:2] / (T[:3, :3] @ X + T[:3, 3])[2] for T in Ts])
    np.testing.assert_allclose(triangulate(Ts, x), X, atol=1e-6)
    with pytest.raises(ValueError, match="views"):
        triangulate(Ts[:1], x[:1])


def test_root_sift_is_unit_length_and_features_are_in_full_size_pixels():
    d = root_sift(np.random.default_rng(1).uniform(0, 200, (7, 128)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, rtol=1e-5)
    # a blob drawn at a known place is found there, in the frame's own pixels, at half size too
    img = np.full((360, 640), 200, np.uint8)
    cv2.circle(img, (400, 100), 12, 30, -1, cv2.LINE_AA)
    xy, desc = image_features(img)
    assert len(xy) >= 1 and desc.shape == (len(xy), 128)
    assert np.min(np.linalg.norm(xy - [400, 100], axis=1)) < 1.5
    with pytest.raises(ValueError, match="uint8"):
        image_features(img.astype(float))


def _synthetic_map(rng, n=400):
    pts = rng.uniform([-1500, -800, 1500], [1500, 800, 3500], (n, 3))
    desc = root_sift(rng.uniform(0, 1, (n, 128)) ** 4)
    return pts, desc


def test_matches_keep_a_point_seen_twice_and_drop_ambiguous_descriptors():
    rng = np.random.default_rng(2)
    pts, desc = _synthetic_map(rng)
    # each point twice (two views of it, nearly equal descriptors): the ratio test must compare
    # with the nearest descriptor of ANOTHER point, or every match would fail it
    def view():
        return root_sift(desc**2 * (1 + 0.02 * rng.uniform(size=desc.shape)))
    fmap = FeatureMap(pts, np.vstack([view(), view()]), np.r_[np.arange(len(pts)), np.arange(len(pts))])
    loc = FeatureLocalizer(fmap, CAM)
    q, p = loc.matches(view()[:50])                                 # a third view of each
    assert len(q) >= 45 and np.all(p == q)
    # a query halfway between two points' descriptors is ambiguous: not matched
    mid = root_sift(((desc[0] ** 2 + desc[1] ** 2) / 2)[None])
    assert len(loc.matches(mid)[0]) == 0
    with pytest.raises(ValueError, match="point_of"):
        FeatureMap(pts, desc, np.full(len(desc), len(pts)))


def test_pose_from_matches_with_outliers_is_the_true_one_with_a_covariance():
    rng = np.random.default_rng(3)
    pts, desc = _synthetic_map(rng)
    loc = FeatureLocalizer(FeatureMap(pts, desc, np.arange(len(pts))), CAM)
    T_cw = _pose(rng)
    x = (pts @ T_cw[:3, :3].T + T_cw[:3, 3])
    px = x[:, :2] / x[:, 2:] * 640 + [639.5, 359.5] + rng.normal(0, 0.5, (len(pts), 2))
    px[:60] = rng.uniform([0, 0], [1280, 720], (60, 2))                 # 15 % wrong matches
    res = loc.pose(px, pts)
    assert res.ok and res.n_points >= 330
    T_wc = invert(T_cw)
    assert rotation_angle_deg(res.T_world_from_cam[:3, :3], T_wc[:3, :3]) < 0.05
    err = np.linalg.norm(res.T_world_from_cam[:3, 3] - T_wc[:3, 3])
    sd = np.sqrt(np.trace(res.covariance[3:, 3:]))
    assert err < 5 and 0 < sd < 10 and err < 5 * sd
    few = loc.pose(px[100:120], pts[100:120])
    assert not few.ok and "need 30" in few.reason


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A 6 s rendered survey of the lab room and a markerless map of it (30 frames), placed in
    the room's world by its marker map."""
    root = tmp_path_factory.mktemp("survey")
    sess = root / "survey"
    simulate_scenario({"base": "survey", "duration_s": 6.0}, sess, seed=4)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["map", "--markerless", str(sess / "scene.mp4"), "--camera", str(sess / "truth" / "camera.json"),
                     "--markers", str(sess / "markers.json"), "--max-frames", "30", "-o", str(root / "sfm")])
    assert code == 0
    return sess, root / "sfm", printed.getvalue()


def _truth(sess) -> dict:
    """{frame: T_world_from_cam} of the simulator's true head poses."""
    _, frame, T, _ = read_poses_csv(sess / "truth" / "head_poses.csv")
    return dict(zip(frame.tolist(), T, strict=True))


def test_a_markerless_map_of_a_rendered_survey_localises_its_frames_within_a_few_mm(survey):
    sess, sfm, out = survey
    assert "points from" in out and "world and scale from markers" in out
    fmap, meta = load_sfm_map(sfm)
    assert meta["views"]["registered"] >= 27 and meta["points"] > 500
    assert meta["scaled_by"]["kind"] == "marker_map" and meta["scaled_by"]["residual_mm"] < 5, meta["scaled_by"]
    assert (sfm / "colmap" / "points3D.bin").is_file() and (sfm / "sfm_top_view.png").is_file()
    assert not (sfm / "images").exists() and not (sfm / "database.db").exists()
    # the survey's views in the world, against the truth (the map's scale and world from markers)
    truth = _truth(sess)
    for view in meta["survey"][::5]:
        T, Tt = np.array(view["T_world_from_cam"]), truth[int(view["name"].split("#")[1])]
        assert rotation_angle_deg(T[:3, :3], Tt[:3, :3]) < 0.3
        assert np.linalg.norm(T[:3, 3] - Tt[:3, 3]) < 10
    # frames between the survey's, localised (what track --map and process --map do)
    poses = track_video(sess / "scene.mp4", load_camera(sess / "truth" / "camera.json"), fmap, every=7)
    ok = np.asarray(poses.columns["status"]) == "ok"
    assert ok[poses.frame % 7 == 0].mean() > 0.9                 # the frames localised (the rest interpolated)
    rot = [rotation_angle_deg(T[:3, :3], truth[k][:3, :3]) for T, k in zip(poses.T_world_from_cam[ok],
                                                                            poses.frame[ok], strict=True)]
    pos = [np.linalg.norm(T[:3, 3] - truth[k][:3, 3]) for T, k in zip(poses.T_world_from_cam[ok], poses.frame[ok],
                                                                      strict=True)]
    assert np.median(rot) < 0.2 and np.median(pos) < 8, (np.median(rot), np.median(pos))


def test_a_markerless_map_records_its_markers_and_the_truth_is_moved_into_its_world(survey, tmp_path):
    """sfm_map.json records the corners of the markers that placed the map (``scaled_by.corners_mm``):
    ``process --map`` moves a simulated truth into the map's world through them. Placed by the
    room's true map: nothing to move; placed by one marker (its frame the world), or a map of
    before (no corners: its origin marker's square): the truth moved by that marker's inverse pose."""
    from types import SimpleNamespace

    from tracking.markermap import square_corners
    from wearable_gaze.formats.markermap import load_marker_map
    from wearable_gaze.pipeline.process.options import truth_frame

    sess, sfm, _ = survey
    meta = json.loads((sfm / "sfm_map.json").read_text())
    true_map = load_marker_map(sess / "markers.json")
    corners = meta["scaled_by"]["corners_mm"]
    assert sorted(int(i) for i in corners) == meta["scaled_by"]["markers"]
    for i, c in corners.items():
        np.testing.assert_allclose(c, true_map.corners(int(i)), atol=1e-6)
    f = SimpleNamespace(truth_targets=sess / "truth" / "targets.json", truth_map=sess / "truth" / "markers.json",
                        truth_moved=None, markers=None)
    assert truth_frame(f, SimpleNamespace(map_kind="markerless", sfm_map=sfm), None, None) is None
    o = meta["scaled_by"]["markers"][0]
    for scaled_by in ({"kind": "marker", "markers": [o], "size_mm": true_map.size_of(o),
                       "corners_mm": {str(o): square_corners(true_map.size_of(o)).tolist()}},
                      {"kind": "marker", "markers": [o], "size_mm": true_map.size_of(o)}):
        shutil.copytree(sfm, tmp_path / "sfm", dirs_exist_ok=True)
        (tmp_path / "sfm" / "sfm_map.json").write_text(json.dumps(meta | {"scaled_by": scaled_by}))
        frame = truth_frame(f, SimpleNamespace(map_kind="markerless", sfm_map=tmp_path / "sfm"), None, None)
        np.testing.assert_allclose(frame.T_map_from_truth, invert(true_map.poses[o]), atol=1e-6)
        assert frame.markers == (o,) and frame.rms_mm < 1e-6 and "the markerless map (--map)" in frame.note()
    (tmp_path / "sfm" / "sfm_map.json").write_text(json.dumps(meta | {"scaled_by": {"kind": "distance"}}))
    frame = truth_frame(f, SimpleNamespace(map_kind="markerless", sfm_map=tmp_path / "sfm"), None, None)
    assert frame.T_map_from_truth is None and "not compared" in frame.note()


def test_a_distance_walked_scales_a_map_without_markers(survey, tmp_path, capsys):
    sess, _, _ = survey
    truth = _truth(sess)
    t_a, t_b = 0.5, 5.0                                            # frames 15 and 150 at 30 fps
    mm = float(np.linalg.norm(truth[150][:3, 3] - truth[15][:3, 3]))
    sfm = tmp_path / "sfm"
    assert main(["map", "--markerless", str(sess / "scene.mp4"), "--camera", str(sess / "truth" / "camera.json"),
                 "--distance", f"{t_a},{t_b},{mm:.3f}", "--max-frames", "30", "-o", str(sfm)]) == 0
    assert "scale from" in capsys.readouterr().out
    fmap, meta = load_sfm_map(sfm)
    assert meta["scaled_by"]["kind"] == "distance"
    # the survey path has the true scale: its views' distances from the first as the truth's
    views = {int(v["name"].split("#")[1]): np.array(v["T_world_from_cam"]) for v in meta["survey"]}
    k0 = min(views)
    got = [np.linalg.norm(T[:3, 3] - views[k0][:3, 3]) for k, T in views.items() if k != k0]
    want = [np.linalg.norm(truth[k][:3, 3] - truth[k0][:3, 3]) for k in views if k != k0]
    assert np.median(np.array(got) / want) == pytest.approx(1, abs=0.01)
    # the world is the camera's frame at t_a
    T_a = np.linalg.inv(truth[15]) @ truth[k0]                  # the first view, seen from the camera at t_a
    assert np.linalg.norm(views[k0][:3, 3] - T_a[:3, 3]) < 5
    assert rotation_angle_deg(views[k0][:3, :3], T_a[:3, :3]) < 0.3


def test_track_with_a_markerless_map_writes_poses(survey, tmp_path, capsys):
    sess, sfm, _ = survey
    out = tmp_path / "poses.csv"
    assert main(["track", str(sess / "scene.mp4"), "--camera", str(sess / "truth" / "camera.json"),
                 "--map", str(sfm), "-o", str(out)]) == 0
    assert "frames with a pose" in capsys.readouterr().out
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 180 and sum(r["status"] == "ok" for r in rows) > 150


def test_markerless_map_prints_lines_while_pycolmap_matches(survey, tmp_path, monkeypatch):
    """pycolmap's exhaustive matching is one call, and ``map --markerless`` printed nothing in a
    log (stderr not a terminal) while it ran (144 s in all for 150 frames). Made slow here (1 s,
    then stopped), it prints a line naming it at least every interval (0.2 s)."""
    import sys

    import pycolmap

    class Stop(Exception):                         # an internal error: the command ends there
        pass

    slow_down(monkeypatch, pycolmap, "match_exhaustive", raises=Stop)
    monkeypatch.setenv("WEARABLE_GAZE_PROGRESS_S", "0.2")
    log = TimedLog()
    monkeypatch.setattr(sys, "stderr", log)
    sess = survey[0]
    assert main(["map", "--markerless", str(sess / "scene.mp4"), "--camera", str(sess / "truth" / "camera.json"),
                 "--markers", str(sess / "markers.json"), "--max-frames", "8", "-o", str(tmp_path / "sfm")]) != 0
    lines = log.getvalue().splitlines()
    matching = [t for t, ln in zip(log.times, lines, strict=True) if ln.startswith("markerless map: matching: ")]
    assert len(matching) >= 4 and np.diff(matching).max() < 0.35, lines
    assert not (tmp_path / "sfm").exists()


def test_markerless_bad_inputs_are_one_line(survey, tmp_path, capsys):
    sess, sfm, _ = survey
    cam = str(sess / "truth" / "camera.json")
    cases = [
        (["map", "--markerless", str(sess / "scene.mp4"), "--camera", cam, "-o", str(tmp_path / "a")],
         "--origin-marker ID --size-mm MM"),
        (["map", "--markerless", str(sess / "scene.mp4"), "--camera", cam, "--distance", "1,2,300", "--markers",
          str(sess / "markers.json"), "-o", str(tmp_path / "a")], "one of --origin-marker"),
        (["map", "--markerless", str(sess / "scene.mp4"), "--camera", cam, "--distance", "1,1,300", "-o",
          str(tmp_path / "a")], "two different times"),
        (["map", "--markerless", str(sess / "scene.mp4"), "--camera", cam, "--distance", "1,99,300", "--max-frames",
          "5", "-o", str(tmp_path / "a")], "no frame at 99 s"),
        (["map", str(sess / "scene.mp4"), "--camera", cam, "--distance", "1,2,300", "--size-mm", "150", "-o",
          str(tmp_path / "m.json")], "are for --markerless"),
        (["map", "--markerless", str(sess / "scene.mp4"), "--camera", cam, "--markers", str(sess / "markers.json"),
          "-o", str(sfm)], "already exists and is not empty"),
        (["map", "--markerless", str(sess / "scene.mp4"), "--camera", cam, "--origin-marker", "99", "--size-mm",
          "150", "--max-frames", "5", "-o", str(tmp_path / "b")], "marker 99"),
        (["track", str(sess / "scene.mp4"), "--camera", cam, "--map", str(tmp_path), "-o", str(tmp_path / "p.csv")],
         "not a markerless map folder"),
        (["process", str(sess), "--map", str(tmp_path), "-o", str(tmp_path / "out")], "not a markerless map folder"),
    ]
    for argv, needle in cases:
        try:
            code = main(argv)
        except SystemExit as exc:                                   # argparse's own refusal (a bad option value)
            code = exc.code
        assert code == 2, argv
        err = capsys.readouterr().err.strip()
        assert needle in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "b").exists() and not (tmp_path / "out" / "poses.csv").exists()
    # a features file that does not belong to its JSON is refused, not used
    bad = tmp_path / "bad"
    bad.mkdir()
    meta = json.loads((sfm / "sfm_map.json").read_text())
    (bad / "sfm_map.json").write_text(json.dumps({**meta, "points": meta["points"] + 1}))
    (bad / "features.npz").write_bytes((sfm / "features.npz").read_bytes())
    assert main(["track", str(sess / "scene.mp4"), "--camera", cam, "--map", str(bad), "-o",
                 str(tmp_path / "p.csv")]) == 2
    assert "different maps" in capsys.readouterr().err


def test_a_map_placed_loosely_by_its_markers_says_so():
    """The terminal report of a markerless map placed by several markers whose corners fit their
    places by more than ``LOOSE_PLACEMENT_MM`` says so and what to do; a tight fit, one marker
    or a distance does not."""
    from types import SimpleNamespace

    from wearable_gaze.pipeline.maps.sfm import LOOSE_PLACEMENT_MM, SfmBuild, format_sfm_report

    fmap = SimpleNamespace(points_world=np.zeros((10, 3)))

    def report(markers, residual):
        scaled = {"kind": "marker_map", "markers": markers, "views": {}, "residual_mm": residual}
        return "\n".join(format_sfm_report(SfmBuild(fmap, 40, 40, 0.7, scaled, {})))
    assert "loosely (21.8 mm RMS)" in report([0, 1, 2], 21.8) and "--origin-marker" in report([0, 1, 2], 21.8)
    assert "loosely" not in report([0, 1, 2], LOOSE_PLACEMENT_MM * 0.8)
    assert "loosely" not in report([0], 21.8)                       # one marker fits itself: nothing to judge
