"""The survey scenario (issue 16): a head walking a loop inside the lab room, looking at the walls,
so that every marker of the map is seen many times and from a range of directions. The path is
checked over the whole 60 s without rendering; one short rendered run checks the session it
writes and that OpenCV finds the markers in its video."""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tracking.markers import MarkerDetector
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.session import load_session
from wearable_gaze.sim.motion import make_motion
from wearable_gaze.sim.scenario import resolve
from wearable_gaze.sim.simulate import build_world, make_targets, scene_camera, simulate_scenario

FPS = 30


@pytest.fixture(scope="module")
def survey():
    """The resolved scenario, its world, camera, and the 60 s head path at 30 fps (and 240 Hz)."""
    scn = resolve("survey")
    rng = np.random.default_rng(3)
    world = build_world(scn, rng, make_targets(scn, rng))
    motion = make_motion(scn["head"], scn["duration_s"], rng, lambda t: np.zeros((len(t), 3)))
    t = np.arange(int(scn["duration_s"] * FPS)) / FPS
    return {"scn": scn, "world": world, "camera": scene_camera(scn), "motion": motion, "t": t,
            "T": motion.poses(t)}


def _walls(scn):
    """left x, back z, right x, front z of the room (world.lab_room), and ceiling and floor y."""
    width, height, depth = scn["room"]["size_mm"]
    eye, back = scn["room"]["eye_height_mm"], scn["room"]["back_mm"]
    return -width / 2, -back, width / 2, depth - back, -(height - eye), eye


def test_survey_scenario_is_a_minute_in_the_lab_room_with_24_markers(survey):
    scn = survey["scn"]
    assert scn["name"] == "survey" and scn["duration_s"] == 60 and scn["head"]["motion"] == "survey"
    assert scn["head"]["survey_walls_mm"] == list(_walls(scn)[:4])
    assert sorted(survey["world"].markers) == list(range(24))
    # the lab-walkabout room: a seed gives both the same walls and marker map
    lab = build_world(resolve("lab-walkabout"), np.random.default_rng(5), [])
    same = build_world(scn, np.random.default_rng(5), [])
    assert all(np.array_equal(lab.markers[i], same.markers[i]) for i in range(24))
    # a file may start from it, and a loop that does not fit the room is refused by name
    assert resolve({"base": "survey", "duration_s": 5.0})["head"]["motion"] == "survey"
    with pytest.raises(Exception, match="head.survey_inset_mm"):
        resolve({"base": "survey", "head": {"survey_inset_mm": 2100.0}})


def test_survey_path_is_one_loop_inside_the_room_a_metre_or_more_from_the_walls(survey):
    x0, z0, x1, z1, y_ceil, y_floor = _walls(survey["scn"])
    p = survey["T"][:, :3, 3]
    to_wall = np.column_stack([p[:, 0] - x0, x1 - p[:, 0], p[:, 2] - z0, z1 - p[:, 2]])
    assert to_wall.min() >= 1000                                  # never near, let alone through, a wall
    assert to_wall.min(axis=1).max() <= 2000                      # and never out in the middle
    assert np.all((p[:, 1] > y_ceil + 500) & (p[:, 1] < y_floor - 1000))   # at eye height
    assert np.ptp(p[:, 0]) > 1000 and np.ptp(p[:, 2]) > 1500      # it walks around the room
    # every side of the room is walked along: the nearest wall is each of the four for a while
    nearest = np.bincount(to_wall.argmin(axis=1), minlength=4) / len(p)
    assert nearest.min() > 0.1, nearest
    step = np.linalg.norm(np.diff(p[:, [0, 2]], axis=0), axis=1) * FPS
    assert 50 < np.median(step) < 600                             # a slow walk, mm/s
    end = survey["motion"].poses([survey["scn"]["duration_s"]])[0, :3, 3]
    assert np.linalg.norm(end - p[0]) < 300                       # one loop takes the session


