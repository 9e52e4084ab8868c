"""Progress that a log shows (issue 25): off a terminal a long step prints a line at least every
``WEARABLE_GAZE_PROGRESS_S`` seconds, also while one blocking call runs (pycolmap's matching, a
map's bundle adjustment); on a terminal the bar's clock keeps running; map building reports its
bundle adjustments' steps through its progress callback. The interval is a fraction of a second
here (5 s by default); tests/conftest.py turns the lines off for every other test."""

import io
import sys
import time

import numpy as np
import pytest
from helpers import TimedLog, slow_down

import tracking.mapadjust as mapadjust
import tracking.mapbuild as mapbuild
import wearable_gaze.pipeline.maps.markers as mapping
import wearable_gaze.progress as progress_module
from wearable_gaze.cli import main
from wearable_gaze.progress import LINE_INTERVAL_S, heartbeat, progress_bar, staged, step_bars

INTERVAL = 0.2


Log = TimedLog


class Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def every(monkeypatch):
    monkeypatch.setenv("WEARABLE_GAZE_PROGRESS_S", str(INTERVAL))
    return INTERVAL


def _gaps(times, t0) -> list:
    return np.diff([t0, *times]).tolist()


def test_the_default_interval_keeps_to_the_rule(monkeypatch):
    monkeypatch.delenv("WEARABLE_GAZE_PROGRESS_S", raising=False)
    assert 0 < progress_module.line_interval_s() == LINE_INTERVAL_S <= 10.0


def test_off_a_terminal_a_blocking_call_prints_a_line_every_interval(every):
    """A step that reports nothing for 1.5 s (one blocking call) printed nothing in a log until it
    ended; now a line at least every interval (a quarter of it late at most), and one at the end
    saying how it ended."""
    log = Log()
    t0 = time.monotonic()
    with heartbeat("mapping", log):
        time.sleep(1.5)
    lines = log.getvalue().splitlines()
    assert len(lines) >= 5 and all(ln.startswith("mapping: still running, ") for ln in lines[:-1]), lines
    assert lines[-1].startswith("mapping: done, "), lines
    assert max(_gaps(log.times, t0)) < 1.25 * every + 0.1, _gaps(log.times, t0)
    failed = Log()
    with pytest.raises(ValueError), heartbeat("mapping", failed):
        time.sleep(0.5)
        raise ValueError("no reconstruction")
    assert failed.getvalue().splitlines()[-1].startswith("mapping: stopped, ")       # not "done"


def test_off_a_terminal_lines_say_how_far_and_which_stage(every):
    log = Log()
    with progress_bar("markerless map", 1, log) as cb:
        for k in range(4):
            staged(cb, "features")(k + 1, 8)
        time.sleep(0.5)
        staged(cb, "matching")(0, 0)
        time.sleep(0.5)
        cb(3, 5)                                            # a callback without a stage clears it
        time.sleep(0.5)
    text = log.getvalue()
    assert "markerless map: features: 4/8 (50%), " in text
    assert "markerless map: matching: still running, " in text
    assert "markerless map: 3/5 (60%), " in text
    quick = Log()                                           # a step shorter than the interval: nothing
    with progress_bar("quick", 3, quick) as cb:
        cb(3, 3)
    assert quick.getvalue() == ""

    def plain(done, total):                                 # a callback that shows no stage gets none
        pass
    assert staged(plain, "x") is plain and staged(None, "x") is None


def test_a_run_of_short_steps_is_not_a_long_silence(every):
    """``process`` opens one bar a step: six steps of 0.15 s each (under the interval) printed
    nothing in 0.9 s, each counting from its own start. With ``step_bars`` they count from the
    last line of any of them: a line at least every interval across steps too."""
    def run(factory, log):
        t0 = time.monotonic()
        for name in ("camera", "eyes", "tracking", "viewlines", "targets", "export"):
            with factory(name):
                time.sleep(0.15)
        return t0
    alone = Log()
    run(lambda name: progress_bar(name, 1, alone), alone)
    assert alone.getvalue() == ""
    log = Log()
    t0 = run(step_bars(log), log)
    assert len(log.times) >= 4 and max(_gaps(log.times, t0)) < 1.25 * every + 0.15, log.getvalue()


