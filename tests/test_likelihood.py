import numpy as np
import pytest
from scipy.stats import chi2

from estimator import MLConfig, Status, cramer_rao_bound, ml_point, perturb_directions
from estimator.frames import tangent_basis
from estimator.likelihood import (
    MAX_TAN2,
    angular_log_likelihood,
    angular_residuals,
    angular_tan2,
    reliability_weights,
)
from estimator.lines import ViewLines
from tests.helpers import lines_toward, walkabout_samples
from wearable_gaze.sim.protocol import simulate_lines


def test_noise_model_has_the_configured_angular_std(rng):
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sig = np.deg2rad(1.0)
    m = perturb_directions(d, sig, rng)
    b1, b2 = tangent_basis(d)
    comp = np.column_stack([(m * b1).sum(1), (m * b2).sum(1)]) / (m * d).sum(1, keepdims=True)
    assert np.allclose(comp.std(axis=0), sig, rtol=0.03)
    assert np.allclose(comp.mean(axis=0), 0, atol=3 * sig / np.sqrt(20000))


def test_crb_matches_the_notes_for_the_paper_protocol():
    """NOTES.md: about 13, 53, 119, 211, 330 mm on Z at 1..5 m."""
    s = simulate_lines([0, 0, 1000.0], np.random.default_rng(0))
    o = s.lines().origins_mm
    expected = {1000: 13, 2000: 53, 3000: 119, 4000: 211, 5000: 330}
    for z, want in expected.items():
        crb = cramer_rao_bound(o, [0, 0, z], 1.0)
        assert abs(np.sqrt(crb[2, 2]) - want) < 1.0


def test_crb_refuses_unidentifiable_geometry():
    with pytest.raises(ValueError, match="cannot fix"):
        cramer_rao_bound(np.zeros((5, 3)), [0, 0, 1000], 1.0)


def test_ml_is_exact_without_noise(rng):
    for target in ([0, 0, 1000.0], [300, -200, 4500.0], [-800, 50, 600.0]):
        s = walkabout_samples(target, rng, sigma_deg=0.0)
        r = ml_point(s.lines())
        assert r.ok and r.info["converged"]
        assert np.allclose(r.position_mm, target, atol=1e-5)
        assert r.info["residual_rms_deg"] < 1e-6


def test_ml_residuals_are_gnomonic(rng):
    o = np.zeros((1, 3))
    lines = ViewLines(o, [[0, 0, 1.0]])
    r = angular_residuals([np.tan(0.01) * 1000, 0, 1000], lines)
    assert np.isclose(np.hypot(*r[0]), np.tan(0.01))
    behind = angular_residuals([0, 0, -1000.0], lines)
    assert np.all(np.isfinite(behind)) and np.hypot(*behind[0]) >= 1e3


def test_angular_log_likelihood_is_the_residuals_norm_with_weights_and_the_behind_bound(rng):
    """The log-likelihood at many points equals -sum w |r|^2 / (2 sigma^2) from the ML fit's gnomonic
    residuals (a separate formula), in all directions around a target and over many lines; a point
    behind an eye costs exactly MAX_TAN2 for that line."""
    X = np.array([150.0, -80.0, 2500.0])
    o = rng.normal(size=(300, 3)) * [200.0, 60.0, 100.0]
    d = perturb_directions(X - o, np.deg2rad(2.0), rng)
    lines = ViewLines(o, d)
    pts = X + rng.normal(size=(50, 3)) * [300.0, 300.0, 900.0]
    w = rng.uniform(0.1, 1.0, size=len(o))
    sigma = np.deg2rad(0.7)
    want = np.array([-0.5 * np.sum(w * np.sum(angular_residuals(p, lines) ** 2, axis=1)) / sigma**2 for p in pts])
    got = angular_log_likelihood(pts, o, d, sigma, weights=w)
    assert got.shape == (50,)
    assert np.allclose(got, want, rtol=1e-9, atol=0)
    assert np.allclose(angular_log_likelihood(pts, o, d, sigma), angular_log_likelihood(pts, o, d, sigma, np.ones(300)))
    # behind the only eye: the bound, and never inf or NaN
    behind = angular_tan2([[0, 0, -1000.0], [0, 0, 1000.0]], [[0, 0, 0.0]], [[0, 0, 1.0]])
    assert behind.shape == (1, 2) and np.isclose(behind[0, 0], MAX_TAN2, rtol=1e-12) and behind[0, 1] == 0.0
    ll = angular_log_likelihood([[0, 0, -1000.0]], [[0, 0, 0.0]], [[0, 0, 1.0]], 1.0)
    assert np.isclose(ll[0], -0.5 * MAX_TAN2, rtol=1e-12)
    with pytest.raises(ValueError, match="as many rows"):
        angular_log_likelihood(pts, o, d[:-1], sigma)


def test_angular_log_likelihood_is_exact_far_from_the_origin():
    """Points and eyes metres from the world origin: the expansion stays exact (reference point
    at the points), tan^2 of 1 degree at 4 m to 1e-9."""
    off = np.array([3.0e6 + 0.3141, -2.0e6 - 0.2718, 1.0e6 + 0.1414])
    o = off + np.array([[0.0, 0.0, 0.0]])
    ang = np.deg2rad([1.0, 2.0])
    X = off + np.column_stack([np.tan(ang) * 4000.0, [0.0, 0.0], [4000.0, 4000.0]])
    t = angular_tan2(X, o, [[0.0, 0.0, 1.0]])
    assert np.allclose(t[0], np.tan(ang) ** 2, rtol=1e-9, atol=0)


