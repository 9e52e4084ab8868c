"""Imported sessions (issue 14), independent of any one device: ``process`` on the eye rays a
device gives with each source of head poses, the eye-ray file, the ``import`` command's refusals,
and the estimators on the short fixations of a 10 Hz device."""

import html
import json

import numpy as np
import pytest
from roundtrip import native, rms, target_errors

from estimator import BinocularSamples, estimate, perturb_directions
from estimator.segments import SegmentConfig, segment_fixations
from wearable_gaze.cli import main
from wearable_gaze.errors import UserError
from wearable_gaze.formats.devices import detect_format
from wearable_gaze.formats.devices.common import SessionImport, read_simulated_recording
from wearable_gaze.formats.eye_rays import EyeRaysWriter, read_eye_rays
from wearable_gaze.formats.gaze_export import read_gaze_csv
from wearable_gaze.formats.outputs import check_output
from wearable_gaze.pipeline.process.session import process_session


def _import_simulated(session, out, pose_source, gaze=True):
    """The simulated session as a device with perfect rays would give it."""
    sim = read_simulated_recording(session)
    r = sim.rays
    with SessionImport(out, "test", session) as imp:
        imp.add_rays(sim.t, r.left_origin_mm, r.left_direction, r.left_valid, r.right_origin_mm, r.right_direction,
                     r.right_valid)
        if pose_source == "device":
            imp.add_head_poses(sim.t, sim.T_world_from_head)
        if gaze:
            imp.add_device_gaze(sim.t, sim.gaze_head_mm)
        imp.note("kappa offset by cyclopean-ray at 1000 mm")
        imp.drop("status 16", 3)
        imp.finish(sim.eye_rate_hz, 12.5, pose_source, {"head": "the scene camera"})
    return sim


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return native(str(tmp_path_factory.getbasetemp()))


def test_device_rays_and_poses_find_the_targets_as_well_as_the_native_session(simulated, tmp_path):
    session, native_err = simulated
    _import_simulated(session, tmp_path / "s", "device")
    res = process_session(tmp_path / "s", tmp_path / "out")
    err = target_errors(session, res.targets)
    assert res.problems == [] and res.status["eyes"] == "device" and res.status["camera"] == "device"
    assert np.all(np.isfinite(err)) and rms(err) <= 1.1 * rms(native_err), (err, native_err)
    # each target beside the device's own gaze, in the report too
    cmp = (tmp_path / "out" / "device_comparison.csv").read_text().splitlines()
    assert len(cmp) == len(res.targets) + 1
    page = html.unescape((tmp_path / "out" / "report.html").read_text())
    assert "Beside the device's own 3D gaze" in page and "Head poses: the device's own" in page
    # what the import noted and dropped is said where the results are read
    assert "Import (test): kappa offset by cyclopean-ray" in page and "dropped 3 (status 16)" in page
    # the exports (issue 17): every file in its documented format; gaze.csv on the device's clock too,
    # and without a scene-camera calibration no 2D gaze
    for p in (tmp_path / "out").iterdir():
        check_output(p)
    gaze = read_gaze_csv(tmp_path / "out" / "gaze.csv")
    np.testing.assert_allclose(gaze["device_t_s"] - gaze["t_s"], 12.5, atol=2e-6)
    assert np.all(np.isnan(gaze["gaze_x_px"])) and not gaze["in_image"].any() and gaze["pose_ok"].mean() > 0.9


def test_a_still_head_uses_only_vergence_and_the_report_says_so(simulated, tmp_path):
    session, _ = simulated
    _import_simulated(session, tmp_path / "s", "still_head", gaze=False)
    res = process_session(tmp_path / "s", tmp_path / "out")
    poses = (tmp_path / "out" / "poses.csv").read_text().splitlines()
    assert poses[1].split(",")[-1] == "still_head"
    assert "only the two eyes' vergence" in html.unescape((tmp_path / "out" / "report.html").read_text())
    assert not (tmp_path / "out" / "device_comparison.csv").exists()
    # the head frame is the world: every target is within reach of the head frame's origin
    for t in res.targets:
        assert np.linalg.norm(t["position_mm"]) < 6000


