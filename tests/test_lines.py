import numpy as np
import pytest

from estimator import BinocularSamples, ViewLines
from estimator.frames import invert, transform_points
from estimator.lines import calibration_plane_points, view_lines_in_camera, view_lines_to_camera, view_lines_to_world
from tests.helpers import random_transform

K = np.array([[800.0, 0, 640], [0, 810.0, 360], [0, 0, 1]])


def test_calibration_plane_points_lie_on_the_wall_and_project_back(rng):
    px = rng.uniform([0, 0], [1280, 720], size=(20, 2))
    p = calibration_plane_points(px, K, 1500.0)
    assert np.allclose(p[:, 2], 1500.0)
    back = (K @ (p / p[:, 2:3]).T).T[:, :2]
    assert np.allclose(back, px, atol=1e-9)


def test_calibration_plane_rejects_bad_input():
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        calibration_plane_points(np.zeros((3, 3)), K, 1000)
    with pytest.raises(ValueError, match="positive"):
        calibration_plane_points(np.zeros((3, 2)), K, -1)


def test_view_line_passes_through_gazed_point_and_eye():
    eye = np.array([-32.5, 10.0, -20.0])
    p = np.array([[100.0, -50.0, 1000.0], [0.0, 0.0, 2000.0]])
    lines = view_lines_in_camera(p, eye)
    assert lines.frame == "cam"
    dist = np.linalg.norm(p - eye, axis=1)
    assert np.allclose(lines.point_at(dist), p)
    assert np.allclose(np.linalg.norm(lines.directions, axis=1), 1.0)


def test_world_camera_round_trip_matches_paper_eq_5_to_8(rng):
    T_cam_from_world = random_transform(rng)
    eye = np.array([32.5, 0.0, 0.0])
    p_cam = rng.uniform([-500, -300, 800], [500, 300, 3000], size=(10, 3))
    lines_cam = view_lines_in_camera(p_cam, eye)
    world = view_lines_to_world(lines_cam, T_cam_from_world)
    # eq. 7: e_g = R^-1 (e_c - T); the gazed points map the same way
    R, t = T_cam_from_world[:3, :3], T_cam_from_world[:3, 3]
    assert np.allclose(world.origins_mm, (R.T @ (eye - t))[None])
    p_world = transform_points(invert(T_cam_from_world), p_cam)
    dist = np.linalg.norm(p_cam - eye, axis=1)
    assert np.allclose(world.point_at(dist), p_world, atol=1e-9)
    back = view_lines_to_camera(world, T_cam_from_world)
    assert np.allclose(back.origins_mm, lines_cam.origins_mm)
    assert np.allclose(back.directions, lines_cam.directions)


def test_per_line_poses(rng):
    Ts = np.stack([random_transform(rng) for _ in range(4)])
    lines = view_lines_in_camera(rng.uniform(500, 1500, size=(4, 3)), [0, 0, 0])
    world = view_lines_to_world(lines, Ts)
    for i in range(4):
        one = view_lines_to_world(ViewLines(lines.origins_mm[[i]], lines.directions[[i]], "cam"), Ts[i])
        assert np.allclose(world.directions[i], one.directions[0])


def test_frame_mismatch_is_refused(rng):
    lines = ViewLines(np.zeros((1, 3)), [[0, 0, 1.0]], "world")
    with pytest.raises(ValueError, match="frame 'cam'"):
        view_lines_to_world(lines, np.eye(4))


def test_zero_direction_names_its_row():
    with pytest.raises(ValueError, match=r"directions\[1\]"):
        ViewLines(np.zeros((2, 3)), [[0, 0, 1.0], [0, 0, 0]])


def test_binocular_samples_monocular_rows_and_lines():
    nan = np.full(3, np.nan)
    lo = np.array([[0, 0, 0.0], nan, [0, 0, 0.0]])
    ld = np.array([[0, 0, 2.0], nan, [0, 0, 1.0]])
    ro = np.array([[65, 0, 0.0], [65, 0, 0.0], nan])
    rd = np.array([[0, 0, 1.0], [0, 1, 1.0], nan])
    s = BinocularSamples.from_arrays([0, 1, 2], lo, ld, ro, rd)
    assert s.left_valid.tolist() == [True, False, True]
    assert s.right_valid.tolist() == [True, True, False]
    assert s.binocular.tolist() == [True, False, False]
    lines = s.lines()
    assert len(lines) == 4
    assert lines.sample_index.tolist() == [0, 0, 1, 2]
    assert np.allclose(lines.directions[0], [0, 0, 1])
    one = s.sample(1)
    assert one.left_origin_mm is None and one.right_direction is not None


def test_view_lines_to_world_takes_the_pose_either_way_round(rng):
    """``T_world_from_cam=`` (as tracking gives the pose) gives the lines ``T_cam_from_world``
    gives, one pose or one per line; passing both, or neither, is refused."""
    lines = ViewLines(rng.normal(size=(5, 3)) * 30, rng.normal(size=(5, 3)), "cam")
    Ts = np.stack([random_transform(rng) for _ in range(5)])
    for T_cw in (Ts[0], Ts):
        T_wc = invert(T_cw) if T_cw.ndim == 2 else np.stack([invert(t) for t in T_cw])
        a = view_lines_to_world(lines, T_cw)
        b = view_lines_to_world(lines, T_world_from_cam=T_wc)
        assert np.allclose(a.origins_mm, b.origins_mm, atol=1e-9) and np.allclose(a.directions, b.directions)
    with pytest.raises(ValueError, match="exactly one"):
        view_lines_to_world(lines, Ts[0], T_world_from_cam=invert(Ts[0]))
    with pytest.raises(ValueError, match="exactly one"):
        view_lines_to_world(lines)
