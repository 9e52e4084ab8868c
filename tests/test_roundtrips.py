"""Seeded round trips beside each library's maths (issue 30; as pytransform3d tests its own): a
transform and its inverse, view lines taken to the world and back, the 95 % ellipsoid's scale
against chi-square (exactly and by Monte Carlo), the pose covariance propagated to the world
against Monte Carlo, and undistortion as the inverse of OpenCV's projection. Each fails when the
maths it guards is broken (a transposed rotation, a chi-square with the wrong degrees of freedom,
a sign in a Jacobian)."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from calibration.camera import undistort_points
from estimator.errormodel import K95
from estimator.frames import invert, rotate_directions, rotation_about_axis, similarity_transform, transform_points
from estimator.lines import view_lines_in_camera, view_lines_to_camera, view_lines_to_world
from estimator.result import covariance_ellipsoid
from tracking.pnp import covariance_cam_from_obj, covariance_world_from_cam, transform_from_rvec_tvec


def _random_transform(rng) -> np.ndarray:
    """A rigid ``T_b_from_a`` (4, 4): a random axis, angle up to pi, translation up to 2 m."""
    axis = rng.normal(size=3)
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis(axis / np.linalg.norm(axis), rng.uniform(-np.pi, np.pi))
    T[:3, 3] = rng.uniform(-2000.0, 2000.0, 3)
    return T


def _random_covariance(rng, scales_mm) -> np.ndarray:
    """A (3, 3) covariance, mm^2, with standard deviations ``scales_mm`` along random axes."""
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q @ np.diag(np.asarray(scales_mm, float) ** 2) @ Q.T


# --- estimator: frames ---------------------------------------------------------------------------

def test_a_transform_and_its_inverse_return_every_point_and_direction():
    rng = np.random.default_rng(30)
    for _ in range(50):
        T_b_from_a, T_c_from_b = _random_transform(rng), _random_transform(rng)
        pts_a = rng.uniform(-3000.0, 3000.0, (20, 3))
        dirs_a = rng.normal(size=(20, 3))
        np.testing.assert_allclose(invert(T_b_from_a) @ T_b_from_a, np.eye(4), atol=1e-9)     # mm: 2 m
        np.testing.assert_allclose(T_b_from_a @ invert(T_b_from_a), np.eye(4), atol=1e-9)     # translations
        pts_b = transform_points(T_b_from_a, pts_a)
        np.testing.assert_allclose(transform_points(invert(T_b_from_a), pts_b), pts_a, atol=1e-9)
        # composing left to right is applying right to left
        np.testing.assert_allclose(transform_points(T_c_from_b @ T_b_from_a, pts_a),
                                   transform_points(T_c_from_b, pts_b), atol=1e-9)
        # a direction turns as the difference of two points does, keeps its length, and comes back
        d_b = rotate_directions(T_b_from_a, dirs_a)
        np.testing.assert_allclose(d_b, pts_b - transform_points(T_b_from_a, pts_a - dirs_a), atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(d_b, axis=1), np.linalg.norm(dirs_a, axis=1), rtol=1e-12)
        np.testing.assert_allclose(rotate_directions(invert(T_b_from_a), d_b), dirs_a, atol=1e-12)
        # one transform per point: each point its own
        Ts = np.stack([_random_transform(rng) for _ in range(len(pts_a))])
        one_by_one = np.array([transform_points(T, p)[0] for T, p in zip(Ts, pts_a, strict=True)])
        np.testing.assert_allclose(transform_points(Ts, pts_a), one_by_one, atol=1e-9)


def test_the_fitted_similarity_is_the_planted_one_and_maps_back():
    rng = np.random.default_rng(31)
    for _ in range(20):
        T = _random_transform(rng)
        scale = rng.uniform(0.5, 2.0)
        T[:3, :3] *= scale
        A = rng.uniform(-1000.0, 1000.0, (8, 3))
        B = A @ T[:3, :3].T + T[:3, 3]
        S = similarity_transform(A, B)
        np.testing.assert_allclose(S, T, atol=1e-8)
        np.testing.assert_allclose(np.cbrt(np.linalg.det(S[:3, :3])), scale, rtol=1e-12)
        np.testing.assert_allclose(similarity_transform(B, A) @ S, np.eye(4), atol=1e-8)


def test_view_lines_to_the_world_and_back_keep_every_gazed_point():
    """Eq. 4-8 as a round trip: camera-frame lines from an eye through gazed points, taken to the
    world by a head pose (given either way round, one pose or one per line), pass through the
    gazed points moved by that pose at the same distance, and come back to the camera unchanged
    (issue 30, planted fault ``viewline-direction-transposed``)."""
    rng = np.random.default_rng(36)
    for _ in range(20):
        eye = rng.uniform(-40.0, 40.0, 3)
        p_cam = np.column_stack([rng.uniform(-800.0, 800.0, (15, 2)), rng.uniform(300.0, 5000.0, 15)])
        lines = view_lines_in_camera(p_cam, eye)
        dist = np.linalg.norm(p_cam - eye, axis=1)
        T_world_from_cam = _random_transform(rng)
        Ts = np.stack([_random_transform(rng) for _ in range(len(p_cam))])
        for world, T in ((view_lines_to_world(lines, T_world_from_cam=T_world_from_cam), T_world_from_cam),
                         (view_lines_to_world(lines, invert(T_world_from_cam)), T_world_from_cam),
                         (view_lines_to_world(lines, T_world_from_cam=Ts), Ts)):
            np.testing.assert_allclose(world.point_at(dist), transform_points(T, p_cam), atol=1e-9)
            np.testing.assert_allclose(world.origins_mm, transform_points(T, lines.origins_mm), atol=1e-9)
        back = view_lines_to_camera(view_lines_to_world(lines, T_world_from_cam=T_world_from_cam),
                                    invert(T_world_from_cam))
        np.testing.assert_allclose(back.origins_mm, lines.origins_mm, atol=1e-9)
        np.testing.assert_allclose(back.directions, lines.directions, atol=1e-12)


# --- estimator: the ellipsoid's scale ---------------------------------------------------------------

def test_k95_is_the_square_root_of_chi_square_3_at_95_percent():
    assert K95 ** 2 == pytest.approx(chi2.ppf(0.95, 3), rel=1e-12)
    assert K95 == pytest.approx(2.7954834829151074, rel=1e-12)         # independent of scipy's ppf: its
    assert chi2.cdf(K95 ** 2, 3) == pytest.approx(0.95, abs=1e-12)     # square holds 95 % of chi2(3)


@pytest.mark.parametrize("probability", [0.5, 0.68, 0.95, 0.99])
def test_the_ellipsoid_holds_its_probability_of_its_normal(probability):
    """Its semi-axes squared over the covariance's eigenvalues are chi2(3)'s point at the
    probability; 200 000 draws of the normal fall inside as often (within 5 binomial sds)."""
    rng = np.random.default_rng(32)
    C = _random_covariance(rng, [4.0, 25.0, 300.0])
    c = rng.uniform(-1000.0, 1000.0, 3)
    E = covariance_ellipsoid(c, C, probability)
    np.testing.assert_allclose(E.radii_mm ** 2 / np.linalg.eigvalsh(C), chi2.ppf(probability, 3), rtol=1e-10)
    np.testing.assert_allclose(E.axes @ np.diag(E.radii_mm ** 2) @ E.axes.T / chi2.ppf(probability, 3), C,
                               rtol=1e-9, atol=1e-9)
    n = 200_000
    x = rng.multivariate_normal(c, C, size=n)
    inside = np.mean(np.sum(((x - c) @ E.axes / E.radii_mm) ** 2, axis=1) <= 1.0)
    assert abs(inside - probability) < 5 * np.sqrt(probability * (1 - probability) / n), inside


# --- tracking: the pose covariance -----------------------------------------------------------------

def _pose_vector(T_world_from_cam) -> np.ndarray:
    """(6,): rotation vector (rad) and camera position (mm) of a pose."""
    rvec, _ = cv2.Rodrigues(T_world_from_cam[:3, :3])
    return np.concatenate([rvec.ravel(), T_world_from_cam[:3, 3]])


def test_the_world_pose_covariance_is_the_monte_carlo_one():
    """(rvec, tvec) of ``T_cam_from_obj`` drawn from their covariance and each turned into
    ``T_world_from_cam = T_world_from_obj @ inv(T_cam_from_obj)``: the draws' covariance is the
    first-order propagation's, to 3 % (40 000 draws, small enough noise for the first order)."""
    rng = np.random.default_rng(33)
    rvec, tvec = np.array([0.3, -0.5, 0.2]), np.array([120.0, -80.0, 900.0])
    T_world_from_obj = _random_transform(rng)
    L = np.array([2e-3] * 3 + [1.5] * 3)[:, None] * rng.normal(size=(6, 6))    # rows: rad, mm
    C_cam = L @ L.T / 6
    C_world = covariance_world_from_cam(C_cam, rvec, tvec, T_world_from_obj)
    draws = rng.multivariate_normal(np.concatenate([rvec, tvec]), C_cam, size=40_000)
    R_co = Rotation.from_rotvec(draws[:, :3]).as_matrix()            # scipy's, not OpenCV's Rodrigues
    R_wc = np.einsum("ij,nkj->nik", T_world_from_obj[:3, :3], R_co)  # R_wo R_co^T
    t_wc = -np.einsum("nij,nj->ni", R_wc, draws[:, 3:]) + T_world_from_obj[:3, 3]
    world = np.column_stack([Rotation.from_matrix(R_wc).as_rotvec(), t_wc])
    np.testing.assert_allclose(world[0], _pose_vector(T_world_from_obj @ invert(transform_from_rvec_tvec(
        draws[0, :3], draws[0, 3:]))), atol=1e-9)                     # the same pose as the frames' maths
    mc = np.cov(world.T)
    scale = np.sqrt(np.outer(np.diag(mc), np.diag(mc)))
    np.testing.assert_allclose(C_world / scale, mc / scale, atol=0.03)
    np.testing.assert_allclose(np.diag(C_world), np.diag(mc), rtol=0.03)


