import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wearable_gaze.cli import main
from wearable_gaze.formats.viewlines import REQUIRED, read_viewlines_csv, write_viewlines_csv
from wearable_gaze.sim.protocol import simulate_lines


@pytest.fixture
def csv_two_segments(tmp_path, rng):
    a = simulate_lines([0, 0, 1500.0], rng)
    b = simulate_lines([200, 0, 2500.0], rng)
    path = tmp_path / "lines.csv"
    from estimator import BinocularSamples
    both = BinocularSamples.concatenate([a, b])
    write_viewlines_csv(path, both, segment=["near"] * len(a) + [7] * len(b))
    return path


def _one_line_error(capsys):
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_csv_round_trip_keeps_samples(tmp_path, rng):
    s = simulate_lines([0, 0, 1000.0], rng)
    p = tmp_path / "x.csv"
    write_viewlines_csv(p, s)
    segs = read_viewlines_csv(p)
    assert len(segs) == 1 and segs[0].key is None
    got = segs[0].samples
    assert np.allclose(got.left_direction, s.left_direction, atol=1e-8)
    assert np.allclose(got.right_origin_mm, s.right_origin_mm, atol=1e-5)


def test_estimate_json_one_object_per_segment_in_order(csv_two_segments, capsys):
    assert main(["estimate", str(csv_two_segments), "--method", "ml", "--json"]) == 0
    out = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    assert [o["segment"] for o in out] == ["near", 7]
    assert all(o["method"] == "ml" and o["n_samples"] == 200 for o in out)
    assert abs(out[0]["position_mm"][2] - 1500) < 150 and abs(out[1]["position_mm"][2] - 2500) < 400
    assert np.array(out[0]["covariance_mm2"]).shape == (3, 3)


@pytest.mark.parametrize("method", ["lse", "ml", "voxel", "paper"])
def test_estimate_table_for_every_method(csv_two_segments, capsys, method):
    assert main(["estimate", str(csv_two_segments), "--method", method]) == 0
    out = capsys.readouterr().out
    assert "near" in out and method in out and "ok" in out


def test_export_density_writes_a_ply_per_segment(csv_two_segments, tmp_path, capsys):
    out = tmp_path / "dens.ply"
    assert main(["estimate", str(csv_two_segments), "--method", "voxel", "--export-density", str(out), "--json"]) == 0
    rows = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    from estimator._open3d import import_open3d
    for r in rows:
        pc = import_open3d().t.io.read_point_cloud(r["density_ply"])
        assert "density" in pc.point
        assert pc.point["density"].numpy().sum() == pytest.approx(1.0, rel=1e-3)