def test_eye_rays_round_trip_and_refuse_bad_rows(tmp_path):
    p = tmp_path / "eye_rays.csv"
    with EyeRaysWriter(p) as w:
        w.add([0.0, 0.1], [[-32, 0, -30]] * 2, [[0, 0, 2], [0.1, 0, 1]], [True, False], [[32, 0, -30]] * 2,
              [[0, 0, 1]] * 2, [True, True])
    s = read_eye_rays(p)
    assert s.frame == "head" and list(s.left_valid) == [True, False] and np.allclose(s.left_direction[0], [0, 0, 1])
    text = p.read_text().splitlines()
    (tmp_path / "order.csv").write_text("\n".join([text[0], text[2], text[1]]) + "\n")
    with pytest.raises(UserError, match=r"line 3: t = 0.000000 does not increase \(line 2 has t = 0.100000\)"):
        read_eye_rays(tmp_path / "order.csv")        # both rows named: the damaged one may be the earlier
    bad = text[2].split(",")
    bad[7] = "1"                                   # the left eye marked valid, its ray empty
    (tmp_path / "valid.csv").write_text("\n".join([text[0], text[1], ",".join(bad)]) + "\n")
    with pytest.raises(UserError, match="left eye is marked valid"):
        read_eye_rays(tmp_path / "valid.csv")


def test_an_import_that_fails_leaves_nothing(tmp_path):
    (tmp_path / "rec").mkdir()
    with pytest.raises(UserError, match="no usable eye sample"):
        with SessionImport(tmp_path / "s", "test", tmp_path / "rec") as imp:
            imp.drop("status not 0", 7)
            imp.finish(60, 0.0, "still_head", {})
    assert not (tmp_path / "s" / "session.json").exists()


