"""``live --device pupil-core://`` end to end (issue 29): a simulated session served by the Pupil
Core emulator on loopback, the live session's targets, its recording (every sample received,
read by ``process`` as an imported session: the same targets), a garbage message, and a device
killed and started again mid-session."""

import json
import re
import threading
import time

import numpy as np
import pytest

from tests.helpers import recorded_rays, run_live_device
from wearable_gaze.formats.fixations_table import read_fixations_csv
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.viewlines import read_viewlines_csv
from wearable_gaze.live.device_app import open_device_session
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.report.truth_match import match_targets
from wearable_gaze.sim.pupil_core_emu import PupilCoreEmulator, device_stream


@pytest.fixture(scope="module")
def session(device_session):
    """The simulated session both device tests serve (tests/conftest.py's ``device_session``)."""
    return device_session


def _sent_rays(emu, until=np.inf):
    """(k, (12,) both eyes' lines as sent) of every gaze message the emulator sent before ``until``
    (``time.monotonic()``)."""
    s = emu.stream
    nan = np.full(6, np.nan)
    return [(k, np.concatenate([s.left[k] if s.left_valid[k] else nan, s.right[k] if s.right_valid[k] else nan]))
            for t, k in emu.sent_log if t <= until]


def _assert_every_sample_from_the_first_kept(sent, rows, n_sent_before_end=None):
    """``rows`` are ``sent`` from the one matching ``rows[0]`` on, in order; none of the first
    ``n_sent_before_end`` sent (default all; those sent once the session had ended cannot be
    there) missing."""
    first = next(i for i, (_, v) in enumerate(sent) if np.allclose(v, rows[0], atol=2e-4, equal_nan=True))
    kept = np.array([v for _, v in sent[first:first + len(rows)]])
    assert len(kept) == len(rows) >= (len(sent) if n_sent_before_end is None else n_sent_before_end) - first
    assert np.allclose(kept, rows, atol=2e-4, equal_nan=True)


@pytest.fixture(scope="module")
def live_run(session, tmp_path_factory):
    base = tmp_path_factory.mktemp("pupil-live")
    junk = {90: [[b"gaze.3d.01.", b"\xc1 not msgpack"], [b"gaze.3d.01."]]}
    emu = PupilCoreEmulator(device_stream(session), inject=junk, log_sent=True)
    url = emu.listen()
    msgs, code, err = run_live_device(url, session, base / "rec")
    emu.stop()
    return base / "rec", msgs, code, err, emu


def test_live_from_pupil_core_finds_the_targets(session, live_run):
    _, msgs, code, err, _ = live_run
    assert code == 0, err
    est = [m for m in msgs if m["type"] == "estimate"]
    assert len(est) > 150
    lat = np.array([m["latency_ms"] for m in est])
    assert np.all(lat > 0) and np.median(lat) < 100        # from the device's sample time, on the local clock
    targets = [m for m in msgs if m["type"] == "target"]
    truth = json.loads((session / "truth" / "targets.json").read_text())["targets"]
    pairs = match_targets(targets, [t for t in truth if sum(b - a for a, b in t["fixations_s"]) >= 1.0])
    assert pairs and all(f is not None for _, f in pairs)
    for tt, f in pairs:
        m = next(x for x in targets if x["target"] == f["target"])
        assert np.linalg.norm(np.array(m["position_mm"]) - tt["position_mm"]) < 2.0 * max(m["ellipsoid95_radii_mm"])


def test_a_bad_message_is_one_line_and_counted(live_run):
    _, _, code, err, _ = live_run
    assert code == 0
    assert len([ln for ln in err.splitlines() if "bad gaze.3d.01. message" in ln]) == 1
    assert re.search(r"eye \d+ \(corrupt 2,", err)


