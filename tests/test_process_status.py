"""What ``process`` and ``batch`` say a run came to (issue 25): a run with targets but a failed
step exits 3 (``partial``), not 0; a batch marks such a session ``partial`` and a session whose
worker met an internal error ``failed`` with its traceback."""

import json
import logging
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

import wearable_gaze.pipeline.process.session_steps as steps_mod
from wearable_gaze.cli import main
from wearable_gaze.errors import UserError
from wearable_gaze.formats.batch_status import (
    LOCK_FILE,
    process_start,
    read_status,
    release_lock,
    take_lock,
    this_process,
)
from wearable_gaze.pipeline.batch import workers as batch_workers
from wearable_gaze.pipeline.batch.run import BatchSettings, run_batch
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.sim.simulate import simulate_scenario

SMALL = {"base": "lab-walkabout", "duration_s": 4.0, "camera": {"resolution": [640, 360]}}
SETTINGS = BatchSettings(overlay=False)


@pytest.fixture(scope="module")
def small_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("status") / "session"
    simulate_scenario(SMALL, root, seed=0)
    return root


@pytest.fixture
def session(small_session, tmp_path):
    s = tmp_path / "study" / "s1"
    shutil.copytree(small_session, s)
    return s


def _plant_report_failure(monkeypatch):
    def fail(*args, **kwargs):
        raise UserError("planted: the report could not be written")
    monkeypatch.setattr(steps_mod, "write_report", fail)


def _in_process(monkeypatch):
    """Local batch sessions run in this process (so that a monkeypatch reaches them)."""
    def run(self, tasks):
        for t in tasks:
            yield t, batch_workers.run_session(t)
    monkeypatch.setattr(batch_workers.LocalRunner, "run", run)


def test_a_run_with_targets_and_a_failed_step_exits_partial(session, monkeypatch, capsys):
    _plant_report_failure(monkeypatch)
    rc = main(["process", str(session), "--no-overlay"])
    out, err = capsys.readouterr()
    assert rc == 3, (out, err)
    assert "FAILED: report" in out and "PARTIAL" in out and "planted" in err
    summary = json.loads((session / "processed" / "summary.json").read_text())
    assert summary["outcome"] == "partial" and summary["failed_steps"] == ["report"] and summary["targets"]
    assert not (session / "processed" / "report.html").exists()
    # the same session with nothing planted: 0, outcome ok
    monkeypatch.undo()
    res = process_session(session, overlay=False)
    assert res.exit_status == 0 and res.outcome == "ok" and res.skipped == ["camera", "eyes", "tracking", "viewlines",
                                                                           "targets", "export"]


def test_batch_marks_a_session_with_a_failed_step_partial(session, tmp_path, monkeypatch, capsys):
    _plant_report_failure(monkeypatch)
    _in_process(monkeypatch)
    res = run_batch([session.parent], tmp_path / "out", SETTINGS)
    st = res.statuses["s1"]
    assert st["state"] == "partial" and "planted" in st["reason"] and st["n_targets"] > 0, st
    assert st == read_status(tmp_path / "out" / "s1") and res.partial == ["s1"] and res.exit_status == 3
    index = json.loads((tmp_path / "out" / "batch.json").read_text())
    assert index["counts"]["partial"] == 1
    assert 'class="partial"' in (tmp_path / "out" / "batch_report.html").read_text()
    # the CLI: exit 3, the reason on stderr
    rc = main(["batch", str(session.parent), "-o", str(tmp_path / "out2"), "--no-overlay"])
    out, err = capsys.readouterr()
    assert rc == 3 and "s1 partial: report: planted" in err and "1 partial" in out, (out, err)