@pytest.mark.parametrize("argv,match", [
    (["import", "{t}/nothing", "-o", "{t}/s"], "no such recording"),
    (["import", "{t}/empty", "-o", "{t}/s"], "matches none of the known formats"),
    (["import", "{t}/empty", "-o", "{t}/s", "--format", "aria-mps", "--markers", "{t}/m.json"], "--markers"),
    (["import", "{t}/empty", "-o", "{t}/full"], "not empty"),
    (["import", "{t}/empty", "-o", "{t}/file.txt"], "is a file"),
    (["export-recording", "{t}/empty", "-o", "{t}/x", "--format", "tobii-g3"], "session"),
])
def test_import_refuses_bad_input_in_one_line(tmp_path, capsys, argv, match):
    (tmp_path / "empty").mkdir()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    (tmp_path / "file.txt").write_text("mine")
    code = main([a.format(t=tmp_path) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and match in err[0], err
    assert (tmp_path / "full" / "keep.txt").read_text() == "mine" and (tmp_path / "file.txt").read_text() == "mine"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]        # no temporary folder left



def test_a_session_inside_the_recording_is_refused(real_data, tmp_path, capsys):
    """``import REC -o REC/session`` (a copy of the real Aria sample) wrote the session into the
    recording's folder; it is one line, exit status 2, and the recording is left as it was."""
    import shutil

    rec = tmp_path / "mps"
    shutil.copytree(real_data / "aria_mps_sample_gen1", rec, ignore=shutil.ignore_patterns("*.gz"))
    before = sorted(p.name for p in rec.iterdir())
    assert main(["import", str(rec), "-o", str(rec / "session")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is inside the recording" in err[0], err
    assert sorted(p.name for p in rec.iterdir()) == before


def test_a_recording_given_to_process_or_a_session_to_import_says_which_command(real_data, tmp_path, capsys):
    """A new user's first slips on the real recordings: ``process`` on the Aria MPS folder said
    "session.json: no such file; pass the session manifest", on the Tufts CSV "run 'wearable-gaze
    simulate -o .../test.csv'" (into the data folder), and ``import`` of an imported session "matches
    none of the known formats". Each line now names the command to run."""
    aria, tufts = real_data / "aria_mps_sample_gen1", real_data / "tufts_gaze_depth" / "test.csv"
    assert main(["import", str(aria), "-o", str(tmp_path / "s")]) == 0
    capsys.readouterr()
    for argv, want in ((["process", str(aria), "-o", str(tmp_path / "p1")], f"wearable-gaze import {aria} -o"),
                       (["process", str(tufts), "-o", str(tmp_path / "p2")], f"wearable-gaze import {tufts} -o"),
                       (["import", str(tmp_path / "s"), "-o", str(tmp_path / "s2")],
                        f"wearable-gaze process {tmp_path / 's'}")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and want in err[0] and "simulate" not in err[0], err

def test_detect_format_names_the_choices(tmp_path):
    with pytest.raises(UserError, match="--format"):
        detect_format(tmp_path)


def test_short_fixations_at_10_hz_are_found_and_estimated(rng):
    """Aria's 10 Hz: a 0.5 s fixation has 5 samples. The rate's window finds the three 2 s
    fixations, and every estimator answers on 5 samples. The default window, 8 samples a side,
    does not: its noise measure (three windows, 2.4 s, against the medians' noise) has no
    stretch clear of a saccade in 2 s fixations, so its threshold takes the saccades for noise
    (before issue 27 it found none: a saccade took half a window and 50 ms more off each side)."""
    t = np.arange(60) / 10.0
    targets = np.repeat([[300.0, 0, 1500], [-400, 100, 2500], [0, -300, 1000]], 20, axis=0)
    heads = np.column_stack([200 * np.sin(0.8 * t), 30 * np.cos(t), 50 * t])
    lo, ro = heads - [32, 0, 0], heads + [32, 0, 0]
    s = BinocularSamples.from_arrays(t, lo, perturb_directions(targets - lo, np.deg2rad(0.5), rng), ro,
                                     perturb_directions(targets - ro, np.deg2rad(0.5), rng))
    labels = segment_fixations(s, SegmentConfig.for_rate(10.0))
    assert labels.max() + 1 == 3
    assert segment_fixations(s, SegmentConfig()).max() + 1 < 3
    five = s.select(np.flatnonzero(labels == 0)[:5])
    for method in ("ml", "voxel", "lse", "paper"):
        e = estimate(five, method)
        assert e.ok, (method, e.reason)
        assert np.linalg.norm(e.position_mm - [300, 0, 1500]) < 300, method


def test_the_manifest_records_the_source(simulated, tmp_path):
    session, _ = simulated
    _import_simulated(session, tmp_path / "s", "device")
    man = json.loads((tmp_path / "s" / "session.json").read_text())
    assert man["source"] == {"device": "test", "path": str(session), "clock_offset_s": 12.5, "pose_source": "device"}
    assert set(man["files"]) == {"eye_rays", "head_poses", "device_gaze", "import_report"}


@pytest.mark.parametrize("method", ["ml", "voxel", "lse", "paper"])
def test_a_point_nearer_than_anyone_fixates_is_not_an_answer(rng, method):
    """Lines that meet 40 mm in front of the eyes (an eye model not fitted: the Tufts rows) give
    'too-near', not a confident point; the same lines toward 600 mm give one."""
    from estimator import NEAR_POINT_MM, Status
    t = np.arange(40) / 60.0
    lo, ro = np.tile([-32.0, 0, 0], (40, 1)), np.tile([32.0, 0, 0], (40, 1))
    for depth, want in ((40.0, Status.TOO_NEAR), (600.0, Status.OK)):
        p = np.array([0.0, 0, depth])
        s = BinocularSamples.from_arrays(t, lo, perturb_directions(p - lo, np.deg2rad(0.2), rng), ro,
                                         perturb_directions(p - ro, np.deg2rad(0.2), rng))
        e = estimate(s, method)
        assert e.status == want, (method, depth, e.status, e.reason)
    assert NEAR_POINT_MM > 40


def test_a_poorly_fixed_fixation_is_not_merged_into_a_well_fixed_one(rng):
    """Aria's two fixations: one with 400 mm of head travel fixes its point to a few cm, the
    other (a still head: vergence only) to a metre in depth. When the good point lies 2 deg off
    the vague fixation's lines, the covariances still overlap (with the 0.5 deg floor for
    calibration bias), so ``same_target`` alone merged them and dragged the good point toward
    the other lines; the lines' likelihood ratio keeps them apart. Two fixations of one point
    still merge."""
    from tests.helpers import same_target
    from wearable_gaze.pipeline.steps.fixations import find_targets

    def fixation(point, heads, t0):
        lo, ro = heads - [32, 0, 0], heads + [32, 0, 0]
        return BinocularSamples.from_arrays(t0 + np.arange(len(heads)) / 10.0, lo,
                                            perturb_directions(point - lo, np.deg2rad(1.0), rng), ro,
                                            perturb_directions(point - ro, np.deg2rad(1.0), rng))
    p_a = np.array([300.0, 0, 2400])
    u = p_a / np.linalg.norm(p_a)
    side = np.cross(u, [0, 1.0, 0])
    p_b = 3400 * (np.cos(np.deg2rad(2.0)) * u + np.sin(np.deg2rad(2.0)) * side / np.linalg.norm(side))
    moving = np.column_stack([np.linspace(-200, 200, 5), np.zeros(5), np.zeros(5)])
    a = fixation(p_a, moving, 0.0)
    b = fixation(p_b, np.zeros((9, 3)), 8.0)
    c = fixation(p_a, moving[::-1] + [0, 0, 100], 20.0)
    s = BinocularSamples.concatenate([a, b, c])
    ea, eb = estimate(a, "ml"), estimate(b, "ml")
    assert same_target(ea.position_mm, ea.covariance_mm2, eb.position_mm, eb.covariance_mm2, origin=[0, 0, 0])
    res = find_targets(s, np.repeat([0, 1, 2], [5, 9, 5]), "ml", 1.0)
    assert [t.fixations for t in res.targets] == [(0, 2), (1,)]
    assert np.linalg.norm(res.targets[0].position_mm - p_a) < 3 * res.targets[0].crb_mm


def test_a_target_whose_depth_is_not_fixed_is_unresolved_not_ok(rng):
    """A still head looking at a point 8 m away with 1 deg of noise assumed: the lines fix its
    direction, not its depth (the 95 % region, 8.9 m along the line of sight, reaches past twice
    the distance): the target is published as 'unresolved'. The
    same lines toward 1 m give an 'ok' target, and a moving target's point nearer the eyes than
    anyone fixates is 'too-near', not 'moving'."""
    from wearable_gaze.pipeline.steps.estimate import UNRESOLVED, target_status
    from wearable_gaze.pipeline.steps.fixations import find_targets

    t = np.arange(30) / 60.0
    lo, ro = np.tile([-32.0, 0, 0], (30, 1)), np.tile([32.0, 0, 0], (30, 1))
    for depth, want in ((8000.0, UNRESOLVED), (1000.0, "ok")):
        p = np.array([100.0, 0, depth])
        s = BinocularSamples.from_arrays(t, lo, p - lo, ro, p - ro)          # exact lines: the model's covariance
        res = find_targets(s, np.zeros(30, int), "ml", 1.0)
        assert [tg.status for tg in res.targets] == [want], (depth, res.targets)
    assert target_status("moving", np.array([0, 0, 30.0]), np.ones(3), s) == "too-near"
    assert target_status("moving", np.array([100, 0, 1000.0]), np.ones(3), s) == "moving"