def test_ml_degenerate_lines_are_reported():
    par = ViewLines(np.array([[0, 0, 0.0], [65, 0, 0]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    r = ml_point(par)
    assert r.status is Status.DEGENERATE and r.position_mm is None and r.reason


def _ml_trials(target, n_trials, make, seed=0):
    rng = np.random.default_rng(seed)
    est, covs = [], []
    for _ in range(n_trials):
        r = ml_point(make(rng).lines())
        est.append(r.position_mm)
        covs.append(r.covariance_mm2)
    return np.array(est), np.array(covs)


@pytest.mark.parametrize("depth", [1000.0, 3000.0, 5000.0])
def test_ml_rmse_is_near_the_cramer_rao_bound_on_the_paper_protocol(depth):
    X = np.array([0, 0, depth])
    est, covs = _ml_trials(X, 100, lambda g: simulate_lines(X, g))
    o = simulate_lines(X, np.random.default_rng(1)).lines().origins_mm
    crb = np.sqrt(np.trace(cramer_rao_bound(o, X, 1.0)))
    rmse = np.sqrt(np.mean(np.sum((est - X) ** 2, axis=1)))
    assert 0.8 * crb < rmse < 1.2 * crb
    # bias well inside the spread, and the reported covariance is the bound's size
    assert abs(est[:, 2].mean() - depth) < 0.35 * crb
    assert np.median(np.sqrt(np.trace(covs, axis1=1, axis2=2))) == pytest.approx(crb, rel=0.25)


def test_ml_on_a_walkabout_geometry_reaches_the_bound():
    X = np.array([400.0, -150.0, 2500.0])
    est, _ = _ml_trials(X, 80, lambda g: walkabout_samples(X, g), seed=3)
    o = walkabout_samples(X, np.random.default_rng(0), sigma_deg=0).lines().origins_mm
    crb = np.sqrt(np.trace(cramer_rao_bound(o, X, 1.0)))
    rmse = np.sqrt(np.mean(np.sum((est - X) ** 2, axis=1)))
    assert rmse < 1.2 * crb


def test_ml_robust_loss_resists_blinks_and_saccades(rng):
    X = np.array([0, 0, 2000.0])
    s = simulate_lines(X, rng)
    lines = s.lines()
    d = lines.directions.copy()
    bad = np.isin(lines.sample_index, rng.choice(len(s), 20, replace=False))
    d[bad] = perturb_directions(d[bad], np.deg2rad(15), rng)        # 10% of samples: 15 deg off
    corrupted = ViewLines(lines.origins_mm, d, "world", lines.sample_index)
    clean = ml_point(lines).position_mm
    plain = ml_point(corrupted).position_mm
    robust = ml_point(corrupted, MLConfig(loss="mixture"))
    huber = ml_point(corrupted, MLConfig(loss="huber")).position_mm
    assert np.linalg.norm(robust.position_mm - clean) < 0.25 * np.linalg.norm(plain - clean)
    assert np.linalg.norm(huber - clean) < np.linalg.norm(plain - clean)
    assert robust.info["inlier_weight_mean"] == pytest.approx(0.9, abs=0.03)


def test_scalar_reliability_weight_matches_the_vector_one():
    from estimator.likelihood import reliability_weight

    chi2_values = np.array([0.0, 3.0, 30.0, 45.0, 400.0])
    for dof in (2.0, 4.0):
        vec = reliability_weights(chi2_values, dof, np.deg2rad(1), 0.02)
        assert np.allclose([reliability_weight(c, dof, np.deg2rad(1), 0.02) for c in chi2_values], vec)


def test_reliability_weights():
    w = reliability_weights(np.array([0.0, 4.0, 400.0]), 4, np.deg2rad(1), 0.02)
    assert w[0] > 0.999 and w[1] > 0.999 and w[2] < 1e-6
    assert np.all(reliability_weights(np.array([1e6]), 4, 0.01, 0.0) == 1.0)


def test_ellipsoid_radii(rng):
    X = np.array([0, 0, 1500.0])
    r = ml_point(simulate_lines(X, rng).lines())
    ell = r.ellipsoid(0.95)
    w = np.linalg.eigvalsh(r.covariance_mm2)
    assert np.allclose(ell.radii_mm, np.sqrt(w * chi2.ppf(0.95, 3)))
    assert np.allclose(ell.center_mm, r.position_mm)
    d = r.to_dict()
    assert d["status"] == "ok" and len(d["position_mm"]) == 3 and len(d["covariance_mm2"]) == 3


def test_config_validation():
    with pytest.raises(ValueError, match="sigma_deg"):
        MLConfig(sigma_deg=0)
    with pytest.raises(ValueError, match="loss"):
        MLConfig(loss="l1")


def test_lines_toward_helper_is_exact():
    o = np.array([[0, 0, 0.0], [65, 0, 0]])
    lines = lines_toward([10, 0, 1000], o)
    assert np.allclose(lines.point_at(np.linalg.norm([10, 0, 1000] - o, axis=1)), [10, 0, 1000])


def test_run_estimator_logs_the_result_or_the_reason(caplog, rng):
    """One info line per estimate (shown by ``-v``): method, counts, the point or why there is none."""
    import logging

    from estimator import run_estimator

    s = walkabout_samples([0, 0, 2000.0], rng, sigma_deg=0.0)
    with caplog.at_level(logging.INFO, logger="estimator"):
        run_estimator(s, "ml")
        run_estimator(s.select(slice(0, 0)), "ml")
    lines = [r.getMessage() for r in caplog.records if r.name == "estimator.api"]
    assert len(lines) == 2
    assert lines[0].startswith(f"ml: {len(s)} samples, {2 * len(s)} lines: [") and lines[0].endswith("2000.0] mm")
    assert lines[1] == "ml: 0 samples, 0 lines: insufficient-data: needs at least 2 view lines, got 0"
