"""``process`` never presents an earlier run's results as this run's (issue 12): a failed step
invalidates every step after it, the summary says what failed, the exit status is 2 when no
target could be estimated, a corrupt step cache is redone, and a killed writer's temporary files
are cleaned up."""

import json
import logging
import shutil

import numpy as np
import pytest

import wearable_gaze.pipeline.process.session_steps as steps_mod
from wearable_gaze.cli import main
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.process.stepcache import ON_REQUEST, STEPS
from wearable_gaze.sim.simulate import simulate_scenario

SMALL = {"base": "lab-walkabout", "duration_s": 4.0, "camera": {"resolution": [640, 360]}}
RESULTS = ("viewlines.csv", "estimates.csv", "targets.csv", "targets.json", "target_labels.npy", "fixations.csv",
           "gaze.csv", "targets.ply", "report.html")


@pytest.fixture(scope="module")
def small_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("stale") / "session"
    simulate_scenario(SMALL, root, seed=0)
    return root


@pytest.fixture
def processed(small_session, tmp_path):
    """A fresh copy of the small session, processed once (report without the overlay)."""
    s = tmp_path / "s"
    shutil.copytree(small_session, s, ignore=shutil.ignore_patterns("processed"))
    res = process_session(s, s / "processed", overlay=False)
    assert res.targets and res.problems == []
    for name in RESULTS:
        assert (s / "processed" / name).is_file(), name
    return s, s / "processed"


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def test_rerun_skips_unchanged_steps_and_redoes_what_changed(processed):
    """Run again with the same options: every step skipped; with another method: the targets
    redone and the tracking kept; forced: nothing skipped. (On this module's fresh copy: the run
    changes the outputs, so not on the session-wide ``processed`` of tests/conftest.py.)"""
    s, out = processed
    res = process_session(s, out, overlay=False)
    assert set(res.skipped) == {"camera", "eyes", "tracking", "viewlines", "targets", "export", "report"}
    res = process_session(s, out, method="ml", report=False)
    assert "targets" not in res.skipped and "tracking" in res.skipped
    assert {t["method"] for t in json.loads((out / "targets.json").read_text())["targets"]} == {"ml"}
    res = process_session(s, out, force=True, report=False)
    assert res.skipped == []


def test_a_failed_step_never_leaves_the_previous_targets_as_the_result(processed, capsys):
    s, out = processed
    capsys.readouterr()
    lines = (s / "eye.csv").read_text().splitlines()
    cells = lines[10].split(",")
    cells[2] = "nan"                                              # left_x of one sample
    lines[10] = ",".join(cells)
    (s / "eye.csv").write_text("\n".join(lines) + "\n")
    assert main(["process", str(s), "--no-overlay"]) == 2
    cap = capsys.readouterr()
    assert cap.out.startswith("0 fixated target(s)") and "FAILED: viewlines" in cap.out
    assert "viewlines:" in cap.err and "left_x" in cap.err and "Traceback" not in cap.err
    for name in RESULTS + (".viewlines_unsegmented.csv",):
        assert not (out / name).exists(), f"{name} of the earlier run survived"
    summary = _summary(out)
    assert summary["targets"] == [] and summary["failed_steps"] == ["viewlines"]
    assert summary["steps_not_done"] == ["targets", "export", "report"] and "report" not in summary
    assert any(p.startswith("viewlines:") for p in summary["problems"])
    # what does not depend on the failed step is kept, and not redone
    assert {"camera", "eyes", "tracking"} <= set(summary["steps_skipped"])
    assert (out / "poses.csv").is_file() and (out / "eyes.json").is_file()
    # fixed input: the steps after it run again and the targets come back
    cells[2] = "2000.00"
    lines[10] = ",".join(cells)
    (s / "eye.csv").write_text("\n".join(lines) + "\n")
    assert main(["process", str(s), "--no-overlay"]) == 0
    assert (out / "targets.json").is_file() and not capsys.readouterr().out.startswith("0 fixated")


def test_a_failed_camera_calibration_invalidates_every_later_step_and_exits_2(processed, capsys):
    s, out = processed
    capsys.readouterr()
    board = s / "calibration" / "camera" / "board.json"
    spec = json.loads(board.read_text())
    spec["board"]["cols"], spec["board"]["rows"] = 5, 4                  # not the board in the images
    board.write_text(json.dumps(spec))
    assert main(["process", str(s), "--no-overlay"]) == 2
    cap = capsys.readouterr()
    assert cap.out.startswith("0 fixated target(s)") and "camera:" in cap.err
    summary = _summary(out)
    assert summary["failed_steps"] == ["camera"] and summary["targets"] == []
    assert summary["steps_not_done"] == ["eyes", "tracking", "viewlines", "targets", "export", "report"]
    for name in ("camera.json", "eyes.json", "poses.csv") + RESULTS:
        assert not (out / name).exists(), name
    assert not json.loads((out / ".steps.json").read_text())               # nothing cached is valid