def test_survey_camera_faces_the_walls_it_walks_along(survey):
    """The optical axis meets a wall near by (not the far side of the room), and each of the four
    walls is looked at for a good part of the loop."""
    x0, z0, x1, z1, _, _ = _walls(survey["scn"])
    T = survey["T"]
    p, fx, fz = T[:, :3, 3], T[:, 0, 2], T[:, 2, 2]
    with np.errstate(divide="ignore"):
        tx = np.where(fx > 0, (x1 - p[:, 0]) / fx, (x0 - p[:, 0]) / fx)
        tz = np.where(fz > 0, (z1 - p[:, 2]) / fz, (z0 - p[:, 2]) / fz)
    hit = np.minimum(tx, tz) * np.hypot(fx, fz)                   # horizontal distance to the wall ahead
    assert np.percentile(hit, 95) < 2400 and np.median(hit) < 2000, np.percentile(hit, [50, 95])
    wall = np.where(tx < tz, np.where(fx > 0, 1, 3), np.where(fz > 0, 0, 2))
    assert (np.bincount(wall, minlength=4) / len(wall)).min() > 0.1
    assert np.all(np.abs(T[:, 1, 2]) < np.sin(np.deg2rad(20)))    # level, not at the floor or ceiling


def test_survey_head_turns_smoothly_under_60_deg_per_s(survey):
    t = np.arange(0, survey["scn"]["duration_s"], 1 / 240)
    R = Rotation.from_matrix(survey["motion"].poses(t)[:, :3, :3])
    rate = np.degrees((R[:-1].inv() * R[1:]).magnitude()) * 240
    assert rate.max() < 60, rate.max()
    yaw = np.unwrap(np.arctan2(survey["T"][:, 2, 2], survey["T"][:, 0, 2]))
    assert abs(abs(yaw[-1] - yaw[0]) - 2 * np.pi) < np.deg2rad(45)   # a full turn over the loop


def _views(survey):
    """Per marker id: the (K, 3) unit directions from the camera to the marker's centre in the
    frames where all four of its corners are in the image, in front of the camera."""
    cam, T = survey["camera"], survey["T"]
    w, h = cam.image_size
    corners = survey["world"].marker_corners()
    ids = sorted(corners)
    pts = np.concatenate([corners[i] for i in ids])               # (4 M, 3)
    T_cw = np.linalg.inv(T)
    pc = np.einsum("nij,mj->nmi", T_cw[:, :3, :3], pts) + T_cw[:, None, :3, 3]
    px = cam.project(np.where(pc[..., 2:] > 50, pc, 1.0).reshape(-1, 3)).reshape(len(T), -1, 2)
    ok = (pc[..., 2] > 50) & np.all((px >= 0) & (px < [w, h]), axis=-1)
    ok = ok.reshape(len(T), len(ids), 4).all(axis=-1)
    out = {}
    for k, i in enumerate(ids):
        d = corners[i].mean(axis=0) - T[ok[:, k], :3, 3]
        out[i] = d / np.linalg.norm(d, axis=1, keepdims=True)
    return out


def test_every_marker_is_seen_often_from_a_range_of_directions(survey):
    views = _views(survey)
    assert len(views) == 24
    counts = {i: len(d) for i, d in views.items()}
    assert min(counts.values()) >= 20, counts
    span = {i: np.degrees(np.arccos(np.clip(d @ d.T, -1, 1)).max()) for i, d in views.items()}
    assert min(span.values()) >= 20, span


def test_rendered_survey_session_has_the_map_the_path_and_a_video_with_markers_found(tmp_path):
    root = tmp_path / "survey"
    man = simulate_scenario("survey", root, seed=1, duration_s=3.0, resolution=(640, 360))
    s = load_session(root)
    assert man["files"]["marker_map"] == "markers.json" and man["files"]["scene_video"] == "scene.mp4"
    mm = s.marker_map()
    assert sorted(m["id"] for m in mm["markers"]) == list(range(24))
    t, _, T, extra = read_poses_csv(root / "truth" / "head_poses.csv")
    assert len(t) == man["n_frames"] == 90 and np.all(np.isfinite(T))
    x0, z0, x1, z1 = man["scenario"]["head"]["survey_walls_mm"]
    assert np.all((T[:, 0, 3] > x0 + 1000) & (T[:, 0, 3] < x1 - 1000))
    assert np.all((T[:, 2, 3] > z0 + 1000) & (T[:, 2, 3] < z1 - 1000))
    det = MarkerDetector(mm["dictionary"])
    cap = cv2.VideoCapture(str(s.path("scene_video")))
    found = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        ids = {d.marker_id for d in det.detect(frame[..., 0])}
        assert ids <= set(range(24))                               # no false ids
        found.append(len(ids))
    found = np.array(found)
    assert len(found) == len(t)
    assert np.mean(found >= 2) > 0.8 and np.median(found) >= 3, found
    assert np.all(found <= np.asarray(extra["n_markers"]) + 1)    # what the truth says is in view
    json.loads((root / "session.json").read_text())
