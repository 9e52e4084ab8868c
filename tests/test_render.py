"""The renderer's geometry against projection of the ground truth (issue 3, first part).

OpenCV's sub-pixel refinement is itself biased inward on the L-shaped corners of a marker
(measured below on analytically area-sampled squares), so the renderer is held to what an ideal
area-sampled image gives with the same detector, and to no systematic offset; with the
edge-line refinement of ``tracking.corners`` the corners match the ground truth to < 0.1 px.
"""

import cv2
import numpy as np
import pytest

from calibration.camera import aruco_dictionary
from tests.helpers import rendered_marker_scene
from wearable_gaze.sim.camera import Camera
from wearable_gaze.sim.noise import finish
from wearable_gaze.sim.planes import Plane
from wearable_gaze.sim.render import render


def _detector():
    det = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_4X4_50"), cv2.aruco.DetectorParameters())
    p = det.getDetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    p.cornerRefinementMinAccuracy = 0.001
    p.cornerRefinementMaxIterations = 100
    det.setDetectorParameters(p)
    return det


def _ideal_errors(det, rng, n=12):
    """Detection errors on exactly area-sampled markers (drawn at 16x, box-downsampled)."""
    d = aruco_dictionary("DICT_4X4_50")
    mk = cv2.aruco.generateImageMarker(d, 3, 300, borderBits=1)
    S, errs = 16, []
    for _ in range(n):
        side, ang, c = rng.uniform(40, 90), rng.uniform(0, 2 * np.pi), rng.uniform(150, 250, 2)
        R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        dst = (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * side / 2) @ R.T + c
        # the marker image's outer edge lies half a pixel outside its border pixel centres
        H = cv2.getPerspectiveTransform(np.float32([[-0.5, -0.5], [299.5, -0.5], [299.5, 299.5], [-0.5, 299.5]]),
                                        (S * (dst + 0.5) - 0.5).astype(np.float32))
        big = cv2.warpPerspective(mk, H, (400 * S, 400 * S), flags=cv2.INTER_NEAREST, borderValue=255)
        img = cv2.resize(big, (400, 400), interpolation=cv2.INTER_AREA)
        cc, ids, _ = det.detectMarkers(img)
        e = cc[0].reshape(4, 2) - dst
        errs.append(np.linalg.norm(e, axis=1))
    return np.concatenate(errs)


@pytest.fixture(scope="module")
def scenes():
    rng = np.random.default_rng(0)
    return [rendered_marker_scene(rng) for _ in range(8)]


def test_rendered_marker_corners_match_projected_ground_truth(scenes):
    det = _detector()
    errs, offsets = [], []
    for img, truth in scenes:
        corners, ids, _ = det.detectMarkers(img)
        assert ids is not None
        for c, i in zip(corners, ids.ravel(), strict=True):
            e = c.reshape(4, 2) - truth[int(i)]
            errs.append(np.linalg.norm(e, axis=1))
            offsets.append(e)
    errs = np.concatenate(errs)
    offsets = np.concatenate(offsets)
    assert len(errs) >= 0.8 * 4 * 4 * len(scenes)            # markers in view are found
    assert np.all(np.abs(offsets.mean(axis=0)) < 0.05)      # no systematic shift of the image
    ideal = _ideal_errors(det, np.random.default_rng(1))
    assert np.median(errs) < np.median(ideal) + 0.05        # as good as ideal area sampling
    assert np.percentile(errs, 95) < 0.6


def test_occlusion_nearest_plane_wins():
    cam = Camera.wide_scene_camera(width=320, height=180)
    near = np.eye(4)
    near[:3, 3] = [-500, -500, 1000]
    far = np.eye(4)
    far[:3, 3] = [-2000, -2000, 3000]
    white = np.full((8, 8), 250, np.uint8)
    black = np.zeros((8, 8), np.uint8)
    img = render(cam, np.eye(4), [Plane(near, (1000, 1000), black), Plane(far, (4000, 4000), white)])
    img2 = render(cam, np.eye(4), [Plane(far, (4000, 4000), white), Plane(near, (1000, 1000), black)])
    c = (90, 160)
    assert img[c] < 5 and img2[c] < 5                        # the near black plane hides the far one
    assert img[90, 80] > 240 and img2[90, 240] > 240          # the far plane shows beside it


