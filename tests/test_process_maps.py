"""``process``'s map options and the options that cannot apply (issue 25, "A new lab's first day"):
``--markers MAP`` tracks in a map from ``map``; ``--build-map`` on a session that has a map builds
and uses the new one, saying so; a simulated session's truth is moved into the world of the map
used before any comparison (``truth_match.TruthFrame``); an option that does nothing for the
session says so in one line and changes nothing else."""

import html
import json
import re

import numpy as np
import pytest

from estimator.frames import rotation_about_axis, similarity_transform
from wearable_gaze.cli import main
from wearable_gaze.formats.devices.common import SessionImport, read_simulated_recording
from wearable_gaze.formats.markermap import load_marker_map, marker_map_dict, write_marker_map
from wearable_gaze.pipeline.batch.run import BatchSettings, session_fingerprint
from wearable_gaze.pipeline.batch.summary import truth_errors
from wearable_gaze.pipeline.process.options import markerless_corners
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.report.truth_match import TruthFrame, fit_truth_frame
from wearable_gaze.sim.simulate import simulate_scenario

WALLS = [{"distance_mm": 1000.0, "grid": [3, 3], "tilt_deg": 12.0},
         {"distance_mm": 2000.0, "grid": [3, 3], "tilt_deg": 6.0}]
SCENARIO = {"base": "lab-walkabout", "duration_s": 8.0, "targets": {"random_count": 2},
            "calibration": {"camera_views": 0, "walls": WALLS, "dwell_s": 1.0}}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """An 8 s walkabout at 960x540 (seed 3) processed with its own, true map: (session folder,
    the keyword arguments every run here uses, the ``ProcessResult``)."""
    root = tmp_path_factory.mktemp("maps") / "s"
    simulate_scenario(SCENARIO, root, seed=3, resolution=(960, 540))
    kw = {"camera": root / "truth" / "camera.json", "overlay": False}
    return root, kw, process_session(root, root.parent / "true", **kw, report=False)


def _shift() -> np.ndarray:
    """A rigid transform of a room's world: turned 20 deg about y, moved by (400, -100, 250) mm."""
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis([0, 1, 0], np.radians(20))
    T[:3, 3] = [400.0, -100.0, 250.0]
    return T


def _report_errors(out) -> list:
    """Each target row's error (mm) of report.html's table, or its text where it has none."""
    page = html.unescape((out / "report.html").read_text(encoding="utf-8"))
    table = page[page.index('<table id="targets">'):page.index("</table>")]
    return [(re.findall(r"<td>(.*?)</td>", row) or [""])[-5:] for row in re.findall(r"<tr>(.*?)</tr>", table)[1:]]


def test_the_truth_is_moved_by_the_similarity_through_the_shared_markers(rng):
    """The fit recovers a known similarity (scale too) from the corners both maps share, leaves
    out the moved ones, says when there is nothing to move (the same map) or no shared marker."""
    truth = {i: rng.normal(0, 1000, (4, 3)) for i in range(5)}
    T = _shift()
    T[:3, :3] *= 1.02
    used = {i: c @ T[:3, :3].T + T[:3, 3] for i, c in truth.items() if i != 4}
    used[3] = used[3] + 50.0                                      # a marker moved during the session
    frame = fit_truth_frame(truth, used, "built", exclude=[3])
    np.testing.assert_allclose(frame.T_map_from_truth, T, atol=1e-9)
    assert frame.markers == (0, 1, 2) and frame.rms_mm < 1e-9 and abs(frame.scale - 1.02) < 1e-12
    moved = frame.targets([{"index": 0, "position_mm": [1.0, 2.0, 3.0]}, {"index": 1, "path_mm": [[0, 0, 0]] * 2}])
    np.testing.assert_allclose(moved[0]["position_mm"], T[:3, :3] @ [1.0, 2.0, 3.0] + T[:3, 3])
    np.testing.assert_allclose(moved[1]["path_mm"], [T[:3, 3]] * 2)
    head = np.stack([_shift(), np.full((4, 4), np.nan)])                               # a pose, and none
    got = frame.poses(head)
    np.testing.assert_allclose(got[0, :3, 3], T[:3, :3] @ head[0, :3, 3] + T[:3, 3])
    np.testing.assert_allclose(got[0, :3, :3], T[:3, :3] / 1.02 @ head[0, :3, :3], atol=1e-12)
    assert np.isnan(got[1]).all()
    again = TruthFrame.from_record(json.loads(json.dumps(frame.record())))
    np.testing.assert_allclose(again.T_map_from_truth, T, atol=1e-8)
    assert "3 marker(s)" in frame.note() and "scale 1.0200" in frame.note()
    assert fit_truth_frame(truth, dict(truth), "given") is None                      # the truth's own map
    none = fit_truth_frame(truth, {9: truth[0]}, "markerless")
    assert none.T_map_from_truth is None and "shares no marker" in none.note()
    # a markerless map: the corners it records, or its origin marker's square, or none (a distance)
    assert markerless_corners({"scaled_by": {"kind": "marker", "markers": [7], "size_mm": 100.0}})[7][2].tolist() == \
        [50.0, 50.0, 0.0]
    assert list(markerless_corners({"scaled_by": {"kind": "marker_map", "corners_mm": {"4": truth[4].tolist()}}})) \
        == [4]
    assert markerless_corners({"scaled_by": {"kind": "distance"}}) is None


