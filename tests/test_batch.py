"""``wearable-gaze batch`` (issue 18): many sessions processed as ``process`` would, in parallel on
local worker processes or a Dask cluster; a corrupt session fails with its reason and the others
finish; a killed worker's session is done again elsewhere; an interrupted batch resumes without
redoing finished sessions; the batch report."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from wearable_gaze.cli import main
from wearable_gaze.formats.batch_status import read_status
from wearable_gaze.formats.tables import read_table
from wearable_gaze.pipeline.batch.run import BatchSettings, find_sessions, output_names, run_batch
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.sim.simulate import simulate_scenario

SCENARIO = {"base": "lab-walkabout", "duration_s": 5.0, "camera": {"resolution": [640, 360]},
            "targets": {"random_count": 2, "random_depth_mm": [700.0, 3000.0]}, "calibration": {"camera_views": 6}}
SETTINGS = BatchSettings(overlay=False, report=False)          # small and fast; the CLI test runs the report too
COMPARED = ("targets.json", "targets.csv", "poses.csv")
# the study: participant/session folders; same-named sessions in different folders; p03/s2 corrupt
LAYOUT = {"p01/s1": "a", "p01/s2": "b", "p02/s1": "a", "p02/s2": "b", "p03/s1": "a", "p03/s2": "corrupt"}
NAMES = {"p01/s1": "p01-s1", "p01/s2": "p01-s2", "p02/s1": "p02-s1", "p02/s2": "p02-s2", "p03/s1": "p03-s1",
         "p03/s2": "p03-s2"}


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """Two simulated sessions (a, b), each processed once by ``process_session`` (the reference),
    laid out as six sessions of three participants, one of them with a corrupt scene video."""
    base = tmp_path_factory.mktemp("batch")
    src, ref = {}, {}
    for key, seed in (("a", 5), ("b", 6)):
        src[key] = base / "src" / key
        simulate_scenario(SCENARIO, src[key], seed=seed)
        ref[key] = base / "ref" / key
        assert process_session(src[key], ref[key], **SETTINGS.process_kwargs()).exit_status == 0
    root = base / "study"
    for rel, key in LAYOUT.items():
        shutil.copytree(src["b" if key == "corrupt" else key], root / rel)
    (root / "p03" / "s2" / "scene.mp4").write_bytes(b"\x00" * 1000)
    return root, ref


def _assert_batch_outputs(res, out, ref, sessions=tuple(LAYOUT)):
    """The good ``sessions`` done with the outputs of a single process run, byte for byte; the
    corrupt one failed with its reason; the exit status says so."""
    assert list(res.statuses) == [NAMES[r] for r in sessions]
    for rel in sessions:
        name = NAMES[rel]
        st = res.statuses[name]
        assert st == read_status(out / name)                              # on disk as returned
        if LAYOUT[rel] == "corrupt":
            assert st["state"] == "failed" and "scene.mp4" in st["reason"] and "tracking" in st["reason"]
            continue
        assert st["state"] == "done" and st["n_targets"] == 2, st
        for f in COMPARED:
            assert (out / name / f).read_bytes() == (ref[LAYOUT[rel]] / f).read_bytes(), (name, f)
    assert res.failed == ["p03-s2"] and res.exit_status == 2
    index = json.loads((out / "batch.json").read_text())
    assert index["counts"] == {"pending": 0, "running": 0, "done": len(sessions) - 1, "partial": 0, "failed": 1}
    assert len({res.statuses[n]["worker"] for n in res.done}) >= 2            # both workers took sessions


def test_sessions_are_found_and_named_apart(tmp_path):
    for rel in ("a/p01/s1", "a/p02/s1", "a/p02/s2", "b/s1", "a/p01/s1/processed/x", "a/.hidden/s9"):
        (tmp_path / rel).mkdir(parents=True)
    for rel in ("a/p01/s1", "a/p02/s1", "a/p02/s2", "b/s1", "a/.hidden/s9"):
        (tmp_path / rel / "session.json").write_text("{}")
    found = find_sessions([tmp_path / "a", tmp_path / "b" / "s1", tmp_path / "a" / "p02"])
    assert found == sorted((tmp_path / r).resolve() for r in ("a/p01/s1", "a/p02/s1", "a/p02/s2", "b/s1"))
    names = output_names(found)
    assert sorted(names.values()) == ["b-s1", "p01-s1", "p02-s1", "s2"]
    # an earlier run's names are kept; a new session never takes one of them
    kept = output_names(found, {found[3]: "s1"})
    assert kept[found[3]] == "s1" and len(set(kept.values())) == 4
    with pytest.raises(Exception, match="no session folder"):
        find_sessions([tmp_path / "a" / "p01" / "s1" / "processed"])


def _killer(out: Path, pids=None):
    """An ``on_status`` callback: after the first session ends, SIGKILL the worker process of a
    session still running (one of ``pids()``, if given); what it did goes into the dict returned."""
    killed = {}

    def kill(status):
        if killed:
            return
        allowed = None if pids is None else pids()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60:
            for d in out.iterdir():
                st = read_status(d) if d.is_dir() else None
                pid = int(st["worker"].rsplit(":", 1)[1]) if st and st["state"] == "running" else None
                if pid is not None and pid != os.getpid() and (allowed is None or pid in allowed):
                    killed.update(name=d.name, pid=pid)
                    os.kill(pid, signal.SIGKILL)
                    return
            time.sleep(0.05)
        killed["name"] = None
    return kill, killed


@pytest.fixture(scope="module")
def local_batch(study, tmp_path_factory):
    """Participants p01 and p03 (four sessions, p03/s2 corrupt) on two local worker processes,
    one of them killed while processing a session."""
    root, _ = study
    out = tmp_path_factory.mktemp("local") / "out"
    seen = []
    kill, killed = _killer(out)
    res = run_batch([root / "p01", root / "p03"], out, SETTINGS, workers=2, progress=lambda d, n: seen.append((d, n)),
                    on_status=kill)
    return out, res, seen, killed


def test_local_batch_finishes_despite_a_corrupt_session_and_a_killed_worker(study, local_batch):
    root, ref = study
    out, res, seen, killed = local_batch
    _assert_batch_outputs(res, out, ref, ("p01/s1", "p01/s2", "p03/s1", "p03/s2"))
    assert seen[0] == (0, 4) and seen[-1] == (4, 4)
    assert killed.get("name"), "no session was running after the first one finished"
    st = res.statuses[killed["name"]]
    assert st["attempt"] == 2 and not st["worker"].endswith(f":{killed['pid']}")      # done again, elsewhere


def test_batch_report_tables_every_session_with_its_accuracy(study, local_batch):
    _, ref = study
    out, _, _, _ = local_batch
    rep = read_table(out / "batch_report.csv", ["n_targets", "truth_targets", "truth_found", "error_rms_mm",
                                                "recording_s", "processing_s"], ("session", "state", "reason"),
                     empty_ok=("truth_targets", "truth_found", "error_rms_mm"))
    assert list(rep["session"]) == ["p01-s1", "p01-s2", "p03-s1", "p03-s2"]
    done = rep["state"] == "done"
    assert list(rep["state"]) == ["done", "done", "done", "failed"] and "scene.mp4" in rep["reason"][3]
    assert (rep["truth_found"][done] == 2).all() and (rep["truth_targets"][done] == 2).all()
    assert (rep["error_rms_mm"][done] < 100).all() and (rep["recording_s"] == 5.0).all()
    assert (rep["processing_s"] > 0).all()
    targets = read_table(out / "all_targets.csv", ["x_mm", "y_mm", "z_mm", "crb_mm"], ("session", "status"))
    assert len(targets["x_mm"]) == 6 and set(targets["session"]) == set(rep["session"][done])
    a = json.loads((ref["a"] / "targets.json").read_text())["targets"]
    assert [round(t["position_mm"][0], 1) for t in a] == list(targets["x_mm"][targets["session"] == "p01-s1"])
    page = (out / "batch_report.html").read_text()
    assert "RMS error (mm)" in page and "processing (s)" in page and page.count("<tr") == 5
    assert "3 done, 1 failed" in page


def test_rerun_retries_the_failed_and_redoes_only_what_changed(study, local_batch):
    root, _ = study
    out, res, _, _ = local_batch
    mtimes = {n: (out / n / "targets.json").stat().st_mtime_ns for n in res.done}
    res2 = run_batch([root / "p01", root / "p03"], out, SETTINGS, workers=2)
    assert sorted(res2.skipped) == sorted(res.done) and res2.failed == ["p03-s2"]
    assert res2.statuses["p03-s2"]["started"] > res.statuses["p03-s2"]["finished"]         # retried
    assert {n: (out / n / "targets.json").stat().st_mtime_ns for n in res.done} == mtimes
    # a changed session is redone (process itself then skips its unchanged steps); the others not
    eye = root / "p01" / "s2" / "eye.csv"
    os.utime(eye, ns=(eye.stat().st_atime_ns, eye.stat().st_mtime_ns + 10**9))      # same data, "edited"
    res3 = run_batch([root / "p01", root / "p03"], out, SETTINGS, workers=1)
    assert sorted(res3.skipped) == ["p01-s1", "p03-s1"] and res3.statuses["p01-s2"]["state"] == "done"
    assert {"camera", "eyes", "tracking"} <= set(res3.statuses["p01-s2"]["steps_skipped"])
    assert "viewlines" not in res3.statuses["p01-s2"]["steps_skipped"]
    assert (out / "p01-s2" / "targets.json").stat().st_mtime_ns > mtimes["p01-s2"]


def test_dask_batch_survives_a_worker_killed_mid_session(study, tmp_path):
    distributed = pytest.importorskip("distributed", reason="Dask's distributed is not installed (pip install "
                                                           "'wearable-gaze[dask]'; the test extra has it)")
    root, ref = study
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:        # not the batch's client
        kill, killed = _killer(out, lambda: set(client.run(os.getpid).values()))
        res = run_batch([root], out, SETTINGS, scheduler=cluster.scheduler_address, on_status=kill)
    assert killed.get("name"), "no session was running after the first one finished"
    _assert_batch_outputs(res, out, ref)
    assert res.statuses[killed["name"]]["state"] == "done"
    assert not res.statuses[killed["name"]]["worker"].endswith(f":{killed['pid']}")    # done again elsewhere


def test_scheduler_without_dask_says_which_extra_to_install(study, tmp_path, monkeypatch, capsys):
    root, _ = study
    monkeypatch.setitem(sys.modules, "distributed", None)                # import distributed: ImportError
    assert main(["batch", str(root / "p01"), "-o", str(tmp_path / "out"), "--scheduler", "tcp://127.0.0.1:8786"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "wearable-gaze[dask]" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()                                 # nothing written
    assert main(["batch", str(tmp_path / "nothing"), "-o", str(tmp_path / "out")]) == 2
    assert "no such folder" in capsys.readouterr().err


def _wait_for(path: Path, cond, timeout=120.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            d = json.loads(path.read_text())
            if cond(d):
                return d
        except (OSError, ValueError):
            pass
        time.sleep(0.05)
    raise AssertionError(f"{path}: the condition did not hold within {timeout} s")


def test_interrupted_batch_resumes_without_redoing_finished_sessions(study, tmp_path):
    """Ctrl-C once a session is done: exit 130, no traceback, the sessions not finished back to
    pending; the same command again skips the finished ones (their files untouched) and does the
    rest. Three sessions, one worker: the Ctrl-C lands while one of the later two runs (with two,
    a loaded machine once let the second end before the signal was acted on)."""
    root, _ = study
    sessions = [str(root / r) for r in ("p02/s1", "p02/s2", "p03/s1")]
    out = tmp_path / "out"
    # Ctrl-C raises KeyboardInterrupt even where the tests run in the background (which ignores SIGINT)
    cmd = [sys.executable, "-c", "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
           "from wearable_gaze.cli import main; sys.exit(main())",
           "batch", *sessions, "-o", str(out), "--workers", "1", "--no-overlay"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(out / "batch.json", lambda d: d["counts"]["done"] >= 1)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr and "resume" in stdout and "Traceback" not in stderr, stderr
    index = json.loads((out / "batch.json").read_text())
    done = [s["name"] for s in index["sessions"] if s["state"] == "done"]
    c = index["counts"]
    assert 1 <= len(done) < 3 and c == {"pending": 3 - len(done), "running": 0, "done": len(done), "partial": 0,
                                        "failed": 0}, (
        index, stdout, stderr)                                   # the stopped session is pending again
    assert all(read_status(out / s["name"])["state"] == s["state"] for s in index["sessions"])
    mtimes = {n: [(out / n / f).stat().st_mtime_ns for f in ("targets.json", "report.html")] for n in done}
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert f"3 done ({len(done)} unchanged, skipped), 0 failed" in run.stdout
    assert {n: [(out / n / f).stat().st_mtime_ns for f in ("targets.json", "report.html")] for n in done} == mtimes
    assert json.loads((out / "batch.json").read_text())["counts"]["done"] == 3


def test_an_imported_session_is_processed_as_process_would(study, tmp_path):
    from wearable_gaze.formats.devices.common import SessionImport, read_simulated_recording

    root, _ = study
    sim = read_simulated_recording(root / "p01" / "s1")
    r = sim.rays
    with SessionImport(tmp_path / "imported" / "dev1", "test", root / "p01" / "s1") as imp:   # a device's rays, poses
        imp.add_rays(sim.t, r.left_origin_mm, r.left_direction, r.left_valid, r.right_origin_mm, r.right_direction,
                     r.right_valid)
        imp.add_head_poses(sim.t, sim.T_world_from_head)
        imp.finish(sim.eye_rate_hz, 12.5, "device", {"head": "the scene camera"})
    ref = process_session(tmp_path / "imported" / "dev1", tmp_path / "ref", **SETTINGS.process_kwargs())
    res = run_batch([tmp_path / "imported"], tmp_path / "out", SETTINGS, workers=1)
    assert res.done == ["dev1"] and res.statuses["dev1"]["n_targets"] == len(ref.found) > 0
    for f in COMPARED:
        assert (tmp_path / "out" / "dev1" / f).read_bytes() == (tmp_path / "ref" / f).read_bytes(), f


def test_a_stopped_pools_manager_thread_ends_without_a_traceback():
    """``LocalRunner.stop`` shuts the pool down without waiting, and its manager thread, meeting a
    worker's exit, counts workers the pool has let go of (``len(None)``): that TypeError, from that
    thread of that pool, is not printed; any other thread's exception, or another error, is."""
    import threading
    from types import SimpleNamespace

    from wearable_gaze.pipeline.batch.workers import _quiet_end

    seen = []
    previous, threading.excepthook = threading.excepthook, lambda args: seen.append((args.thread.name, args.exc_type))
    try:
        pool = SimpleNamespace(_processes=None)

        def count():
            len(pool._processes)

        def other():
            raise ValueError("a real fault")
        manager = threading.Thread(target=count, name="manager")
        bystander = threading.Thread(target=other, name="bystander")
        with _quiet_end(pool, manager):
            manager.start()
            bystander.start()
            bystander.join()
        again = threading.Thread(target=count, name="after")     # the hook is gone once the thread ended
        again.start()
        again.join()
    finally:
        threading.excepthook = previous
    assert seen == [("bystander", ValueError), ("after", TypeError)]


