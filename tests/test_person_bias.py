"""A per-person gaze bias learned from a validation session and applied to that person's later
sessions (issue 15; docs/calibration.md "Per-person bias").

The simulated person P has a fixed per-eye bias (left (1.2, -0.8), right (1.0, -1.1) deg) that
the session's own eye calibration does not see (the simulator applies ``eyes.bias_deg`` in the
recording only: the glasses slipped after calibrating). Every session is processed with the
simulator's true camera (``--camera truth/camera.json``): a camera calibrated from a few views
leaves a systematic error of its own (about 0.2 deg at 640x360), which belongs to that session,
not to the person, and would otherwise be learned with the bias.

Figures (seeds below; ``.venv/bin/python -m pytest -q tests/test_person_bias.py -s``, printed):
learned corrections left (-1.16, +0.86), right (-0.98, +1.10) deg against the truth (-1.2, +0.8),
(-1.0, +1.1); per-eye RMS angular error on the validation targets 1.63 -> 0.72 deg; on the later
session (seed 7, other targets) the RMS 3D target error is 69 mm without the correction and 21 mm
with it; a bias-free person (seed 5) gets (-0.03, -0.02), (-0.01, -0.01) deg.
"""

import json
import shutil

import numpy as np
import pytest

from wearable_gaze.cli import main
from wearable_gaze.formats.person import read_person, read_validation, write_validation
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.report.truth_match import match_targets
from wearable_gaze.pipeline.steps.person import learn_bias
from wearable_gaze.sim.simulate import simulate_scenario

BIAS_P = [[1.2, -0.8], [1.0, -1.1]]


def _scenario(bias):
    return {"base": "lab-walkabout", "duration_s": 8.0, "camera": {"resolution": [640, 360]},
            "eyes": {"bias_deg": bias, "sigma_deg": 0.5},
            "targets": {"random_count": 3, "random_depth_mm": [700.0, 3000.0]}, "calibration": {"camera_views": 6}}


def _session(base, name, bias, seed):
    root = base / name
    simulate_scenario(_scenario(bias), root, seed=seed)
    process_session(root, method="ml", camera=root / "truth" / "camera.json", overlay=False, report=False)
    return root


def _pairs(res, root):
    truth = json.loads((root / "truth" / "targets.json").read_text())["targets"]
    fixated = [t for t in truth if sum(b - a for a, b in t["fixations_s"]) >= 1.0]
    pairs = match_targets(res.targets, fixated)
    assert len(pairs) == len(fixated) and all(f is not None for _, f in pairs)
    return pairs


def _rms_error_mm(res, root):
    err = [np.linalg.norm(np.array(f["position_mm"]) - tt["position_mm"]) for tt, f in _pairs(res, root)]
    return float(np.sqrt(np.mean(np.square(err))))


def _rms_direction_error_deg(res, root):
    """RMS over the fixated targets of the angle, seen from where the target's lines were seen
    (its ``direction.seen_from_mm``), between the estimate and the true target: what an eye's
    angular bias turns, apart from the depth (mostly noise from a metre on)."""
    err = []
    for tt, f in _pairs(res, root):
        seen = np.array(f["direction"]["seen_from_mm"])
        a, b = np.array(f["position_mm"]) - seen, np.array(tt["position_mm"]) - seen
        err.append(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))
    return float(np.sqrt(np.mean(np.square(err))))


@pytest.fixture(scope="module")
def person_p(tmp_path_factory):
    """P's validation session (seed 6), the correction learned from it (person.json), and a later
    session of P (seed 7: other targets) processed without and with it."""
    base = tmp_path_factory.mktemp("person")
    val = _session(base, "validation", BIAS_P, 6)
    person = base / "person.json"
    assert main(["learn-bias", str(val), "--validation", str(val / "truth" / "targets.json"), "-o", str(person)]) == 0
    later = base / "later"
    simulate_scenario(_scenario(BIAS_P), later, seed=7)
    cam = later / "truth" / "camera.json"
    plain = process_session(later, base / "plain", method="ml", camera=cam, overlay=False, report=False)
    fixed = process_session(later, base / "fixed", method="ml", camera=cam, overlay=False, report=False,
                            person=person)
    return val, person, later, plain, fixed


def test_the_learned_correction_is_the_persons_bias(person_p):
    _, person, _, _, _ = person_p
    p = read_person(person)
    learned = np.array([e["correction_deg"] for e in p["eyes"]])
    print("learned", learned.tolist(), "figures", [(e["rms_before_deg"], e["rms_after_deg"]) for e in p["eyes"]])
    np.testing.assert_allclose(learned, -np.array(BIAS_P), atol=0.2)
    for e in p["eyes"]:
        assert e["targets"] == 3 and e["samples"] > 300
        assert e["rms_after_deg"] < 0.6 * e["rms_before_deg"]


def test_a_later_session_is_more_accurate_with_the_correction(person_p):
    _, _, later, plain, fixed = person_p
    without, with_ = _rms_error_mm(plain, later), _rms_error_mm(fixed, later)
    print(f"later session RMS target error: {without:.0f} mm without, {with_:.0f} mm with the correction")
    assert with_ < 0.6 * without
    np.testing.assert_allclose(fixed.summary["person"]["correction_deg"],
                               [e["correction_deg"] for e in read_person(person_p[1])["eyes"]])


def test_a_bias_free_person_learns_no_correction(tmp_path):
    root = _session(tmp_path, "s", [[0.0, 0.0], [0.0, 0.0]], 5)
    p = learn_bias(root, root / "truth" / "targets.json")
    learned = np.array([e["correction_deg"] for e in p["eyes"]])
    print("bias-free person learned", learned.tolist())
    assert np.all(np.abs(learned) < 0.15), learned
    for e in p["eyes"]:
        assert e["rms_after_deg"] <= e["rms_before_deg"] + 1e-3