def test_markers_option_tracks_in_the_given_map(session, tmp_path):
    """The true map moved rigidly (``_shift``) and given with ``--markers``: the targets come out
    moved by the same transform, the truth is moved into that world (the fit finds the shift,
    the errors are the true map's), and the same map given again as a copy of the truth's is the
    truth's frame (nothing moved) with tracking redone for the changed map."""
    root, kw, base = session
    true_map, T = load_marker_map(root / "markers.json"), _shift()
    write_marker_map(tmp_path / "lab.json", marker_map_dict(true_map.dictionary, true_map.marker_size_mm,
                                                             {i: T @ P for i, P in true_map.poses.items()}))
    res = process_session(root, tmp_path / "out", **kw, markers=tmp_path / "lab.json")
    assert res.problems == [] and len(res.found) == len(base.found) >= 2
    for got, want in zip(res.found, base.found, strict=True):
        assert np.linalg.norm(got.position_mm - (T[:3, :3] @ want.position_mm + T[:3, 3])) < 2.0
    frame = res.summary["truth_frame"]
    assert frame["map"] == "given" and frame["rms_mm"] < 0.01
    np.testing.assert_allclose(frame["T_map_from_truth"], T, atol=1e-4)
    errors = [float(r[1]) for r in _report_errors(tmp_path / "out")]
    assert len(errors) == len(res.found) and max(errors) < 100.0, errors
    assert "world of the marker map given (--markers)" in (tmp_path / "out" / "report.html").read_text()
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["truth_frame"]["map"] == "given"
    # the session's own map given as a file: the truth's frame, and tracking redone for it
    (tmp_path / "lab.json").write_bytes((root / "markers.json").read_bytes())
    again = process_session(root, tmp_path / "out", **kw, markers=tmp_path / "lab.json")
    assert "tracking" not in again.skipped and "truth_frame" not in again.summary
    for got, want in zip(again.found, base.found, strict=True):
        assert np.linalg.norm(got.position_mm - want.position_mm) < 2.0
    assert (tmp_path / "lab.json").is_file()


def test_build_map_on_a_session_with_a_map_builds_and_uses_it(session, tmp_path, capsys):
    """``process --build-map`` on a session that has markers.json was silently ignored; it builds
    the map, tracks in it, says so in one line, and the report compares the targets with the
    truth moved into the built map's world (before: every estimate "no true target near", every
    true target "not found")."""
    root, kw, base = session
    out = tmp_path / "out"
    argv = ["process", str(root), "-o", str(out), "--camera", str(kw["camera"]), "--no-overlay", "--build-map",
            str(load_marker_map(root / "markers.json").marker_size_mm)]
    assert main(argv) == 0
    cap = capsys.readouterr()
    assert [ln for ln in cap.err.splitlines() if "--build-map" in ln] == [
        "wearable-gaze process: --build-map: the session's own marker map (markers.json) is not used: the map built "
        "from its video is (OUT/built_map.json)"], cap.err
    built = load_marker_map(out / "built_map.json")
    origin = next(i for i, P in built.poses.items() if np.allclose(P, np.eye(4)))
    assert not np.allclose(load_marker_map(root / "markers.json").poses[origin], np.eye(4))    # its own world
    summary = json.loads((out / "summary.json").read_text())
    assert summary["truth_frame"]["map"] == "built" and summary["truth_frame"]["rms_mm"] < 10.0
    assert len(summary["truth_frame"]["markers"]) >= 4
    rows = _report_errors(out)
    page = (out / "report.html").read_text()
    assert "no true target near" not in page and "not found" not in page
    errors = [float(r[1]) for r in rows]
    assert len(errors) == len(base.found) and max(errors) < 100.0, errors
    assert "world of the map built from the video (--build-map)" in html.unescape(page)