def test_an_internal_error_in_one_session_fails_that_session_and_the_batch_goes_on(study, tmp_path, monkeypatch):
    """A bug planted in one session's processing (a ``RuntimeError``, not a ``UserError``): that
    session is ``failed`` with ``internal error (...)`` as its reason and the traceback kept in
    its status; the other session is done with the outputs of a single ``process`` run; the batch
    neither crashes nor passes (exit status 2). The Dask cluster runs in this process (threads),
    so the planted fault reaches the worker."""
    distributed = pytest.importorskip("distributed", reason="Dask's distributed is not installed (pip install "
                                                           "'wearable-gaze[dask]'; the test extra has it)")
    from wearable_gaze.pipeline.process import session as process

    root, ref = study
    real = process.process_session

    def planted(session, out, **kwargs):
        if Path(session).parts[-2:] == ("p01", "s2"):
            raise RuntimeError("planted fault: index 7 is out of bounds")
        return real(session, out, **kwargs)

    monkeypatch.setattr(process, "process_session", planted)
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        res = run_batch([root / "p01"], out, SETTINGS, scheduler=cluster.scheduler_address)
    bad, good = res.statuses["s2"], res.statuses["s1"]
    assert bad["state"] == "failed" and bad == read_status(out / "s2"), bad
    assert bad["reason"].startswith("internal error (RuntimeError: planted fault: index 7 is out of bounds); "
                                    "this is a bug"), bad["reason"]
    assert "Traceback" in bad["traceback"] and "planted fault" in bad["traceback"]
    assert good["state"] == "done" and good["n_targets"] == 2, good
    for f in COMPARED:
        assert (out / "s1" / f).read_bytes() == (ref["a"] / f).read_bytes(), f
    assert res.failed == ["s2"] and res.done == ["s1"] and res.exit_status == 2
    counts = json.loads((out / "batch.json").read_text())["counts"]
    assert counts == {"pending": 0, "running": 0, "done": 1, "partial": 0, "failed": 1}


