"""The error model wired into the pipeline: ``estimate`` reports the model's covariance by default
and the inverse Fisher information with --no-error-model (and says which), ``find_targets`` gives
it to the running, fixation, merged and target estimates, and ``process`` takes its bias from the
eye calibration (an imported session: its device's, tests/test_errorbudget.py)."""

import json
from dataclasses import replace

import numpy as np
import pytest
from helpers import walkabout_samples

from estimator import run_estimator
from estimator.errormodel import ErrorModel, bias_from_calibration
from estimator.merge import MERGE_POSE_DEG
from wearable_gaze.cli import main
from wearable_gaze.formats.viewlines import write_viewlines_csv
from wearable_gaze.pipeline.steps.errorbudget import TRACKED_POSITION_MM, session_error_model
from wearable_gaze.pipeline.steps.estimate import radius95_mm, running_estimate
from wearable_gaze.pipeline.steps.fixations import find_targets

TARGET = [120.0, -40.0, 1200.0]


def test_estimate_reports_the_error_model_by_default_and_the_crb_without(tmp_path, capsys):
    samples = walkabout_samples(TARGET, np.random.default_rng(3), n=240)
    path = tmp_path / "one.csv"
    write_viewlines_csv(path, samples, segment=[0] * len(samples))
    got = {}
    for flag in ([], ["--no-error-model"]):
        assert main(["estimate", str(path), "--method", "ml", "--json", *flag]) == 0
        got[bool(flag)] = json.loads(capsys.readouterr().out.splitlines()[0])
    model, plain = got[False], got[True]
    assert model["covariance_model"] == "error-model" and plain["covariance_model"] == "inverse-fisher"
    want_model = run_estimator(samples, "ml", 1.0, error_model=ErrorModel())[1].covariance_mm2
    want_plain = run_estimator(samples, "ml", 1.0)[1].covariance_mm2
    np.testing.assert_allclose(model["covariance_mm2"], want_model, rtol=1e-6)
    np.testing.assert_allclose(plain["covariance_mm2"], want_plain, rtol=1e-6)
    assert np.trace(want_model) > 2 * np.trace(want_plain)          # the bias floor dominates 1 deg noise


def test_find_targets_gives_the_model_to_every_estimate():
    samples = walkabout_samples(TARGET, np.random.default_rng(4), n=300)
    labels = np.full(len(samples), -1)
    labels[:120], labels[180:] = 0, 1                                 # a fixation and its revisit
    em = ErrorModel(bias_deg=0.4)
    with_model = find_targets(samples, labels, "ml", 1.0, error_model=em)
    without = find_targets(samples, labels, "ml", 1.0)
    assert len(with_model.targets) == len(without.targets) == 1 and with_model.targets[0].fixations == (0, 1)
    tg = with_model.targets[0]
    want = run_estimator(samples.select(tg.samples), "ml", 1.0, error_model=em)[1].covariance_mm2
    np.testing.assert_allclose(tg.covariance_mm2, want, rtol=1e-6)   # the merged target's estimate
    assert np.trace(tg.covariance_mm2) > 2 * np.trace(without.targets[0].covariance_mm2)
    r_model, r_plain = with_model.running["radius95_mm"], without.running["radius95_mm"]
    assert len(r_model) == len(r_plain) > 10 and np.all(r_model > r_plain)   # the running estimates
    e_model = running_estimate(samples.select(np.arange(120)), "ml", 1.0, error_model=em)[0]
    e_plain = running_estimate(samples.select(np.arange(120)), "ml", 1.0)[0]
    assert radius95_mm(e_model) > 1.5 * radius95_mm(e_plain)


def test_process_takes_the_bias_from_the_eye_calibration(tmp_path):
    eyes = tmp_path / "eyes.json"
    eyes.write_text(json.dumps({"eyes": [{"report": {"loo_rms_deg": 0.3}}, {"report": {"loo_rms_deg": 0.9}}]}))
    calibrated = session_error_model(False, eyes)
    tracked = ErrorModel(pose_offset_deg=MERGE_POSE_DEG, pose_position_mm=TRACKED_POSITION_MM)
    assert calibrated == replace(tracked, bias_deg=calibrated.bias_deg)
    assert calibrated.bias_deg == pytest.approx(bias_from_calibration([0.3, 0.9]), abs=1e-4)
    assert session_error_model(True, eyes, tracked=False) == ErrorModel()          # a device's SLAM poses
    assert session_error_model(True, eyes) == tracked                   # no import report: the conservative bias
    assert session_error_model(False, tmp_path / "absent.json") == tracked
