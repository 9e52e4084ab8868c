"""The error model behind the covariances of ``ml`` and ``voxel`` (estimator.errormodel)."""

import numpy as np
import pytest
from helpers import walkabout_samples
from scipy.stats import chi2

from estimator import BinocularSamples, MLConfig, ViewLines, ml_point, run_estimator
from estimator.errormodel import (
    DEFAULT_BIAS_DEG,
    ErrorModel,
    bias_from_calibration,
    eye_labels,
    model_covariance,
)
from estimator.frames import tangent_basis

X = np.array([200.0, -100.0, 2000.0])


def _biased(samples: BinocularSamples, beta_rad) -> BinocularSamples:
    """The samples with each eye's directions turned by its 2D angle ``beta_rad[eye]`` (2, 2) in a
    basis fixed to that eye's mean direction."""
    dirs = []
    for k, d in enumerate((samples.left_direction, samples.right_direction)):
        m = d.mean(axis=0)
        c1, c2 = tangent_basis((m / np.linalg.norm(m))[None])
        dirs.append(d + beta_rad[k, 0] * c1 + beta_rad[k, 1] * c2)
    return BinocularSamples.from_arrays(samples.t_s, samples.left_origin_mm, dirs[0], samples.right_origin_mm, dirs[1])


def test_without_bias_or_excess_noise_it_is_the_inverse_fisher_information(rng):
    lines = walkabout_samples(X, rng, n=300).lines()
    plain = ml_point(lines)
    modeled = ml_point(lines, MLConfig(error_model=ErrorModel(bias_deg=0.0, far_side_k=0.0)))
    assert np.allclose(modeled.position_mm, plain.position_mm)
    assert np.allclose(modeled.covariance_mm2, plain.covariance_mm2, rtol=1e-6)
    em = modeled.info["error_model"]
    assert em["inflated"] is False and em["note"] == "" and em["sigma_eye_deg"] == [1.0, 1.0]


def test_over_dispersion_inflates_the_covariance_and_says_so(rng):
    lines = walkabout_samples(X, rng, n=300, sigma_deg=2.0).lines()
    plain = ml_point(lines)
    r = ml_point(lines, MLConfig(error_model=ErrorModel(bias_deg=0.0)))
    em = r.info["error_model"]
    assert em["inflated"] is True and "inflated" in em["note"]
    assert em["sigma_eye_deg"] == pytest.approx([2.0, 2.0], rel=0.1)
    assert np.trace(r.covariance_mm2) / np.trace(plain.covariance_mm2) == pytest.approx(4.0, rel=0.2)


def test_a_per_eye_bias_is_a_floor_that_gives_calibrated_ellipsoids():
    """1 deg noise and a per-eye bias of 0.5 deg per axis that does not average down: the ellipsoids
    of the model (linearised: no far side) hold the truth as often as they say; the noise alone's
    hardly ever."""
    rng = np.random.default_rng(7)
    d_model, d_plain = [], []
    for _ in range(150):
        s = _biased(walkabout_samples(X, rng, n=120), rng.normal(0, np.deg2rad(0.5), (2, 2)))
        for cfg, out in ((MLConfig(error_model=ErrorModel(bias_deg=0.5, far_side_k=0.0)), d_model),
                         (MLConfig(), d_plain)):
            r = ml_point(s.lines(), cfg)
            e = r.position_mm - X
            out.append(e @ np.linalg.solve(r.covariance_mm2, e))
    q95, q68 = chi2.ppf(0.95, 3), chi2.ppf(0.68, 3)
    assert 0.90 <= np.mean(np.array(d_model) <= q95) <= 0.99
    assert 0.58 <= np.mean(np.array(d_model) <= q68) <= 0.78
    assert np.mean(np.array(d_plain) <= q95) < 0.6


def test_voxel_reports_the_same_model_as_ml(rng):
    s = walkabout_samples(X, rng, n=240)
    model = ErrorModel()
    m = ml_point(s.lines(), MLConfig(error_model=model))
    _, v = run_estimator(s, "voxel", error_model=model)
    _, plain = run_estimator(s, "voxel")
    assert v.ok and "error_model" in v.info and "error_model" not in plain.info
    assert np.allclose(v.position_mm, plain.position_mm)                  # the point does not change
    ratio = np.sqrt(np.diag(v.covariance_mm2) / np.diag(m.covariance_mm2))
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    assert np.trace(v.covariance_mm2) > 4 * np.trace(plain.covariance_mm2)     # the floor is there


