import numpy as np

from estimator import PairStatus, Status, closest_point_two_lines, lse_point, nearest_point_to_lines
from estimator.lines import ViewLines
from tests.helpers import lines_toward


def test_two_lines_meeting_give_the_point_and_zero_gap(rng):
    X = rng.uniform(-500, 500, size=(50, 3)) + [0, 0, 2000]
    o1 = rng.normal(size=(50, 3)) * 50
    o2 = o1 + [65, 0, 0]
    r = closest_point_two_lines(o1, X - o1, o2, X - o2)
    assert np.all(r.status == PairStatus.OK)
    assert np.allclose(r.point_mm, X, atol=1e-6)
    assert np.allclose(r.gap_mm, 0, atol=1e-6)
    assert np.allclose(r.distance1_mm, np.linalg.norm(X - o1, axis=1))


def test_skew_lines_gap_and_midpoint():
    # x axis at z=0 and a line parallel to y at z=10, x=3
    r = closest_point_two_lines([[0, 0, 0]], [[1, 0, 0]], [[3, -5, 10]], [[0, 1, 0]])
    assert np.allclose(r.gap_mm, 10)
    assert np.allclose(r.point_mm, [[3, 0, 5]])


def test_parallel_lines_are_reported_not_nan_silently():
    r = closest_point_two_lines([[0, 0, 0]], [[0, 0, 1]], [[65, 0, 0]], [[0, 0, 1]])
    assert r.status[0] == PairStatus.PARALLEL
    assert np.isnan(r.point_mm).all()
    assert np.isclose(r.gap_mm[0], 65)


def test_diverging_lines_are_behind_and_not_mirrored():
    # eyes at x=+-32.5 looking slightly outward: the lines meet behind the head
    r = closest_point_two_lines([[-32.5, 0, 0]], [[-0.01, 0, 1]], [[32.5, 0, 0]], [[0.01, 0, 1]])
    assert r.status[0] == PairStatus.BEHIND
    assert r.point_mm[0, 2] < 0                   # the true closest point, behind: not mirrored
    assert r.distance1_mm[0] < 0


def test_lse_and_geometric_are_exact_without_noise(rng):
    X = np.array([120.0, -40.0, 2500.0])
    o = rng.normal(size=(40, 3)) * [100, 30, 50]
    lines = lines_toward(X, o)
    for est in (lse_point(lines), nearest_point_to_lines(lines)):
        assert est.ok
        assert np.allclose(est.position_mm, X, atol=1e-6)


def test_lse_degenerate_and_insufficient():
    par = ViewLines(np.array([[0, 0, 0.0], [65, 0, 0]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    assert lse_point(par).status is Status.DEGENERATE
    assert nearest_point_to_lines(par).status is Status.DEGENERATE
    one = ViewLines(np.zeros((1, 3)), [[0, 0, 1.0]])
    r = lse_point(one)
    assert r.status is Status.INSUFFICIENT and r.position_mm is None and "at least 2" in r.reason


def test_lse_is_biased_toward_the_head_at_depth(rng):
    """The paper's LSE column: errors-in-variables bias pulls the estimate toward the eyes."""
    from wearable_gaze.sim.protocol import simulate_lines

    z = []
    for _ in range(20):
        s = simulate_lines([0, 0, 3000.0], rng)
        z.append(lse_point(s.lines()).position_mm[2])
    assert np.mean(z) < 0.6 * 3000          # NOTES: about 1.34 m for 3 m
    assert np.mean(z) > 0.3 * 3000