def test_on_a_terminal_the_bar_is_redrawn_while_a_blocking_call_runs(monkeypatch):
    """tqdm redraws only when a step is reported: through a 1.3 s call the bar stood still, its clock
    too. Now it is redrawn every ``REFRESH_S``, with the stage named."""
    monkeypatch.setattr(progress_module, "REFRESH_S", 0.05)
    tty = Tty()
    with progress_bar("markerless map", 1, tty) as cb:
        staged(cb, "matching")(0, 0)
        drawn = tty.getvalue().count("\r")
        time.sleep(1.3)
        assert tty.getvalue().count("\r") >= drawn + 10
        assert "markerless map: matching" in tty.getvalue().rsplit("\r", 1)[-1]
        assert "00:01" in tty.getvalue()                      # the clock ran


def _room_views():
    """8 markers on two walls, seen from 40 views of a camera walking past (tests/test_mapbuild's
    survey), marker 5 moved 80 mm halfway."""
    from tests.test_mapbuild import _room, _views

    return _views(_room(), moved=(5, np.array([0.0, 0.0, 80.0])))


def test_map_building_reports_during_its_bundle_adjustments(monkeypatch):
    """``build_marker_map`` took no progress callback: a 41 s ``process --build-map`` stood
    still after the frames were read. Now it reports each step of its bundle adjustments (the
    first, then each moved marker's trials), each marker checked for a move and each marker and
    view of the first guesses' refinement, from inside them, to a total it reaches."""
    inside, calls = [None], []

    def spy(name, module=mapadjust):
        real = getattr(module, name)

        def spying(*args, **kwargs):
            inside[0] = name
            try:
                return real(*args, **kwargs)
            finally:
                inside[0] = None
        monkeypatch.setattr(module, name, spying)
    spy("bundle_adjust")
    spy("_moved")
    spy("_refine_initial", mapbuild)
    views, K = _room_views()
    built = mapbuild.build_marker_map(views, K, np.zeros(5), "DICT_4X4_50", 150.0, origin=0,
                             progress=lambda done, total: calls.append((done, total, inside[0])))
    assert [i for i, inf in built.info.items() if inf.flags] == [5]           # the moved marker was split
    assert sum(c[2] == "bundle_adjust" for c in calls) >= 10
    assert sum(c[2] == "_moved" for c in calls) >= 2 * len(built.marker_map.poses)   # searched twice at least
    refined = mapbuild.REFINE_ROUNDS * (len(built.marker_map.poses) + len(built.cameras))
    assert sum(c[2] == "_refine_initial" for c in calls) == refined
    done = [c[0] for c in calls]
    assert done == sorted(done) and all(0 < d <= t for d, t, _ in calls)
    assert calls[-1][0] == calls[-1][1] > mapadjust.MAX_ITER / 10              # the trials' steps counted too


def test_map_command_prints_lines_while_the_map_is_adjusted(real_data, every, monkeypatch, tmp_path):
    """``map`` (four real ChArUco photos) with its adjustment made slow (1 s): lines on stderr,
    not a terminal, name the stage at least every interval while it runs."""
    slow_down(monkeypatch, mapping, "build_marker_map")
    log = Log()
    monkeypatch.setattr(sys, "stderr", log)
    d = real_data / "opencv_aruco_charuco_tutorial"
    t0 = time.monotonic()
    assert main(["map", *[str(d / f"img_0{k}.jpg") for k in range(4)], "--camera",
                 str(d / "tutorial_camera_charuco.yml"), "--dict", "DICT_6X6_250", "--size-mm", "20", "-o",
                 str(tmp_path / "map.json")]) == 0
    lines = log.getvalue().splitlines()
    assert sum(ln.startswith("marker map: adjusting the map: ") for ln in lines) >= 4, lines
    assert lines[-1].startswith("marker map: done, "), lines
    assert max(_gaps(log.times, t0)) < 1.25 * every + 0.3, _gaps(log.times, t0)


