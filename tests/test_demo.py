"""``wearable-gaze demo`` (issue 17): its first line says where it writes (a fresh folder by
default), progress shows on stderr, a folder with earlier results is refused unless
``--reuse`` asks to use them (then nothing is simulated or recomputed), and the last line tells
how to open the report."""

import os
from datetime import datetime
from pathlib import Path

import pytest

from wearable_gaze.cli import main
from wearable_gaze.errors import UserError
from wearable_gaze.pipeline.demo import DEMO_PREFIX, demo_folder, fresh_folder, run_demo
from wearable_gaze.pipeline.process.stepcache import ON_REQUEST, STEPS

SHORT = {"seed": 0, "duration_s": 4.0, "resolution": (640, 360)}      # a short demo: ~10 s


def _tree(root: Path) -> dict:
    return {str(p): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("demo")
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    cwd = os.getcwd()
    os.chdir(base)
    try:
        with contextlib.redirect_stdout(out):
            code = run_demo(None, err=err, **SHORT)
    finally:
        os.chdir(cwd)
    return base, code, out.getvalue(), err.getvalue()


def test_first_line_names_a_fresh_folder_and_last_line_how_to_open_the_report(first_run):
    base, code, out, _ = first_run
    made = [p for p in base.iterdir()]
    assert len(made) == 1 and made[0].name.startswith(DEMO_PREFIX)
    folder = made[0]
    lines = out.strip().splitlines()
    assert code == 0
    assert lines[0] == f"wearable-gaze demo: writing into {folder}"
    report = folder / "processed" / "report.html"
    assert report.is_file()
    assert lines[-1] == f"open the report in a browser: {report.as_uri()}"
    assert (folder / "session" / "session.json").is_file()


def test_progress_shows_on_stderr_step_by_step(first_run):
    _, _, out, err = first_run
    lines = err.strip().splitlines()
    assert all(ln.startswith("demo: ") for ln in lines), lines
    for what in ("simulating 4 s", "calibrating the scene camera", "tracking the head", "fixations and 3D targets",
                 "plots, overlay and report"):
        assert any(what in ln and ln.endswith("...") for ln in lines), what          # when it starts
        assert any(what in ln and " done (" in ln for ln in lines), what             # and when it ends
    assert not any(ln.startswith("demo: ") for ln in out.splitlines())     # progress apart from the results


def test_a_folder_with_results_is_refused_without_reuse_and_reused_with_it(first_run, capsys):
    base, _, _, _ = first_run
    folder = next(base.iterdir())
    before = _tree(folder)
    code = main(["demo", "--out", str(folder), "--duration", "4"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--reuse" in err[0] and str(folder) in err[0], err
    assert _tree(folder) == before                                 # refused before any work
    code = run_demo(folder, reuse=True, **SHORT)
    cap = capsys.readouterr()
    lines = cap.out.strip().splitlines()
    assert code == 0
    assert lines[0] == f"wearable-gaze demo: writing into {folder} (reusing its earlier results)"
    assert lines[-1] == f"open the report in a browser: {(folder / 'processed' / 'report.html').as_uri()}"
    assert "simulating" not in cap.err
    assert f"reused, not redone: {', '.join(s for s in STEPS if s not in ON_REQUEST)}" in cap.err
    after = _tree(folder)
    session = [p for p in before if "/session/" in p]
    assert all(after[p] == before[p] for p in session)            # the session was not simulated again
    assert after[str(folder / "processed" / "targets.json")] == before[str(folder / "processed" / "targets.json")]


def test_reuse_of_another_demo_or_without_a_folder_is_refused(first_run):
    base, _, _, _ = first_run
    folder = next(base.iterdir())
    with pytest.raises(UserError, match="seed 0 and 4 s, not seed 5 and 4 s"):
        demo_folder(folder, True, 5, 4.0)
    with pytest.raises(UserError, match="--reuse needs --out"):
        demo_folder(None, True, 0, 4.0)
    other = base / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="holds no demo session"):
        demo_folder(other, True, 0, 4.0)
    assert demo_folder(base / "new", True, 0, 4.0) == (base / "new", False)   # nothing to reuse: a fresh run
    with pytest.raises(UserError, match="is not empty"):
        demo_folder(other, False, 0, 4.0)                            # someone's files: never written into
    (other / "notes.txt").unlink()
    other.rmdir()


def test_a_second_default_run_gets_a_folder_of_its_own(tmp_path):
    now = datetime(2026, 12, 2, 4, 5, 6)
    first = fresh_folder(tmp_path, now)
    assert first == tmp_path / "wearable-gaze-demo-20261202-040506"
    first.mkdir()
    second = fresh_folder(tmp_path, now)
    assert second == tmp_path / "wearable-gaze-demo-20261202-040506-2" and not second.exists()
    out, reusing = demo_folder(None, False, 0, 4.0, base=tmp_path)
    assert not reusing and not out.exists() and out.parent == tmp_path and out.name.startswith(DEMO_PREFIX)