def _project(obj, p) -> np.ndarray:
    """(M, N, 2) normalised coordinates of object points (N, 3) mm under M poses (M, 6) (rotation
    vector rad, translation mm of ``T_cam_from_obj``), without OpenCV."""
    X = np.einsum("mij,nj->mni", Rotation.from_rotvec(p[:, :3]).as_matrix(), obj) + p[:, None, 3:]
    return X[..., :2] / X[..., 2:]


def _least_squares_poses(obj, x, p0, iterations: int = 8) -> np.ndarray:
    """(M, 6) poses fitted to M sets of observations ``x`` (M, N, 2) by Gauss-Newton from ``p0``
    (6,), with central-difference Jacobians (independent of OpenCV's)."""
    p = np.repeat(p0[None], len(x), axis=0)
    h = np.array([1e-6] * 3 + [1e-3] * 3)
    for _ in range(iterations):
        r = (_project(obj, p) - x).reshape(len(x), -1)
        J = np.stack([((_project(obj, p + h[k] * np.eye(6)[k]) - _project(obj, p - h[k] * np.eye(6)[k]))
                       .reshape(len(x), -1)) / (2 * h[k]) for k in range(6)], axis=2)
        p = p - np.linalg.solve(np.einsum("mik,mil->mkl", J, J), np.einsum("mik,mi->mk", J, r)[..., None])[..., 0]
    return p