def test_process_build_map_names_the_maps_adjustment_in_its_lines(every, monkeypatch, tmp_path):
    """``process --build-map`` (a 2 s simulated session without its marker map): the map was
    built without a progress callback, so a log showed only "tracking: still running" (or, before,
    nothing) while the map's adjustment ran; now its lines name it."""
    import json

    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.sim.simulate import simulate_scenario

    root = tmp_path / "s"
    simulate_scenario({"base": "lab-walkabout", "duration_s": 2.0, "calibration": {"camera_views": 0}}, root, seed=3,
                      resolution=(640, 360))
    man = json.loads((root / "session.json").read_text())
    del man["files"]["marker_map"]
    (root / "session.json").write_text(json.dumps(man))
    (root / "markers.json").unlink()
    slow_down(monkeypatch, mapping, "build_marker_map")
    log = Log()
    process_session(root, tmp_path / "out", camera=root / "truth" / "camera.json", eyes=root / "truth" / "eyes.json",
                    report=False, build_map=(200.0, "DICT_4X4_50"),
                    progress_factory=lambda name: progress_bar(name, 1, log))
    lines = log.getvalue().splitlines()
    assert sum(ln.startswith("tracking: adjusting the map: ") for ln in lines) >= 4, lines


def test_estimate_prints_lines_while_it_estimates(every, monkeypatch, tmp_path):
    """``estimate`` on a long view-line file printed nothing until its table; made slow here
    (1 s), its log shows "estimating: still running" every interval, and the table on stdout."""
    import wearable_gaze.pipeline.steps.estimate as estimate_module
    from wearable_gaze.formats.viewlines import write_viewlines_csv
    from wearable_gaze.sim.protocol import simulate_lines

    path = tmp_path / "lines.csv"
    write_viewlines_csv(path, simulate_lines([0, 0, 1500.0], np.random.default_rng(0)), segment=None)
    slow_down(monkeypatch, estimate_module, "estimate_file")
    log = Log()
    monkeypatch.setattr(sys, "stderr", log)
    assert main(["estimate", str(path)]) == 0
    lines = log.getvalue().splitlines()
    assert sum(ln.startswith("estimating: still running, ") for ln in lines) >= 4, lines
    assert lines[-1].startswith("estimating: done, ")


FIXATIONS = {"fixations": 1, "rows": 10, "unlabelled": 0, "rate_hz": None,
             "config": {"window": 5, "jump_deg": 2.0, "min_fixation_s": 0.1, "max_gap_s": 0.1}}
VIEWLINES = {"written": 10, "samples": 10, "no_pose": 0, "both_eyes_invalid": 0}


@pytest.mark.parametrize("argv, module, name, result, line", [
    (["fixations", "lines.csv", "-o", "fix.csv"], "wearable_gaze.pipeline.steps.segmentation", "fixations_file",
     FIXATIONS, "segmenting"),
    (["viewlines", "eye.csv", "--eyes", "eyes.json", "--poses", "poses.csv", "-o", "out.csv"],
     "wearable_gaze.pipeline.steps.calibrate", "viewlines_files", VIEWLINES, "view lines"),
    (["export-recording", "session", "-o", "rec", "--format", "tobii-g3"], "wearable_gaze.pipeline.importer",
     "export_recording", "wearable-gaze import rec", "exporting"),
])
def test_commands_over_a_whole_recording_print_lines_while_they_run(every, monkeypatch, tmp_path, argv, module,
                                                                     name, result, line):
    """``fixations``, ``viewlines`` and ``export-recording`` work through a whole recording in one
    call and printed nothing until their last line; made slow here (1 s), each prints a line
    every interval while it runs."""
    import importlib

    slow_down(monkeypatch, importlib.import_module(module), name, result=result)
    monkeypatch.chdir(tmp_path)
    log = Log()
    monkeypatch.setattr(sys, "stderr", log)
    assert main(argv) == 0
    lines = log.getvalue().splitlines()
    assert sum(ln.startswith(f"{line}: still running, ") for ln in lines) >= 4, lines