def test_an_internal_error_in_a_batch_session_fails_it_with_its_traceback(session, tmp_path, monkeypatch):
    def bug(*args, **kwargs):
        raise ZeroDivisionError("planted fault")
    monkeypatch.setattr(steps_mod, "find_targets", bug)
    _in_process(monkeypatch)
    res = run_batch([session.parent], tmp_path / "out", SETTINGS)
    st = read_status(tmp_path / "out" / "s1")
    assert res.statuses["s1"] == st and st["state"] == "failed" and res.exit_status == 2
    assert "internal error (ZeroDivisionError: planted fault)" in st["reason"] and "\n" not in st["reason"]
    assert "Traceback" in st["traceback"] and "in bug" in st["traceback"], st


# --- cached outputs are trusted by content ---------------------------------------------------------

def test_a_cached_output_cut_short_is_redone_with_a_line_saying_why(session, caplog):
    first = process_session(session, overlay=False)
    poses = session / "processed" / "poses.csv"
    whole = poses.read_bytes()
    lines = whole.splitlines(keepends=True)
    poses.write_bytes(b"".join(lines[:len(lines) // 2]))
    with caplog.at_level(logging.WARNING):
        again = process_session(session, overlay=False)
    why = [r.getMessage() for r in caplog.records if "redoing the step" in r.getMessage()]
    assert len(why) == 1 and "poses.csv changed since step 'tracking' wrote it" in why[0], why
    assert "tracking" not in again.skipped and again.exit_status == 0
    assert again.targets == first.targets and poses.read_bytes() == whole


@pytest.mark.parametrize("garbage", [b'{"samples": "\xe9"}', b"[" * 100000])
def test_a_viewlines_counts_file_not_utf8_or_nested_is_redone(session, caplog, garbage):
    first = process_session(session, overlay=False)
    (session / "processed" / ".viewlines_counts.json").write_bytes(garbage)
    with caplog.at_level(logging.WARNING):
        again = process_session(session, overlay=False)
    assert any(".viewlines_counts.json changed" in r.getMessage() for r in caplog.records)
    assert "viewlines" not in again.skipped and again.targets == first.targets and again.exit_status == 0
    assert again.summary["viewlines"] == first.summary["viewlines"]


def test_a_batch_session_that_lost_targets_json_is_not_done(session, tmp_path, monkeypatch):
    _in_process(monkeypatch)
    out = tmp_path / "out"
    assert run_batch([session.parent], out, SETTINGS).done == ["s1"]
    assert run_batch([session.parent], out, SETTINGS).skipped == ["s1"]
    (out / "s1" / "targets.json").unlink()
    res = run_batch([session.parent], out, SETTINGS)
    assert res.skipped == [] and res.done == ["s1"] and (out / "s1" / "targets.json").is_file()


def test_a_batch_output_folder_inside_one_of_its_sessions_is_refused(session, capsys):
    before = sorted(p.relative_to(session.parent) for p in session.parent.rglob("*"))
    for out in (session / "batch-out", session):
        rc = main(["batch", str(session.parent), "-o", str(out)])
        err = capsys.readouterr().err
        assert rc == 2 and len(err.strip().splitlines()) == 1 and "session.json" in err and "Traceback" not in err, err
        assert sorted(p.relative_to(session.parent) for p in session.parent.rglob("*")) == before


# --- a batch's workers and locks ---------------------------------------------------------------------

def _children(pid: int) -> list[int]:
    """The pids of ``pid``'s child processes (Linux /proc)."""
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                if int((p / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(p.name))
            except (OSError, IndexError, ValueError):
                pass
    return out


def _snapshot(out: Path) -> dict:
    return {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs Linux /proc to find the worker processes")
def test_workers_end_with_a_killed_coordinator(session, tmp_path):
    """SIGKILL the coordinator while a worker processes a session: the worker (and the rest of
    the coordinator's children) end within seconds, and nothing more is written into OUT."""
    shutil.copytree(session, session.parent / "s2")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "wearable_gaze", "batch", str(session.parent), "-o", str(out),
                             "--workers", "1", "--no-overlay"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0, worker = time.monotonic(), None
        while worker is None and time.monotonic() - t0 < 120 and proc.poll() is None:
            for d in out.glob("s*"):
                st = read_status(d)
                if st and st["state"] == "running":
                    worker = int(st["worker"].rsplit(":", 1)[1])
            time.sleep(0.05)
        assert worker is not None, "no session was seen running"
        children = _children(proc.pid)
        proc.kill()
        proc.wait()
        t0 = time.monotonic()
        while any(process_start(p) for p in [worker, *children]) and time.monotonic() - t0 < 10:
            time.sleep(0.1)
        left = [p for p in [worker, *children] if process_start(p)]
        assert not left, f"processes left running after their coordinator was killed: {left}"
        before = _snapshot(out)
        time.sleep(2.0)
        assert _snapshot(out) == before
    finally:
        proc.kill()


def test_a_session_locked_by_a_live_worker_is_not_processed_twice(session, tmp_path, monkeypatch):
    _in_process(monkeypatch)
    out = tmp_path / "out"
    (out / "s1").mkdir(parents=True)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock = out / "s1" / LOCK_FILE
        lock.write_text(f"{socket.gethostname()}:{other.pid}:{process_start(other.pid)}")
        res = run_batch([session.parent], out, SETTINGS)
        st = res.statuses["s1"]
        assert st["state"] == "running" and str(other.pid) in st["reason"], st
        assert not (out / "s1" / "targets.json").exists() and lock.is_file()
        # the owner is gone: its lock is stale, and the next batch does the session
        other.kill()
        other.wait()
        res = run_batch([session.parent], out, SETTINGS)
        assert res.done == ["s1"] and not lock.exists()
    finally:
        other.kill()
    assert take_lock(out / "s1") is None and take_lock(out / "s1") == this_process()    # held: by this process
    release_lock(out / "s1")
    assert not (out / "s1" / LOCK_FILE).exists()


# --- whatever a writer writes, its reader accepts ---------------------------------------------------

def test_a_writer_refuses_what_its_reader_would_and_a_path_covariance_in_mm2_is_read_back(tmp_path):
    """A still head's moving path has knots whose depth variance is 1e12 mm^2 (the second real G2
    recording): written and read back. A value its reader would refuse (not finite, or beyond
    the bound) is refused by the writer, with the file, column and row, and nothing written."""
    import numpy as np

    from wearable_gaze.formats.poses import read_poses_csv, write_poses_csv
    from wearable_gaze.formats.targets import read_target_paths, write_target_paths

    t = np.array([0.0, 0.1])
    pos = np.array([[10.0, 20.0, 860.0], [11.0, 21.0, 866.0]])
    cov = np.tile(np.diag([4.9e10, 1.6e11, 1.0e12]), (2, 1, 1))
    write_target_paths(tmp_path / "target_paths.csv", {0: (t, pos, cov)})
    back = read_target_paths(tmp_path / "target_paths.csv")[0]
    assert np.allclose(back[2], cov, rtol=1e-5) and np.allclose(back[1], pos)
    for bad, what in ((np.nan, "not a finite number"), (2e10, "beyond")):
        p = pos.copy()
        p[1, 2] = bad
        with pytest.raises(UserError, match=rf"bad_paths.csv: the target-path CSV .* column z, row 2, which is {what}"):
            write_target_paths(tmp_path / "bad_paths.csv", {0: (t, p, cov)})
        assert not (tmp_path / "bad_paths.csv").exists()
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, 0, 3] = 3e10
    with pytest.raises(UserError, match="column tx, row 2"):
        write_poses_csv(tmp_path / "poses.csv", t, [0, 1], T)
    T[1, 0, 3] = np.nan                                   # no pose: an empty cell, as the reader allows
    write_poses_csv(tmp_path / "poses.csv", t, [0, 1], T)
    assert np.isnan(read_poses_csv(tmp_path / "poses.csv")[2][1]).all()