def test_an_option_that_cannot_apply_says_so_and_changes_nothing(session, tmp_path, capsys):
    """An imported session without a scene video (the device's own head poses): ``--overlay-video``
    redid the report and said nothing; now one line says it does nothing and every step stays
    cached; so do ``--no-overlay``, ``--build-map`` and ``--eyes``."""
    root = session[0]
    sim = read_simulated_recording(root)
    r = sim.rays
    s = tmp_path / "s"
    with SessionImport(s, "test", root) as imp:
        imp.add_rays(sim.t, r.left_origin_mm, r.left_direction, r.left_valid, r.right_origin_mm, r.right_direction,
                     r.right_valid)
        imp.add_head_poses(sim.t, sim.T_world_from_head)
        imp.finish(sim.eye_rate_hz, 0.0, "device", {"head": "the scene camera"})
    assert main(["process", str(s)]) == 0
    first = capsys.readouterr()
    assert "wearable-gaze process:" not in first.err
    for opt, needle in ((["--overlay-video"], "--overlay-video: no overlay is written for this session (it has no "
                                             "scene video)"),
                        (["--no-overlay"], "--no-overlay: there is no overlay to leave out"),
                        (["--build-map", "200"], "--build-map: not used: the session's video is not tracked (its head "
                                                 "poses are the device's)"),
                        (["--eyes", str(s / "nothing.json")], "--eyes: not used")):
        assert main(["process", str(s), *opt]) == 0, opt
        cap = capsys.readouterr()
        lines = [ln for ln in cap.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and needle in lines[0], (opt, cap.err)
        assert "unchanged, not redone: tracking, viewlines, targets, export, report" in cap.out, (opt, cap.out)
        assert json.loads((s / "processed" / "summary.json").read_text())["notes"] == [lines[0].split(": ", 1)[1]]


@pytest.mark.parametrize("extra, needle", [
    (["--markers", "{t}/bad.json"], "bad.json"),
    (["--markers", "{t}/none.json"], "--markers"),
    (["--markers", "{t}/m.json", "--build-map", "200"], "give one"),
    (["--markers", "{t}/m.json", "--map", "{t}"], "give one"),
    (["--overlay-video", "--no-overlay"], "give one of them"),
    (["--map-dict", "DICT_5X5_50"], "give --build-map too"),
])
def test_contradicting_options_and_a_bad_map_get_one_line(session, tmp_path, capsys, extra, needle):
    root = session[0]
    (tmp_path / "bad.json").write_text('{"format": "wearable-gaze-marker-map"}')
    (tmp_path / "m.json").write_bytes((root / "markers.json").read_bytes())
    before = sorted(p.name for p in root.iterdir())
    argv = ["process", str(root), "-o", str(tmp_path / "out"), *[a.format(t=tmp_path) for a in extra]]
    assert main(argv) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and needle in err[0], err
    assert sorted(p.name for p in root.iterdir()) == before and not (tmp_path / "out" / "poses.csv").exists()


def test_batch_passes_the_map_through_and_its_report_moves_the_truth(tmp_path):
    """``batch --markers``: every session gets it, and a changed map changes each session's
    fingerprint (redone); the batch report's accuracy moves the truth into the map's world
    (``summary.json``'s ``truth_frame``)."""
    m = tmp_path / "m.json"
    m.write_text("{}")
    (tmp_path / "s").mkdir()
    settings = BatchSettings(markers=str(m))
    assert settings.process_kwargs()["markers"] == str(m)
    before = session_fingerprint(tmp_path / "s", settings)
    m.write_text('{"changed": 1}')
    assert session_fingerprint(tmp_path / "s", settings) != before
    # the report's truth errors: estimates in a world moved by T, the truth moved by the same T
    (tmp_path / "s" / "truth").mkdir()
    truth = [{"index": 0, "position_mm": [100.0, 0.0, 1500.0], "fixations_s": [[0, 2]]},
             {"index": 1, "position_mm": [-400.0, 200.0, 2500.0], "fixations_s": [[3, 5]]}]
    (tmp_path / "s" / "truth" / "targets.json").write_text(json.dumps({"version": 1, "targets": truth}))
    T = similarity_transform(np.eye(3), np.eye(3) @ _shift()[:3, :3].T + [5000.0, 0.0, -3000.0])
    rows = [{"target": k, "position_mm": (T[:3, :3] @ t["position_mm"] + T[:3, 3] + 3.0).tolist(), "crb_mm": 10.0}
            for k, t in enumerate(truth)]
    got = truth_errors(tmp_path / "s", rows, TruthFrame("built", T, 0.5, (0,)))
    assert got["truth_found"] == 2 and abs(got["error_max_mm"] - np.sqrt(27.0)) < 1e-6
    assert truth_errors(tmp_path / "s", rows)["truth_found"] == 0                     # not moved: nothing near


@pytest.mark.parametrize("extra, needle", [(["--markers", "{t}/m.json", "--build-map", "200"], "give one"),
                                           (["--map-dict", "DICT_5X5_50"], "give --build-map too"),
                                           (["--markers", "{t}/none.json"], "no such file")])
def test_batch_refuses_the_same_before_any_session(tmp_path, capsys, extra, needle):
    (tmp_path / "m.json").write_text("{}")
    (tmp_path / "s").mkdir()
    argv = ["batch", str(tmp_path / "s"), "-o", str(tmp_path / "out"), *[a.format(t=tmp_path) for a in extra]]
    assert main(argv) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and needle in err[0], err
    assert not (tmp_path / "out").exists()