def test_noise_shared_by_the_eyes_and_over_time_is_found_and_widens_the_ellipsoid(rng):
    """The same noise on both eyes of a sample, slowly varying (a head pose error, smoothed): the
    residuals are correlated between the eyes and over time, and the covariance grows for it."""
    s = walkabout_samples(X, rng, n=300, sigma_deg=0.3)
    n = len(s)
    common = np.zeros((n, 2))
    for i in range(1, n):                       # AR(1), lag-one correlation 0.8, 1 deg std
        common[i] = 0.8 * common[i - 1] + rng.normal(0, np.deg2rad(1.0) * 0.6, 2)
    dirs = []
    for d in (s.left_direction, s.right_direction):
        b1, b2 = tangent_basis(d)
        dirs.append(d + common[:, [0]] * b1 + common[:, [1]] * b2)
    shared = BinocularSamples.from_arrays(s.t_s, s.left_origin_mm, dirs[0], s.right_origin_mm, dirs[1])
    r = ml_point(shared.lines(), MLConfig(error_model=ErrorModel(bias_deg=0.0)))
    off = ml_point(shared.lines(), MLConfig(error_model=ErrorModel(bias_deg=0.0, correlations=False)))
    em = r.info["error_model"]
    assert em["eye_correlation"] > 0.6 and em["time_correlation"] > 0.5 and "correlated in time" in em["note"]
    assert np.trace(r.covariance_mm2) > 3 * np.trace(off.covariance_mm2)


def test_eye_labels_follow_the_samples_and_place_lone_lines(rng):
    s = walkabout_samples(X, rng, n=40)
    lv, rv = np.ones(40, bool), np.ones(40, bool)
    lv[[3, 10, 11]] = False
    rv[[5, 20]] = False
    s = BinocularSamples.from_arrays(s.t_s, s.left_origin_mm, s.left_direction, s.right_origin_mm, s.right_direction,
                                     lv, rv)
    lines = s.lines()
    truth = np.concatenate([np.zeros(lv.sum(), int), np.ones(rv.sum(), int)])
    side = np.concatenate([np.flatnonzero(lv), np.flatnonzero(rv)])
    order = np.argsort(side, kind="stable")
    assert np.array_equal(eye_labels(lines), truth[order])
    # the samples in reverse (each sample still left first): the lone lines are placed by their origins
    rev = np.argsort(-lines.sample_index, kind="stable")
    again = ViewLines(lines.origins_mm[rev], lines.directions[rev], "world", lines.sample_index[rev])
    assert np.array_equal(eye_labels(again), truth[order][rev])


def test_bias_from_the_calibration():
    assert bias_from_calibration([None, None]) == 0.0                   # no fixed slippage: the lines size it
    assert bias_from_calibration([None, None], slip_deg=DEFAULT_BIAS_DEG) == pytest.approx(DEFAULT_BIAS_DEG)
    assert bias_from_calibration([0.4, 0.4], slip_deg=0.0) == pytest.approx(0.4 / np.sqrt(2))
    assert bias_from_calibration([0.3, float("nan")], slip_deg=0.5) == pytest.approx(np.sqrt(0.3**2 / 2 + 0.25))


def test_the_pose_term_widens_the_lateral_extent(rng):
    lines = walkabout_samples(X, rng, n=300).lines()
    base, _ = model_covariance(ml_point(lines).position_mm, lines, np.deg2rad(1.0), ErrorModel(bias_deg=0.0))
    pose, _ = model_covariance(ml_point(lines).position_mm, lines, np.deg2rad(1.0),
                               ErrorModel(bias_deg=0.0, pose_sigma_deg=1.0))
    # a shared 1 deg pose error per sample: the lateral variance (x, y) roughly triples
    assert np.all(np.diag(pose)[:2] > 2.5 * np.diag(base)[:2])