def test_run_session_reports_an_internal_error_as_that_session_failing(tmp_path, monkeypatch):
    """The worker itself (no pool): a planted ``ZeroDivisionError`` in ``process_session`` is
    returned and written as a failed status with the reason and traceback, not raised."""
    from wearable_gaze.formats.batch_status import LOCK_FILE
    from wearable_gaze.pipeline.batch.workers import SessionTask, run_session
    from wearable_gaze.pipeline.process import session as process

    def planted(session, out, **kwargs):
        raise ZeroDivisionError("planted: division by zero")

    monkeypatch.setattr(process, "process_session", planted)
    task = SessionTask("s", str(tmp_path / "session"), str(tmp_path / "out"), SETTINGS, "fp")
    st = run_session(task)
    assert st == read_status(tmp_path / "out")
    assert st["state"] == "failed" and st["reason"].startswith("internal error (ZeroDivisionError: planted"), st
    assert "ZeroDivisionError: planted: division by zero" in st["traceback"]
    assert not (tmp_path / "out" / LOCK_FILE).exists()                    # the session's lock released


def test_a_sessions_reason_is_one_printable_line_cut_to_its_length(tmp_path, monkeypatch):
    """A session's error that carries a terminal escape and newlines (a file name, a header) and
    runs long: its status's reason is one printable line (the escape shown, not sent, as the CLI's
    messages), cut to ``REASON_CHARS`` ending ``...``."""
    from wearable_gaze.errors import UserError
    from wearable_gaze.pipeline.batch.workers import REASON_CHARS, SessionTask, run_session
    from wearable_gaze.pipeline.process import session as process

    def planted(session, out, **kwargs):
        raise UserError("scene.mp4 \x1b[2J\x1b[31mred\n\tcannot be read: " + "x" * 1000)

    monkeypatch.setattr(process, "process_session", planted)
    st = run_session(SessionTask("s", str(tmp_path / "session"), str(tmp_path / "out"), SETTINGS, "fp"))
    reason = st["reason"]
    assert st["state"] == "failed" and reason.isprintable() and len(reason) == REASON_CHARS, reason
    assert reason.startswith(r"scene.mp4 \x1b[2J\x1b[31mred cannot be read: xxx") and reason.endswith("x...")