def test_finish_is_seeded_and_clipped():
    img = np.full((10, 10), 254.0, np.float32)
    a = finish(img, np.random.default_rng(3), noise_std=5.0)
    b = finish(img, np.random.default_rng(3), noise_std=5.0)
    assert a.dtype == np.uint8 and np.array_equal(a, b) and a.max() == 255


def test_edge_line_refinement_is_unbiased_on_ideal_squares():
    """tracking.corners on exactly area-sampled markers: the detector's inward bias is gone."""
    from tracking.corners import refine_marker_corners

    det = _detector()
    d = aruco_dictionary("DICT_4X4_50")
    mk = cv2.aruco.generateImageMarker(d, 3, 300, borderBits=1)
    rng = np.random.default_rng(2)
    raw, refined = [], []
    for _ in range(10):
        side, ang, c = rng.uniform(40, 90), rng.uniform(0, 2 * np.pi), rng.uniform(150, 250, 2)
        R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        dst = (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * side / 2) @ R.T + c
        H = cv2.getPerspectiveTransform(np.float32([[-0.5, -0.5], [299.5, -0.5], [299.5, 299.5], [-0.5, 299.5]]),
                                        (16 * (dst + 0.5) - 0.5).astype(np.float32))
        big = cv2.warpPerspective(mk, H, (6400, 6400), flags=cv2.INTER_NEAREST, borderValue=255)
        img = cv2.resize(big, (400, 400), interpolation=cv2.INTER_AREA)
        cc, ids, _ = det.detectMarkers(img)
        # the detector's corners come back in the marker's own order: match them to dst
        got = cc[0].reshape(4, 2)
        order = [int(np.argmin(np.linalg.norm(dst - g, axis=1))) for g in got]
        truth = dst[order]
        raw.append(np.linalg.norm(got - truth, axis=1))
        refined.append(np.linalg.norm(refine_marker_corners(img, got, 6) - truth, axis=1))
    assert np.median(np.concatenate(refined)) < 0.05
    assert np.median(np.concatenate(refined)) < 0.5 * np.median(np.concatenate(raw))


def test_rendered_corners_within_a_tenth_of_a_pixel_with_edge_refinement(scenes):
    """Issue 3's criterion: detected corners vs projected ground truth, median < 0.1 px on clean
    frames, with the edge-line refinement of tracking.corners."""
    from tracking.corners import refine_marker_corners

    det = _detector()
    errs = []
    for img, truth in scenes:
        corners, ids, _ = det.detectMarkers(img)
        for c, i in zip(corners, ids.ravel(), strict=True):
            errs.append(np.linalg.norm(refine_marker_corners(img, c.reshape(4, 2), 6) - truth[int(i)], axis=1))
    errs = np.concatenate(errs)
    assert np.median(errs) < 0.1
    assert np.percentile(errs, 95) < 0.3


def test_edges_land_in_place_on_deep_pyramid_levels_of_odd_sized_textures():
    """A 100-px texture's level 3 is 13 px wide, not 12.5: sampling must use 2^k, not W / width."""
    cam = Camera.wide_scene_camera(width=320, height=180, dist=(0, 0, 0, 0, 0))
    tex = np.zeros((100, 100), np.uint8)
    tex[:, 50:] = 240                                       # edge at the plane's middle
    T = np.eye(4)
    T[:3, 3] = [-100.0, -100.0, 6000.0]                     # 200 mm square, about 5 px wide
    plane = Plane(T, (200.0, 200.0), tex)
    img = render(cam, np.eye(4), [plane], background=120.0)
    assert plane.level(5)[1] >= 3                           # deep levels were built and used
    row = img[int(round(cam.project([[0.0, 0.0, 6000.0]])[0, 1]))]
    edge_x = cam.project([[0.0, 0.0, 6000.0]])[0, 0]        # projected x of the texture's edge
    x = np.arange(len(row))
    lo, hi = int(edge_x) - 2, int(edge_x) + 3
    seg = row[lo:hi]
    j = np.nonzero(seg >= 120.0)[0][0]                      # 50 % crossing between 0 and 240
    crossing = x[lo + j - 1] + (120.0 - seg[j - 1]) / (seg[j] - seg[j - 1])
    assert abs(crossing - edge_x) < 0.15