def test_the_view_lines_step_follows_the_person_file(person_p, tmp_path):
    """``--person`` is a setting of the cached view-line step: adding, changing or removing it
    redoes that step; the same file again does not."""
    _, person, later, _, _ = person_p
    out = tmp_path / "out"
    shutil.copytree(person_p[3].out, out)               # the run without a person
    kw = {"method": "ml", "camera": later / "truth" / "camera.json", "overlay": False, "report": False}
    r = process_session(later, out, person=person, **kw)
    assert "viewlines" not in r.skipped and "targets" not in r.skipped
    r = process_session(later, out, person=person, **kw)
    assert "viewlines" in r.skipped
    other = tmp_path / "other.json"
    d = json.loads(person.read_text())
    d["eyes"][0]["correction_deg"][0] += 0.5
    other.write_text(json.dumps(d))
    assert "viewlines" not in process_session(later, out, person=other, **kw).skipped
    assert "viewlines" not in process_session(later, out, **kw).skipped


def test_a_validation_file_round_trips_and_truth_targets_are_read_as_one(person_p, tmp_path):
    val = person_p[0]
    from_truth = read_validation(val / "truth" / "targets.json")
    assert len(from_truth) == 3 and all(len(t["position_mm"]) == 3 and t["fixations_s"] for t in from_truth)
    path = tmp_path / "validation.json"
    write_validation(path, from_truth)
    assert read_validation(path) == from_truth
    a = learn_bias(val, path)["eyes"]
    b = learn_bias(val, val / "truth" / "targets.json")["eyes"]
    assert a == b


def _imported(session, work):
    """``session`` exported as a Pupil Core recording (per-eye rays from the device) and imported."""
    from wearable_gaze.formats.devices.common import ImportOptions
    from wearable_gaze.pipeline.importer import export_recording, import_recording

    side = json.loads((session / "markers.json").read_text())["marker_size_mm"]
    export_recording(session, work / "recording", "pupil-core")
    import_recording(work / "recording", work / "imported", "pupil-core",
                     ImportOptions(markers=session / "markers.json", marker_size_mm=side))
    return work / "imported"


def test_an_imported_sessions_eye_rays_learn_and_take_the_correction(person_p, tmp_path):
    """The device-ray path: learned from an imported validation session (its eye rays, no eye
    calibration), applied to an imported later session. Figures: learned left (-1.20, +0.87),
    right (-0.97, +1.10) deg; the imported later session's targets' direction error (RMS, seen
    from their lines) 1.41 deg without, 0.10 deg with the correction; in mm 58 without, 51 with:
    its two fixated targets are 0.94 m away (32 -> 3 mm) and 2.4 m away (76 -> 72 mm, the depth's
    noise, which a turn of the lines does not remove, and which four samples more or fewer at the
    fixation's edges move by 10 mm: 68 -> 39 mm with issue 26's segmentation)."""
    val, _, later, _, _ = person_p
    imp_val = _imported(val, tmp_path / "v")
    process_session(imp_val, method="ml", overlay=False, report=False)
    person = tmp_path / "person.json"
    assert main(["learn-bias", str(imp_val), "--validation", str(val / "truth" / "targets.json"),
                 "-o", str(person)]) == 0
    learned = np.array([e["correction_deg"] for e in read_person(person)["eyes"]])
    print("learned from eye rays", learned.tolist())
    np.testing.assert_allclose(learned, -np.array(BIAS_P), atol=0.2)
    imp_later = _imported(later, tmp_path / "l")
    plain = process_session(imp_later, tmp_path / "plain", method="ml", overlay=False, report=False)
    fixed = process_session(imp_later, tmp_path / "fixed", method="ml", overlay=False, report=False, person=person)
    without, with_ = _rms_error_mm(plain, later), _rms_error_mm(fixed, later)
    turned = _rms_direction_error_deg(plain, later), _rms_direction_error_deg(fixed, later)
    print(f"imported later session RMS target error: {without:.0f} mm without, {with_:.0f} mm with the correction; "
          f"direction {turned[0]:.2f} deg without, {turned[1]:.2f} deg with")
    assert turned[1] < 0.5 * turned[0] and with_ < without


def test_viewlines_turns_each_eye_by_its_correction(person_p, tmp_path):
    """``viewlines --person``: each eye's lines turn by its own correction (about 1.45 deg left,
    1.47 deg right here), the origins stay."""
    from wearable_gaze.formats.viewlines import read_viewlines_csv

    val, person, _, _, _ = person_p
    argv = ["viewlines", str(val / "eye.csv"), "--eyes", str(val / "processed" / "eyes.json"), "--poses",
            str(val / "processed" / "poses.csv")]
    assert main(argv + ["-o", str(tmp_path / "a.csv")]) == 0
    assert main(argv + ["-o", str(tmp_path / "b.csv"), "--person", str(person)]) == 0
    a, b = (read_viewlines_csv(tmp_path / n)[0].samples for n in ("a.csv", "b.csv"))
    corr = [e["correction_deg"] for e in read_person(person)["eyes"]]
    for side, (h, v) in zip(("left", "right"), corr, strict=True):
        da, db = getattr(a, f"{side}_direction"), getattr(b, f"{side}_direction")
        ok = getattr(a, f"{side}_valid")
        turn = np.degrees(np.arccos(np.clip(np.sum(da[ok] * db[ok], axis=1), -1, 1)))
        assert abs(np.median(turn) - np.hypot(h, v)) < 0.05, (side, np.median(turn), (h, v))
        np.testing.assert_allclose(getattr(a, f"{side}_origin_mm")[ok], getattr(b, f"{side}_origin_mm")[ok])