def test_the_recording_holds_every_sample_received_and_process_finds_the_same_targets(live_run):
    rec, msgs, _, _, emu = live_run
    man = json.loads((rec / "session.json").read_text())
    assert man["complete"] and man["source"]["device"] == "pupil-core" and "eye_rays" in man["files"]
    t, rows = recorded_rays(rec)
    assert np.all(np.diff(t) > 0) and man["n_eye_samples"] == len(rows)
    _assert_every_sample_from_the_first_kept(_sent_rays(emu), rows)
    again = device_stream(rec)                       # a device recording plays again through the emulator
    assert np.allclose(np.hstack([again.left, again.right]), rows, equal_nan=True)
    assert len(again.frame_times) == man["n_frames"]
    res = process_session(rec, rec / "processed", report=False)
    # process re-runs on the head pose live gave each sample (live_poses.csv), not on a new
    # tracking of the video (which tracks frames live skipped): the same samples get view lines
    t_live, _, T_live, _ = read_poses_csv(rec / "live_poses.csv")
    t_off, _, T_off, _ = read_poses_csv(rec / "processed" / "poses.csv")
    assert np.array_equal(t_live, t_off) and np.allclose(T_live, T_off, equal_nan=True)
    posed = np.all(np.isfinite(T_live.reshape(len(T_live), -1)), axis=1)
    assert posed.sum() > 0.5 * len(rows) and res.summary["viewlines"]["written"] == posed.sum()
    assert np.isin(read_viewlines_csv(rec / "processed" / "viewlines.csv")[0].samples.t_s, t_live[posed]).all()
    live = {}
    for m in msgs:
        if m["type"] == "target":
            live[m["target"]] = m
    live = [m for m in live.values() if m["n_samples"] >= 60]
    offline = [x for x in res.targets if x["n_samples"] >= 60]
    assert live and offline
    for m in live:
        d = [np.linalg.norm(np.subtract(m["position_mm"], x["position_mm"])) for x in offline]
        j = int(np.argmin(d))
        assert d[j] < max(m["ellipsoid95_radii_mm"]) + max(offline[j]["ellipsoid95_radii_mm"])


def test_process_on_the_live_recording_gives_the_targets_live_published(live_run):
    """``process`` re-runs live's own online segmentation and streaming estimates on the samples
    live estimated, with their poses (pipeline/steps/live_replay.py): each target id live published
    comes back at the point of its last message, to the messages' rounding (0.1 mm a coordinate);
    offline segmentation and merged estimates put them 4.5-269 mm away."""
    rec, msgs, code, err, _ = live_run
    assert code == 0, err
    live = {}
    for m in msgs:
        if m["type"] == "target":
            live[m["target"]] = m
    assert len(live) >= 2
    res = process_session(rec, rec / "processed", report=False)
    offline = {x["target"]: x for x in res.targets}
    assert sorted(offline) == sorted(live)
    for i, m in live.items():
        assert np.abs(np.subtract(m["position_mm"], offline[i]["position_mm"])).max() <= 0.05 + 1e-9, i
        assert m["status"] == offline[i]["status"] and m["n_samples"] == offline[i]["n_samples"]
    fixations = read_fixations_csv(rec / "processed" / "fixations.csv")
    assert set(fixations["target_id"][fixations["target_id"] >= 0]) == set(live)


def test_a_device_killed_and_started_again_is_reconnected_and_nothing_received_is_lost(session, tmp_path):
    stream = device_stream(session)
    first = PupilCoreEmulator(stream, log_sent=True)
    url = first.listen()
    port = first.port
    live, link = open_device_session(url, session / "truth" / "camera.json", session / "markers.json",
                                     record=tmp_path / "rec", stdout=False)
    done = {}
    stop_reader = live.reader.stop
    def reader_stopped():                                     # when the session stops reading (its end;
        done["end"] = time.monotonic()                        # closing the recording comes after)
        stop_reader()
    live.reader.stop = reader_stopped
    def run():
        done["stats"] = live.run(5.5)
    th = threading.Thread(target=run)
    th.start()
    time.sleep(2.0)
    first.stop()                                              # the device goes away ...
    killed = time.monotonic()
    time.sleep(0.5)
    second = PupilCoreEmulator(stream, log_sent=True)         # ... and comes back on the same address
    second.listen("127.0.0.1", port)
    back = time.monotonic()
    th.join(15)
    link.close()
    second.stop()
    stats = done["stats"]
    assert stats.reconnects >= 1
    t, rows = recorded_rays(tmp_path / "rec")
    local = t + link.t0
    before, after = rows[local < killed], rows[local > back]
    assert len(before) + len(after) == len(rows)
    assert stats.eye_records == len(rows)                    # every sample received is recorded, and those
    _assert_every_sample_from_the_first_kept(_sent_rays(first), before, 0)   # before in order, none missing
    # (the last the device had queued when it died may never have left it: its sockets closed unsent)
    _assert_every_sample_from_the_first_kept(_sent_rays(second), after, len(_sent_rays(second, done["end"] - 0.5)))
    assert local[local > back][0] - back < 2.0                  # reconnected within 2 s
    assert len(after) > 100
