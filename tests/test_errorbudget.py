"""The bias sized from the data (``pipeline.steps.errorbudget``, issue 27): the eye calibration's
leave-one-out errors with no fixed slippage floor, the slippage the session's lines show on top, a
device kind's published accuracy (its source recorded) where nothing was calibrated here, and an
assumption that fixes a depth named next to every target in targets.json and the report."""

import json

import numpy as np
import pytest

from estimator.errormodel import DEFAULT_BIAS_DEG
from estimator.errormodel_regions import Sight
from estimator.slippage import SeenBias
from wearable_gaze.formats.targets import read_targets, write_targets
from wearable_gaze.pipeline.report.page import _intervals
from wearable_gaze.pipeline.steps.errorbudget import (
    bias_note,
    calibration_prior,
    depth_assumption,
    device_prior,
    session_bias,
    session_error_model,
)
from wearable_gaze.pipeline.types import Target


def _eyes(tmp_path, loo):
    path = tmp_path / "eyes.json"
    path.write_text(json.dumps({"eyes": [{"report": {"loo_rms_deg": v}} for v in loo]}))
    return path


def test_a_good_calibration_gives_a_small_bias_no_fixed_floor(tmp_path):
    eyes = _eyes(tmp_path, [0.16, 0.14])
    want = np.sqrt((0.16**2 + 0.14**2) / 2 / 2)                       # RMS over the eyes, per axis
    assert calibration_prior(eyes).deg == pytest.approx(want, abs=1e-4)
    assert session_error_model(False, eyes).bias_deg == pytest.approx(want, abs=1e-4)     # was 0.51: 0.5 added
    assert session_error_model(False, eyes).bias_deg < 0.2


def test_the_slippage_the_lines_show_is_added_beyond_the_calibration(tmp_path):
    eyes = _eyes(tmp_path, [0.16, 0.14])
    cal = calibration_prior(eyes).deg
    consistent = SeenBias(0.05, 0.03, 8, 0, 2)              # less than the calibration's own error: nothing added
    slipped = SeenBias(0.45, 0.03, 8, 0, 2)                 # the glasses moved after the calibration
    assert session_error_model(False, eyes, seen=consistent).bias_deg == pytest.approx(cal, abs=1e-4)
    assert session_error_model(False, eyes, seen=slipped).bias_deg == pytest.approx(0.45, abs=1e-4)
    rec = session_bias(calibration_prior(eyes), slipped)
    assert rec["slip_deg"] == pytest.approx(np.sqrt(0.45**2 - cal**2), abs=1e-3)
    assert rec["basis"] == "calibration" and rec["seen"]["groups"] == 8
    assert "0.45 deg" in bias_note(rec) and "slippage" in bias_note(rec)


def test_without_a_calibration_the_device_kind_gives_the_bias_and_its_source():
    tobii = device_prior({"device": "tobii-g2", "notes": []})
    assert tobii.basis == "per-wearer calibrated" and tobii.published
    assert "Tobii Pro Glasses 2" in tobii.source and tobii.deg == pytest.approx(0.5 * np.sqrt(2 / np.pi), abs=1e-3)
    neon = device_prior({"device": "pupil-neon", "notes": [], "kappa": {"depth_mm": 1000.0}})
    assert neon.basis == "kappa at a distance" and "Neon" in neon.source and neon.deg > 1.0
    aria = device_prior({"device": "aria-mps", "notes": ["the gaze is Aria's general model, not calibrated"]})
    assert aria.basis == "general model" and not aria.published and "conservative" in aria.source
    unknown = device_prior({"device": "something-new", "notes": []})
    assert unknown.deg == DEFAULT_BIAS_DEG and not unknown.published and "conservative" in unknown.source
    em = session_error_model(True, None, tracked=False, import_report={"device": "tobii-g2", "notes": []})
    assert em.bias_deg == pytest.approx(tobii.deg)          # an imported session: the device's, not the default
    rec = session_bias(aria, None)
    assert "a conservative value, not a published or measured figure" in bias_note(rec)
    nothing = session_bias(aria, SeenBias(0.0, float("nan"), 0, 2, 0))   # no fixation to show it: valid JSON
    assert nothing["seen"]["se_deg"] is None and "no fixation to show it" in bias_note(nothing)
    json.dumps(nothing, allow_nan=False)


def test_the_depth_assumption_is_named_in_targets_json_and_the_report(tmp_path):
    report = {"device": "pupil-neon", "notes": [], "kappa": {"depth_mm": 1000.0}}
    said = depth_assumption(report, "scene_video")
    assert "kappa offset taken at 1 m" in said
    assert "head taken as still" in depth_assumption({"device": "tobii-g2"}, "still_head")
    assert depth_assumption({"device": "tobii-g2"}, "scene_video") is None
    tg = Target(0, np.array([0.0, 0.0, 1500.0]), np.diag([4e2, 4e2, 9e4]), np.array([50.0, 50.0, 800.0]), "ok", 60,
                0.0, 1.0, (0,), "ml", 30.0, sight=Sight(np.zeros(3), 2.8, 0.2), depth_assumption=said)
    budget = session_bias(device_prior(report), None)
    write_targets(tmp_path, [tg.row()], "ml", budget)
    rec = read_targets(tmp_path / "targets.json")[0]          # checked against the schema
    assert rec["depth_assumption"] == said and "depth" in rec
    assert json.loads((tmp_path / "targets.json").read_text())["error_model"]["basis"] == "kappa at a distance"
    again = Target.from_row(rec)
    assert again.depth_assumption == said
    assert "assumes: kappa offset taken at 1 m" in _intervals(again)
    plain = Target.from_row({k: v for k, v in tg.row().items() if k != "depth_assumption"})
    assert plain.depth_assumption is None and "assumes" not in _intervals(plain)