def test_the_head_position_error_over_a_fixation_moves_the_point_as_much(rng):
    lines = walkabout_samples(X, rng, n=300).lines()
    p = ml_point(lines).position_mm
    base = model_covariance(p, lines, np.deg2rad(1.0), ErrorModel(bias_deg=0.2))[1]["linear_cov"]
    moved, info = model_covariance(p, lines, np.deg2rad(1.0), ErrorModel(bias_deg=0.2, pose_position_mm=3.0))
    np.testing.assert_allclose(info["linear_cov"] - base, 9.0 * np.eye(3), atol=1e-6)
    assert info["pose_position_mm"] == 3.0
    with pytest.raises(ValueError, match="pose_position_mm"):
        ErrorModel(pose_position_mm=-1.0)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="bias_correlation"):
        ErrorModel(bias_correlation=1.5)
    with pytest.raises(ValueError, match="bias_deg"):
        ErrorModel(bias_deg=-1)
    with pytest.raises(ValueError, match="error_model"):
        MLConfig(error_model="on")


def test_the_far_side_stretches_depth_to_the_end_of_the_interval_in_inverse_depth():
    """Depth is Gaussian in inverse depth: the depth sd is stretched by 1 / (1 - k r) along the
    line of sight only, so that k sds reach D / (1 - k r)."""
    from estimator.errormodel_regions import far_side

    C = np.diag([4.0, 9.0, 200.0**2])                      # depth along z, 2000 mm away: r = 0.1
    S, f = far_side(C, [0.0, 0.0, 2000.0], [0.0, 0.0, 0.0], 2.8)
    assert f == pytest.approx(1 / (1 - 0.28))
    assert np.sqrt(S[2, 2]) * 2.8 == pytest.approx(2000.0 / (1 - 0.28) - 2000.0)
    np.testing.assert_allclose(S[:2, :2], C[:2, :2])
    assert far_side(C, [0.0, 0.0, 2000.0], [0.0, 0.0, 0.0], 0.0)[1] == 1.0
    assert far_side(np.diag([1.0, 1.0, 1500.0**2]), [0, 0, 2000.0], [0, 0, 0], 2.8)[1] == 10.0   # no far end


def test_far_targets_estimated_too_near_are_held_by_the_far_side():
    """From a head swaying +-40 mm, targets 3-5 m away through a per-eye bias of 0.5 deg per axis
    (many with no far end: depth unresolved): the far side puts the truth in the 95 % ellipsoid
    markedly more often than the linearised covariance, which drops the targets estimated too near
    (their sd, evaluated there, too small). Measured: 88 % against 81 %; the misses left are
    truths beyond the estimate by more than the cone of directions is wide there."""
    from estimator.likelihood import perturb_directions

    rng = np.random.default_rng(11)
    t = np.arange(240) / 60.0
    heads = np.column_stack([40 * np.sin(0.7 * t), 20 * np.sin(1.3 * t + 1), 30 * np.sin(0.4 * t)])   # +-40 mm
    lo, ro = heads - [32.0, 0, 0], heads + [32.0, 0, 0]
    inside = {"far": [], "linear": []}
    for _ in range(150):
        Xt = np.array([rng.uniform(-800, 800), rng.uniform(-300, 300), rng.uniform(3000, 5000)])
        s = BinocularSamples.from_arrays(t, lo, perturb_directions(Xt - lo, np.deg2rad(1.0), rng), ro,
                                         perturb_directions(Xt - ro, np.deg2rad(1.0), rng))
        lines = _biased(s, np.deg2rad(rng.normal(0.0, 0.5, size=(2, 2)))).lines()
        for name, k in (("far", 2.8), ("linear", 0.0)):
            r = ml_point(lines, MLConfig(error_model=ErrorModel(bias_deg=0.5, far_side_k=k)))
            if not r.ok:                    # the biased lines diverge: no point, for either
                continue
            e = r.position_mm - Xt
            inside[name].append(float(e @ np.linalg.solve(r.covariance_mm2, e)) <= chi2.ppf(0.95, 3))
    rate = {k: float(np.mean(v)) for k, v in inside.items()}
    assert rate["far"] >= 0.85 and rate["linear"] < rate["far"] - 0.05, rate


