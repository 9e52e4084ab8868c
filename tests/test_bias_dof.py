"""A bias sized from few combinations of the eyes' angles (issue 27): the session's lines show
the eyes' differences, not their common turn, so the bias they size is known to as many degrees
of freedom as combinations they showed, and the regions are Student's (``ErrorModel.slip_dof``,
``estimator.errormodel_regions``)."""

import math

import numpy as np
from helpers import walkabout_samples
from scipy.stats import chi2
from test_errormodel import X, _biased

from estimator import MLConfig, ml_point
from estimator.errormodel import ErrorModel
from estimator.errormodel_regions import region_radius
from estimator.slippage import SeenBias
from wearable_gaze.formats.targets import record_sight, target_record
from wearable_gaze.pipeline.steps.errorbudget import BiasPrior, session_bias, with_bias


def _coverage(slip_dof: float, trials: int = 120) -> tuple[float, float]:
    """(share of truths in the 95 % regions, median squared Mahalanobis distance) over fixations
    whose eyes carry a bias of 0.5 deg per axis, each sized as the session's lines size it: from
    the eyes' difference alone (two numbers, two degrees of freedom)."""
    rng = np.random.default_rng(11)
    inside, d2 = [], []
    for _ in range(trials):
        beta = rng.normal(0.0, math.radians(0.5), (2, 2))
        seen = math.degrees(math.sqrt(np.mean(((beta[0] - beta[1]) / math.sqrt(2)) ** 2)))
        bias = max(seen, 0.05)
        model = ErrorModel(bias_deg=bias, slip_deg=seen if seen > 0.05 else 0.0, slip_dof=slip_dof)
        r = ml_point(_biased(walkabout_samples(X, rng, n=120), beta).lines(), MLConfig(error_model=model))
        e = r.position_mm - X
        inside.append(float(e @ np.linalg.solve(r.level_covariance(0.95), e)) <= chi2.ppf(0.95, 3))
        d2.append(float(e @ np.linalg.solve(r.covariance_mm2, e)))
    return float(np.mean(inside)), float(np.median(d2))


def test_a_bias_sized_from_two_numbers_gives_student_regions_that_hold_the_truth():
    held, med = _coverage(2.0)
    known, med_known = _coverage(math.inf)
    assert held >= 0.92, f"Student regions held {held:.1%}"
    assert known < held - 0.04, f"chi-square regions held {known:.1%}, Student's {held:.1%}"
    assert med == med_known                       # the covariance (the scale) is the same: only the tails move


def test_student_radius_and_its_limit():
    assert region_radius(0.95, 3, math.inf) == math.sqrt(chi2.ppf(0.95, 3))
    assert region_radius(0.95, 3, 2.0) > 2.0 * math.sqrt(chi2.ppf(0.95, 3))
    assert abs(region_radius(0.95, 3, 1e6) - math.sqrt(chi2.ppf(0.95, 3))) < 1e-3


def test_the_error_budget_carries_the_degrees_of_freedom_of_the_slip():
    prior = BiasPrior(0.12, "calibration", "test", True)
    slipped = with_bias(ErrorModel(), session_bias(prior, SeenBias(0.6, 0.04, 8, 0, 2)))
    assert slipped.slip_dof == 2 and 0 < slipped.slip_deg <= slipped.bias_deg
    calm = with_bias(ErrorModel(), session_bias(prior, SeenBias(0.1, 0.04, 8, 0, 2)))
    assert calm.slip_deg == 0 and math.isinf(calm.slip_dof) and calm.bias_deg == 0.12


def test_targets_json_keeps_the_degrees_of_freedom(rng):
    model = ErrorModel(bias_deg=0.6, slip_deg=0.58, slip_dof=2.0)
    r = ml_point(walkabout_samples(X, rng, n=120).lines(), MLConfig(error_model=model))
    sight = r.sight()
    assert sight.scale_dof < 10 and sight.depth_dof > sight.scale_dof     # the common turn: across the line of sight
    radii = np.sqrt(np.linalg.eigvalsh(r.covariance_mm2)) * 2.8
    rec = target_record(0, 0.0, 1.0, r.position_mm, radii, 120, "ml", "ok", r.covariance_mm2, 100.0, [0],
                        sight=sight)
    back = record_sight(rec)
    assert back.scale_dof == round(sight.scale_dof, 3) and back.depth_dof == round(sight.depth_dof, 3)