def test_no_target_estimated_without_any_failure_still_exits_2_and_says_so(processed, monkeypatch, capsys):
    s, out = processed
    monkeypatch.setattr(steps_mod, "segment_view_lines", lambda samples, config: np.full(len(samples), -1))
    capsys.readouterr()
    assert main(["process", str(s), "--no-overlay", "--method", "ml"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "targets: no target could be estimated" in err[0]         # the report still made
    assert json.loads((out / "targets.json").read_text())["targets"] == [] and (out / "report.html").is_file()


def test_a_report_not_redone_after_its_targets_changed_is_removed(processed):
    s, out = processed
    res = process_session(s, out, method="ml", report=False)
    assert res.targets and "targets" not in res.skipped
    assert not (out / "report.html").exists() and not (out / "plot_3d.png").exists()
    assert "report.html" in _summary(out)["removed_outputs"]
    # unchanged targets: a report left out keeps the one that is still valid
    process_session(s, out, method="ml", overlay=False)
    res = process_session(s, out, method="ml", report=False)
    assert (out / "report.html").is_file() and "targets" in res.skipped


def test_an_exception_in_a_step_removes_the_outputs_of_the_steps_after_it(processed, monkeypatch):
    s, out = processed

    def broken(*args, **kwargs):
        raise RuntimeError("tracking crashed")
    monkeypatch.setattr(steps_mod, "track_video", broken)
    with pytest.raises(RuntimeError, match="tracking crashed"):
        process_session(s, out, overlay=False, force=True)
    for name in ("poses.csv",) + RESULTS:
        assert not (out / name).exists(), name
    state = json.loads((out / ".steps.json").read_text())
    assert "tracking" not in state and "targets" not in state


@pytest.mark.parametrize("garbage", [b"{\"camera\": \"ab", b"", b"[1, 2]", b"\xff\xfe\x00garbage",
                                     b"{\"camera\": " + b"[" * 100000, b"{\"camera\": \"\xe9\"}",
                                     b"{\"camera\": \"" + b"0" * 40 + b"\"}"])
def test_a_corrupt_step_cache_is_redone_with_a_warning(processed, caplog, garbage):
    s, out = processed
    (out / ".steps.json").write_bytes(garbage)
    with caplog.at_level(logging.WARNING, logger="wearable_gaze.pipeline.process.session"):
        res = process_session(s, out, overlay=False)
    assert res.skipped == [] and res.targets and res.problems == []
    assert any(".steps.json is unreadable" in r.getMessage() for r in caplog.records)
    assert set(json.loads((out / ".steps.json").read_text())) == set(STEPS) - set(ON_REQUEST)   # repaired
    assert set(process_session(s, out, overlay=False).skipped) == set(STEPS) - set(ON_REQUEST)


def test_temporary_files_of_a_killed_step_are_removed_at_the_next_run(processed):
    s, out = processed
    leftovers = [out / ".overlay.mp4.k3j_9a0z.mp4", out / ".targets.json.abcdefgh.json",
                 out / ".poses.csv.12345678.csv", out / "..steps.json.zzzzzzzz.json"]
    for p in leftovers:
        p.write_bytes(b"")
    mine = [out / ".overlay.mp4.notes", out / ".my-notes.txt", out / ".targets.json.backup.json"]
    for p in mine:
        p.write_text("the user's own file")
    process_session(s, out, overlay=False)
    assert [p.name for p in leftovers if p.exists()] == []
    assert all(p.read_text() == "the user's own file" for p in mine)      # not the pattern: kept


def test_a_recording_cut_short_is_read_with_a_problem_line(processed, capsys):
    s, out = processed
    man = json.loads((s / "session.json").read_text())
    man["complete"] = False                                     # a live recording that was killed:
    (s / "session.json").write_text(json.dumps(man))
    for name, cut in (("scene_timestamps.csv", 20), ("eye.csv", 30)):     # its video ahead of its timestamps
        lines = (s / name).read_text().splitlines(keepends=True)
        (s / name).write_text("".join(lines[:-cut]))
    capsys.readouterr()
    assert main(["process", str(s), "--no-overlay"]) == 0
    cap = capsys.readouterr()
    assert "cut short" in cap.err and not cap.out.startswith("0 fixated")
    t, frames, _, _ = read_poses_csv(out / "poses.csv")
    assert list(frames) == list(range(120 - 20)) and np.all(np.isfinite(t))   # frames without a time left out


def test_a_calibration_given_as_a_file_is_checked_once_and_never_removed(processed, capsys):
    s, out = processed
    cam = out / "camera.json"                                   # an earlier run's output, given as an input
    before = cam.read_bytes()
    capsys.readouterr()
    assert main(["process", str(s), "--no-overlay", "--camera", str(cam), "--eyes", str(s / "nope.json")]) == 2
    cap = capsys.readouterr()
    assert cam.read_bytes() == before and (out / "eyes.json").is_file()          # neither touched
    assert "eyes:" in cap.err and "nope.json" in cap.err and not (out / "targets.json").exists()
    summary = _summary(out)
    assert summary["failed_steps"] == ["eyes"]
    assert summary["steps_not_done"] == ["viewlines", "targets", "export", "report"]
    bad = s / "bad_camera.json"
    bad.write_text(json.dumps({"format": "wearable-gaze-camera", "version": 1}))
    assert main(["process", str(s), "--no-overlay", "--camera", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("wearable-gaze process: camera:") and "bad_camera.json" in err[0]
    assert _summary(out)["steps_not_done"] == ["eyes", "tracking", "viewlines", "targets", "export", "report"]
    assert cam.read_bytes() == before


def test_a_calibration_only_session_keeps_its_calibrations_and_no_recording_result(processed, capsys):
    s, out = processed
    man = json.loads((s / "session.json").read_text())
    man["has_recording"] = False                 # the same folder, now declared calibration-only
    (s / "session.json").write_text(json.dumps(man))
    capsys.readouterr()
    assert main(["process", str(s), "--no-overlay"]) == 2
    cap = capsys.readouterr()
    assert "no recording" in cap.err and "FAILED" not in cap.out and "not done" not in cap.out
    assert (out / "camera.json").is_file() and (out / "eyes.json").is_file()
    for name in ("poses.csv",) + RESULTS:
        assert not (out / name).exists(), name