def test_the_pnp_covariance_is_the_monte_carlo_one():
    """Markers' corners seen with Gaussian noise (normalised coordinates, sd ``sigma``) and the
    pose fitted again each time (least squares, to convergence): the fits' covariance is
    ``sigma^2 (J^T J)^-1``, to 8 % (6 000 draws; the variances' sampling sd is 1.8 %)."""
    rng = np.random.default_rng(34)
    obj = np.array([[x, y, z] for x in (-150.0, 0.0, 150.0) for y in (-100.0, 100.0) for z in (0.0, 60.0)])
    rvec, tvec = np.array([0.2, -0.3, 0.1]), np.array([30.0, -20.0, 1200.0])
    x0 = cv2.projectPoints(obj, rvec, tvec, np.eye(3), None)[0].reshape(-1, 2)
    sigma, focal_px = 0.5 / 800.0, 800.0                          # 0.5 px on an 800 px focal length
    noise = rng.normal(size=x0.shape)
    noise *= sigma * np.sqrt((2 * len(obj) - 6) / np.sum(noise ** 2))   # residuals whose sd is sigma exactly
    C = covariance_cam_from_obj(obj, rvec, tvec, noise, focal_px)
    x = x0 + rng.normal(scale=sigma, size=(6000, *x0.shape))
    mc = np.cov(_least_squares_poses(obj, x, np.concatenate([rvec, tvec])).T)
    np.testing.assert_allclose(np.diag(C), np.diag(mc), rtol=0.08)
    scale = np.sqrt(np.outer(np.diag(mc), np.diag(mc)))
    np.testing.assert_allclose(C / scale, mc / scale, atol=0.05)


# --- calibration: undistortion -------------------------------------------------------------------

@pytest.mark.parametrize("model", ["pinhole", "fisheye"])
def test_undistortion_inverts_opencvs_projection(model):
    """Points in front of a camera projected with distortion (OpenCV) and undistorted again land
    on their own normalised coordinates (x/z, y/z), to 1e-9."""
    rng = np.random.default_rng(35)
    K = np.array([[800.0, 0.0, 640.0], [0.0, 790.0, 360.0], [0.0, 0.0, 1.0]])
    pts = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), np.ones(200)]) * rng.uniform(500, 5000, (200, 1))
    if model == "fisheye":
        D = np.array([-0.02, 0.01, -0.004, 0.001])
        px = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    else:
        D = np.array([-0.28, 0.09, 0.001, -0.0005, -0.01])
        px = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    np.testing.assert_allclose(undistort_points(px, K, D, model), pts[:, :2] / pts[:, 2:], atol=1e-9)