def test_without_max_tasks_per_child_each_pool_gets_one_session_per_worker(monkeypatch):
    """Python 3.10 has no ``max_tasks_per_child``: ``_pool`` leaves the keyword out there, and
    ``LocalRunner`` gives each pool at most one session per worker and replaces it, so that no worker
    runs two sessions (3.11 and later: one pool, which replaces each worker itself). The pools here
    record what they are given and answer at once."""
    import concurrent.futures
    from concurrent.futures import Future

    from wearable_gaze.pipeline.batch import workers as batch_workers

    pools = []

    class Pool:
        def __init__(self, size):
            self.size, self.given, self.shut = size, [], False
            pools.append(self)

        def submit(self, fn, task):
            self.given.append(task)
            fut = Future()
            fut.set_result({"state": "done"})
            return fut

        def shutdown(self, wait=True):
            self.shut = True

    monkeypatch.setattr(batch_workers, "_pool", Pool)
    for recycles, expected in ((False, [["a", "b"], ["c", "d"], ["e"]]), (True, [["a", "b", "c", "d", "e"]])):
        monkeypatch.setattr(batch_workers, "RECYCLES_WORKERS", recycles)
        pools.clear()
        done = list(batch_workers.LocalRunner(2).run(["a", "b", "c", "d", "e"]))
        assert sorted(t for t, _ in done) == ["a", "b", "c", "d", "e"]
        assert [p.given for p in pools] == expected and all(p.shut for p in pools), recycles
        assert [p.size for p in pools] == [min(2, len(g)) for g in expected]
    monkeypatch.undo()
    kwargs = []
    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", lambda *a, **k: kwargs.append(k))
    for recycles in (False, True):
        monkeypatch.setattr(batch_workers, "RECYCLES_WORKERS", recycles)
        batch_workers._pool(1)
    assert [k.get("max_tasks_per_child") for k in kwargs] == [None, 1]