def test_each_level_has_its_own_far_side_and_the_95_percent_one_is_the_covariance():
    """``at_level`` re-draws the far side for a level: the 95 % level is the covariance itself
    (its ellipsoid is ``covariance_mm2``'s), a 68 % region is shorter along the line of sight
    only, by the ratio of the two levels' stretches; the depth interval is D / (1 +- z r)."""
    from estimator.errormodel import FAR_SIDE_K
    from estimator.errormodel_regions import at_level, depth_interval, far_side, sight_info

    C_lin = np.array([[16.0, 0, 0], [0, 25.0, 0], [0, 0, 300.0**2]])      # 2000 mm away: r = 0.15
    point, origin = np.array([0.0, 0.0, 2000.0]), np.zeros(3)
    C95, f95 = far_side(C_lin, point, origin, FAR_SIDE_K)
    s = sight_info(C_lin, point, origin, FAR_SIDE_K)
    assert s["depth_rel_sd"] == pytest.approx(0.15)
    np.testing.assert_allclose(at_level(C95, point, origin, 0.95, FAR_SIDE_K, 0.15), C95, rtol=1e-9)
    C68 = at_level(C95, point, origin, 0.68, FAR_SIDE_K, 0.15)
    k68 = np.sqrt(chi2.ppf(0.68, 3))
    assert np.sqrt(C68[2, 2]) == pytest.approx(300.0 / (1 - k68 * 0.15))
    np.testing.assert_allclose(C68[:2, :2], C_lin[:2, :2])
    near, far = depth_interval(point, origin, 0.68, 0.15)
    z = 0.994457883
    assert (near, far) == (pytest.approx(2000 / (1 + z * 0.15)), pytest.approx(2000 / (1 - z * 0.15)))
    assert depth_interval(point, origin, 0.95, 0.6)[1] == np.inf              # no far end
    np.testing.assert_allclose(at_level(C95, point, origin, 0.68, 0.0, 0.15), C95)   # never stretched


def test_depth_intervals_and_level_regions_hold_their_share_of_the_truths():
    """From a swaying head (+-60 mm), targets 1.5-3 m away seen through 1 deg of noise and a per-eye
    bias of 0.5 deg per axis (relative depth sd about 0.33): the depth intervals, symmetric in
    inverse depth, hold the true distance for their share (68 % and 95 %); the 68 % region drawn
    for its level is shorter along the line of sight than the 68 % ellipsoid of the covariance,
    which is stretched for the 95 % level. Measured: 66 % and 95 % over 299 targets (intervals
    symmetric in depth, D (1 +- z r), hold 79 % and 91 %)."""
    from estimator.likelihood import perturb_directions

    rng = np.random.default_rng(5)
    t = np.arange(120) / 60.0
    heads = np.column_stack([60 * np.sin(1.4 * t), 20 * np.sin(1.3 * t + 1), 30 * np.sin(0.8 * t)])
    lo, ro = heads - [32.0, 0, 0], heads + [32.0, 0, 0]
    inside, shorter = [], []
    for _ in range(300):
        Xt = np.array([rng.uniform(-500, 500), rng.uniform(-300, 300), rng.uniform(1500, 3000)])
        s = BinocularSamples.from_arrays(t, lo, perturb_directions(Xt - lo, np.deg2rad(1.0), rng), ro,
                                         perturb_directions(Xt - ro, np.deg2rad(1.0), rng))
        e = ml_point(_biased(s, np.deg2rad(rng.normal(0.0, 0.5, size=(2, 2)))).lines(),
                     MLConfig(error_model=ErrorModel(bias_deg=0.5)))
        if not e.ok:
            continue
        D = np.linalg.norm(Xt - np.asarray(e.info["error_model"]["sight_origin_mm"]))
        inside.append([e.depth_interval(p)[0] <= D <= e.depth_interval(p)[1] for p in (0.68, 0.95)])
        r68 = e.ellipsoid(0.68).radii_mm.max() / np.sqrt(chi2.ppf(0.68, 3) * np.linalg.eigvalsh(e.covariance_mm2).max())
        shorter.append((r68, e.info["error_model"]["far_side_factor"] < 9.9))
    rate = np.mean(inside, axis=0)
    assert len(inside) >= 290
    assert 0.62 <= rate[0] <= 0.74 and 0.92 <= rate[1] <= 0.98, rate
    ratio, stretched = np.array(shorter).T
    # capped at 95 %: no far end at 68 % either, the same length
    assert np.all(ratio <= 1 + 1e-9) and np.all(ratio[stretched == 1] < 0.99), ratio