def test_monocular_rows_are_accepted(tmp_path, capsys):
    s = simulate_lines([0, 0, 1200.0], np.random.default_rng(1))
    p = tmp_path / "mono.csv"
    write_viewlines_csv(p, s)
    lines = p.read_text().splitlines()
    cells = lines[5].split(",")
    cells[1:7] = [""] * 6                        # left eye missing on one row
    lines[5] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    assert main(["estimate", str(p), "--method", "ml", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_samples"] == 200 and out["status"] == "ok"


def _write(tmp_path, text, name="bad.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


HEADER = ",".join(REQUIRED)
GOOD_ROW = "0,-32.5,0,0,0,0,1,32.5,0,0,0,0,1"


@pytest.mark.parametrize("text,expect", [
    ("", "empty"),
    ("t,left_ox\n0,1\n", "missing column(s) left_oy"),
    (HEADER + "\n" + GOOD_ROW.replace("-32.5", "abc", 1) + "\n", "line 2, column left_ox: 'abc' is not a number"),
    (HEADER + "\n" + GOOD_ROW + "\n" + "0.1,-32.5,0,0,0,0,0,32.5,0,0,0,0,1\n",
     "line 3, columns left_dx..left_dz: the direction is zero"),
    (HEADER + "\n" + "0,-32.5,,0,0,0,1,32.5,0,0,0,0,1\n", "line 2, column left_oy: empty"),
    (HEADER + "\n" + GOOD_ROW.replace("1", "inf", 1) + "\n", "not a finite number"),
    (HEADER + "\n", "no data rows"),
])
def test_bad_csv_gets_one_line_and_status_2(tmp_path, capsys, text, expect):
    p = _write(tmp_path, text)
    assert main(["estimate", str(p)]) == 2
    line = _one_line_error(capsys)
    assert expect in line and str(p) in line


def test_missing_file_and_bad_options(tmp_path, capsys, csv_two_segments):
    assert main(["estimate", str(tmp_path / "nope.csv")]) == 2
    assert "no such file" in _one_line_error(capsys)
    assert main(["estimate", str(csv_two_segments), "--method", "ml", "--export-density", "x.ply"]) == 2
    assert "--export-density needs --method voxel" in _one_line_error(capsys)
    with pytest.raises(SystemExit) as e:
        main(["estimate", str(csv_two_segments), "--sigma-deg", "-1"])
    assert e.value.code == 2
    assert "must be positive" in _one_line_error(capsys)
    with pytest.raises(SystemExit) as e:
        main(["estimate", str(csv_two_segments), "--method", "kalman"])
    assert e.value.code == 2
    assert "invalid choice" in _one_line_error(capsys)


def test_console_script_reports_bad_input_without_traceback(tmp_path):
    p = _write(tmp_path, "t,foo\n1,2\n")
    exe = Path(sys.executable).with_name("wearable-gaze")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "wearable_gaze.cli"]
    r = subprocess.run(cmd + ["estimate", str(p)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "missing column(s)" in r.stderr


def test_reproduce_figure5(tmp_path, capsys):
    assert main(["reproduce", "figure5", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "figure5_single_pairs.png").stat().st_size > 10000
    rows = [ln.split() for ln in out.splitlines() if ln.strip()[:4].isdigit()]
    stats = {float(r[0]): (float(r[1]), float(r[2]), float(r[3].rstrip("%"))) for r in rows}
    assert sorted(stats) == [1200.0, 1600.0, 2400.0, 3300.0]
    # the paper's finding: usable near 1.2 m, unreliable beyond 3 m
    assert abs(stats[1200.0][0] - 1200) < 0.25 * 1200
    rel_iqr = [stats[z][1] / z for z in sorted(stats)]
    assert all(a < b for a, b in itertools.pairwise(rel_iqr))
    assert rel_iqr[0] < 0.5 < rel_iqr[-1]          # spread below / above half the distance
    assert stats[1200.0][2] <= 5 and stats[3300.0][2] >= 10   # % of diverging pairs


def test_reproduce_table1_prints_all_columns_and_writes_figures(tmp_path, capsys):
    assert main(["reproduce", "table1", "--trials", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for col in ("paper proposed", "paper LSE", "lse mean z", "paper mean z", "voxel mean z", "ml mean z", "CRB"):
        assert col in out
    for name in ("table1.txt", "table1.json", "fig11_density_slices.png", "fig13_convergence.png"):
        assert (tmp_path / name).stat().st_size > 0
    data = json.loads((tmp_path / "table1.json").read_text())
    lse_z = [r["methods"]["lse"]["mean_mm"][2] for r in data["rows"]]
    assert lse_z[-1] < 0.5 * 5000                     # LSE biased toward the head at 5 m


# --- one validation mechanism for JSON files (wearable_gaze/formats/jsonio.py, wearable_gaze/formats/schemas) -----

def test_every_schema_is_valid_and_shipped_as_package_data():
    from importlib import resources

    from jsonschema import Draft202012Validator

    from wearable_gaze.formats.jsonio import SCHEMA_NAMES, schema

    shipped = {p.name for p in resources.files("wearable_gaze.formats").joinpath("schemas").iterdir()}
    assert shipped == {f"{n}.schema.json" for n in SCHEMA_NAMES}
    for n in SCHEMA_NAMES:
        Draft202012Validator.check_schema(schema(n))
        assert schema(n)["title"] and schema(n)["x-doc"]
    toml = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert '"wearable_gaze.formats" = ["schemas/*.schema.json"]' in toml and '"jsonschema>=4.18.0"' in toml


@pytest.fixture(scope="module")
def sim_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("schemas") / "s"
    assert main(["simulate", "-o", str(root), "--resolution", "320x180", "--duration", "1"]) == 0
    return root


def test_files_the_program_writes_pass_their_schemas(sim_session, tmp_path, capsys):
    """The schemas accept what the simulator, calibrate-camera and calibrate-eyes write (a schema
    stricter than the writers would refuse good sessions)."""
    from wearable_gaze.formats.jsonio import load_json, validate
    from wearable_gaze.sim.scenario import resolve

    s = sim_session
    load_json(s / "session.json", "session")
    load_json(s / "truth" / "camera.json", "camera")
    load_json(s / "markers.json", "marker-map")
    load_json(s / "calibration" / "camera" / "board.json", "board")
    load_json(s / "calibration" / "eye" / "walls.json", "walls")
    for name in ("paper-table1", "lab-walkabout", "moving-target", "calibration-only", "survey"):
        validate(resolve(name), "scenario", name)
    assert main(["calibrate-eyes", str(s), "--camera", str(s / "truth" / "camera.json"), "-o",
                 str(tmp_path / "eyes.json")]) == 0
    load_json(tmp_path / "eyes.json", "eyes")
    code = main(["calibrate-camera", str(s / "calibration" / "camera"), "--board", "chessboard:9x6:30", "-o",
                 str(tmp_path / "camera.json")])
    assert code == 0
    d = load_json(tmp_path / "camera.json", "camera")
    assert isinstance(d["trusted"], bool) and isinstance(d["warnings"], list)
    capsys.readouterr()


def test_load_json_names_file_field_expectation_and_fix(tmp_path):
    from wearable_gaze.errors import UserError
    from wearable_gaze.formats.jsonio import load_json

    p = tmp_path / "map.json"
    p.write_text(json.dumps({"dictionary": "DICT_4X4_50", "marker_size_mm": 200,
                             "markers": [{"id": 0, "T_world_from_marker": [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0],
                                                                           [0, 0, 0, 1]]}]}))
    with pytest.raises(UserError) as exc:
        load_json(p, "marker-map")
    msg = str(exc.value)
    assert msg.startswith(str(p)) and "'markers[0].T_world_from_marker[1]'" in msg
    assert "row of 4 numbers" in msg and "got 3 item(s)" in msg and "docs/session.md" in msg
    assert "\n" not in msg


def test_paths_in_a_session_must_stay_inside_it(sim_session, tmp_path):
    import shutil

    from wearable_gaze.errors import UserError
    from wearable_gaze.formats.session import load_session

    s = tmp_path / "s"
    shutil.copytree(sim_session, s)
    man = json.loads((s / "session.json").read_text())
    for rel in ("/etc/passwd", "../s/eye.csv", "truth/../../x", "/"):
        man["files"]["eye_samples"] = rel
        (s / "session.json").write_text(json.dumps(man))
        with pytest.raises(UserError) as exc:
            load_session(s)
        assert "files.eye_samples" in str(exc.value) and "root:" not in str(exc.value)
    man["files"]["eye_samples"] = "eye.csv"
    (s / "session.json").write_text(json.dumps(man))
    assert load_session(s).path("eye_samples") == s / "eye.csv"


def test_plainly_wrong_camera_calibration_is_marked_untrusted():
    from calibration.camera import CameraCalibration
    from wearable_gaze.pipeline.steps.calibrate import camera_json, format_camera_report, plausibility_warnings

    bad = CameraCalibration(np.array([[1304.0, 0, 640], [0, 469.0, 360], [0, 0, 1]]), np.zeros(5), (1280, 720),
                            "pinhole", 1.9, [], None)
    w = plausibility_warnings(bad)
    assert any("fx 1304 and fy 469" in x for x in w) and any("RMS 1.90 px" in x for x in w)
    d = camera_json(bad)
    assert d["trusted"] is False and d["warnings"] == w
    assert format_camera_report(bad).startswith("NOT TRUSTED: ")
    good = CameraCalibration(np.array([[900.0, 0, 640], [0, 902.0, 360], [0, 0, 1]]), np.zeros(5), (1280, 720),
                             "pinhole", 0.3, [], None)
    assert plausibility_warnings(good) == [] and camera_json(good)["trusted"] is True


# --- the CLI's safety net ------------------------------------------------------------------------

@pytest.mark.parametrize("errno_, fix", [(13, "not writable"), (28, "disk is full"), (21, "is a folder"),
                                          (20, "not a folder"), (17, "exists already"), (30, "read-only")])
def test_os_errors_on_output_are_one_line(monkeypatch, capsys, tmp_path, errno_, fix):
    import wearable_gaze.cli.track as cli

    def boom(args):
        raise OSError(errno_, os.strerror(errno_), str(tmp_path / "out.csv"))
    monkeypatch.setattr(cli, "cmd_markers", boom)
    code = main(["markers", "--ids", "0", "--size-mm", "50", "-o", str(tmp_path / "m.pdf")])
    assert code == 2
    line = _one_line_error(capsys)
    assert str(tmp_path / "out.csv") in line and fix in line


def test_an_unexpected_exception_is_a_bug_not_a_bad_input(monkeypatch, capsys, tmp_path):
    import wearable_gaze.cli.track as cli

    def bug(args):
        raise ZeroDivisionError("division by zero")
    monkeypatch.setattr(cli, "cmd_markers", bug)
    argv = ["markers", "--ids", "0", "--size-mm", "50", "-o", str(tmp_path / "m.pdf")]
    assert main(argv) == 1                                        # not 2: not the user's fault
    line = _one_line_error(capsys)
    assert "internal error" in line and "ZeroDivisionError" in line and "-v" in line
    with pytest.raises(ZeroDivisionError):
        main(["-v", *argv])


def test_parse_ids():
    from wearable_gaze.errors import UserError
    from wearable_gaze.pipeline.maps.sheets import parse_ids

    assert parse_ids("0-3,7,2") == [0, 1, 2, 3, 7]
    assert parse_ids(" 5 ") == [5]
    for bad in ("5-3", "-1", "", "a", "1-2-3", "0-99999999"):
        with pytest.raises(UserError):
            parse_ids(bad)


def test_progress_bar_draws_a_new_total_at_once(monkeypatch):
    """A batch learns its session count after the bar opens: the bar shows it before any step
    ends (it used to read 0/1 until the first session finished)."""
    import io
    import sys

    from wearable_gaze.progress import progress_bar

    class Tty(io.StringIO):
        def isatty(self):
            return True

    err = Tty()
    monkeypatch.setattr(sys, "stderr", err)
    with progress_bar("sessions", 1) as cb:
        cb(0, 8)
        assert "0/8" in err.getvalue()


def test_process_into_another_session_folder_is_refused(real_data, tmp_path, capsys):
    """``process A -o B`` with B a session folder (the real Aria sample imported twice) mixed
    process's outputs (poses.csv, viewlines.csv, report.html, ...) into session B; it is one line,
    exit status 2, and B is left as it was."""
    for name in ("a", "b"):
        assert main(["import", str(real_data / "aria_mps_sample_gen1"), "-o", str(tmp_path / name)]) == 0
    before = sorted(p.name for p in (tmp_path / "b").iterdir())
    capsys.readouterr()
    assert main(["process", str(tmp_path / "a"), "-o", str(tmp_path / "b")]) == 2
    line = _one_line_error(capsys)
    assert "is a session folder" in line and "SESSION/processed" in line
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == before


def test_an_imported_sessions_eye_rays_are_not_taken_for_view_lines(real_data, tmp_path, capsys):
    """eye_rays.csv has the view-line CSV's columns plus left_valid/right_valid, in the head frame.
    ``estimate`` and ``fixations`` read it as world view lines: on the real Aria sample (a walking
    head) ``estimate eye_rays.csv --one-point`` gave an 'ok' point in the head frame. Both refuse
    it in one line naming processed/viewlines.csv."""
    s = tmp_path / "s"
    assert main(["import", str(real_data / "aria_mps_sample_gen1"), "-o", str(s)]) == 0
    capsys.readouterr()
    for argv in (["estimate", str(s / "eye_rays.csv"), "--one-point"],
                 ["fixations", str(s / "eye_rays.csv"), "-o", str(tmp_path / "f.csv")]):
        assert main(argv) == 2
        line = _one_line_error(capsys)
        assert "eye-ray CSV" in line and "processed/viewlines.csv" in line
    assert not (tmp_path / "f.csv").exists()


def test_output_piped_into_a_reader_that_stops_is_no_error(csv_two_segments):
    """``wearable-gaze estimate ... --json | head -1`` (on the real Neon session's view lines)
    printed "cannot write or read ?: Broken pipe; check the path and try again" and exited 2, as if
    an input were bad. A reader that stops early is no error of ours: nothing on stderr, status
    141 (128 + SIGPIPE, what a shell reports for a writer the pipe stopped)."""
    exe = Path(sys.executable).with_name("wearable-gaze")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "wearable_gaze.cli"]
    p = subprocess.Popen(cmd + ["estimate", str(csv_two_segments), "--json"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.close()                                       # the reader is gone before the first line
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 141 and err == "", err
