"""Pupil Core's network API (issue 29): the message layouts (``formats.devices.pupil_net``) and the
emulator (``sim.pupil_core_emu``) checked with a raw pyzmq client speaking Pupil's documented
protocol (Pupil Remote's requests, ``gaze.3d.01.`` and ``frame.world`` as Capture sends them),
and the live input's parts (clock sync, bad messages, the device URL)."""

import logging
import time

import cv2
import msgpack
import numpy as np
import pytest
import zmq

from wearable_gaze.errors import UserError
from wearable_gaze.formats.devices.pupil_net import (
    BadMessage,
    frame_message,
    gaze_message,
    parse_frame,
    parse_gaze,
)
from wearable_gaze.live.pupil_core_in import GazeReader, PupilCoreLink, open_link, parse_device_url, probe_frames
from wearable_gaze.sim.pupil_core_emu import DeviceStream, PupilCoreEmulator

W, H = 64, 48


def _line(o, target):
    d = np.subtract(target, o)
    return np.concatenate([o, d / np.linalg.norm(d)])


def _stream(tmp_path, n=200, rate=200.0, frames=20, fps=30.0) -> DeviceStream:
    """A small stream: both eyes looking at a point 1 m ahead, a grey-ramp video."""
    video = tmp_path / "scene.avi"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), fps, (W, H))
    for j in range(frames):
        out.write(np.full((H, W, 3), 10 * j % 250, np.uint8))
    out.release()
    t = np.arange(n) / rate
    left = np.tile(_line([-32.0, 30.0, -20.0], [0, 0, 1000.0]), (n, 1))
    right = np.tile(_line([32.0, 30.0, -20.0], [0, 0, 1000.0]), (n, 1))
    return DeviceStream(t, left, right, np.ones(n, bool), np.ones(n, bool), video, np.arange(frames) / fps)


def test_gaze_messages_round_trip_with_pupils_eye_numbering():
    left, right = _line([-32, 30, -20], [100, 0, 900]), _line([32, 30, -20], [100, 0, 900])
    topic, payload = gaze_message(12.5, left, right, 0.9)
    assert topic == b"gaze.3d.01."
    msg = msgpack.unpackb(payload, strict_map_key=False)
    assert msg["eye_centers_3d"][1] == pytest.approx(left[:3])          # eye1 is the LEFT eye
    assert msg["eye_centers_3d"][0] == pytest.approx(right[:3])
    assert msg["gaze_point_3d"] == pytest.approx([100, 0, 900], abs=1e-6)
    rec = parse_gaze(topic.decode(), payload)
    assert rec.t == 12.5 and rec.left_valid and rec.right_valid
    assert rec.left == pytest.approx(tuple(left)) and rec.right == pytest.approx(tuple(right))
    # Pupil Player's exports read the keys as strings too
    msg["eye_centers_3d"] = {str(k): v for k, v in msg["eye_centers_3d"].items()}
    msg["gaze_normals_3d"] = {str(k): v for k, v in msg["gaze_normals_3d"].items()}
    assert parse_gaze("gaze.3d.01.", msgpack.packb(msg)).left == pytest.approx(tuple(left))
    # one eye alone: gaze.3d.1. with the singular fields
    topic, payload = gaze_message(1.0, left, None)
    assert topic == b"gaze.3d.1."
    rec = parse_gaze(topic.decode(), payload)
    assert rec.left_valid and not rec.right_valid and np.isnan(rec.right).all()
    # under Pupil's confidence threshold neither eye is usable
    rec = parse_gaze("gaze.3d.01.", gaze_message(1.0, left, right, 0.3)[1])
    assert not rec.left_valid and not rec.right_valid


@pytest.mark.parametrize(("topic", "payload", "why"), [
    ("gaze.3d.01.", b"\xc1garbage", "not msgpack"),
    ("gaze.3d.01.", msgpack.packb([1, 2]), "not a map"),
    ("gaze.3d.01.", msgpack.packb({"confidence": 1.0}), "timestamp"),
    ("gaze.3d.01.", msgpack.packb({"timestamp": 1.0, "eye_centers_3d": {0: [0, 0, 0]},
                                   "gaze_normals_3d": {0: [0, 0, 1], 1: [0, 0, 1]}}), "eye_centers_3d has no eye 1"),
    ("gaze.3d.01.", msgpack.packb({"timestamp": 1.0, "eye_centers_3d": {0: [0, 0], 1: [0, 0, 0]},
                                   "gaze_normals_3d": {0: [0, 0, 1], 1: [0, 0, 1]}}, ), "3 finite numbers"),
    ("gaze.2d.01.", msgpack.packb({"timestamp": 1.0}), "not 3D gaze"),
])
def test_a_bad_gaze_message_says_why(topic, payload, why):
    with pytest.raises(BadMessage, match=why):
        parse_gaze(topic, payload)


def test_frame_messages_round_trip_and_bad_ones_say_why():
    img = np.random.default_rng(0).integers(0, 255, (H, W, 3), np.uint8)
    parts = frame_message(7, 3.25, img, "bgr")
    assert parts[0] == b"frame.world" and len(parts[2]) == W * H * 3
    fr = parse_frame(parts)
    assert fr.index == 7 and fr.t == 3.25 and np.array_equal(fr.image, img)
    smooth = np.dstack([*np.meshgrid(np.arange(W) * 3, np.arange(H) * 4), np.full((H, W), 90)]).astype(np.uint8)
    fr = parse_frame(frame_message(8, 3.5, smooth, "jpeg"))
    assert fr.image.shape == (H, W, 3) and np.abs(fr.image.astype(int) - smooth).mean() < 3
    with pytest.raises(BadMessage, match="bytes, not"):
        parse_frame(parts[:2] + [parts[2][:-1]])
    with pytest.raises(BadMessage, match="2 parts, not 3"):
        parse_frame(parts[:2])
    yuv = msgpack.packb({**msgpack.unpackb(parts[1]), "format": "yuv"})
    with pytest.raises(BadMessage, match="BGR or JPEG"):
        parse_frame([parts[0], yuv, parts[2]])


def _req(sock, *parts):
    sock.send_multipart([p if isinstance(p, bytes) else p.encode() for p in parts])
    assert sock.poll(2000)
    return sock.recv_string()


def test_the_emulator_speaks_pupils_documented_protocol(tmp_path):
    """A raw client, as Pupil's own helpers (pupil-helpers/python/filter_messages.py): Pupil Remote
    on REQ; gaze and frames on the SUB port; frames only once the Frame Publisher is started."""
    emu = PupilCoreEmulator(_stream(tmp_path))
    port = int(emu.listen().rsplit(":", 1)[1])
    ctx = zmq.Context()
    try:
        req = ctx.socket(zmq.REQ)
        req.connect(f"tcp://127.0.0.1:{port}")
        sub_port, pub_port = _req(req, "SUB_PORT"), _req(req, "PUB_PORT")
        assert sub_port.isdigit() and pub_port.isdigit() and sub_port != pub_port
        assert float(_req(req, "t")) == pytest.approx(time.monotonic() + emu.clock_s, abs=0.05)
        assert _req(req, "T 100.0") == "Timesync successful."
        assert float(_req(req, "t")) == pytest.approx(100.0, abs=0.05)
        assert _req(req, "what") == "Unknown command."
        sub = ctx.socket(zmq.SUB)
        sub.connect(f"tcp://127.0.0.1:{sub_port}")
        sub.setsockopt(zmq.SUBSCRIBE, b"gaze.3d.")
        sub.setsockopt(zmq.SUBSCRIBE, b"frame.world")
        got = {}
        end = time.monotonic() + 0.4
        while time.monotonic() < end:
            if sub.poll(50):
                parts = sub.recv_multipart()
                got.setdefault(parts[0], []).append(parts)
        assert b"gaze.3d.01." in got and b"frame.world" not in got    # no Frame Publisher yet
        note = msgpack.packb({"subject": "start_plugin", "name": "Frame_Publisher", "args": {"format": "bgr"}})
        assert _req(req, b"notify.start_plugin", note) == "Message forwarded."
        end = time.monotonic() + 0.3
        while time.monotonic() < end and b"frame.world" not in got:
            if sub.poll(50):
                parts = sub.recv_multipart()
                got.setdefault(parts[0], []).append(parts)
        topic, payload, image = got[b"frame.world"][0]
        fr = msgpack.unpackb(payload)
        assert {"width": W, "height": H, "format": "bgr"}.items() <= fr.items() and len(image) == W * H * 3
        assert fr["timestamp"] == pytest.approx(100.0, abs=1.0)           # Pupil time, as set by T
        g = msgpack.unpackb(got[b"gaze.3d.01."][-1][1], strict_map_key=False)
        assert set(g) >= {"eye_centers_3d", "gaze_normals_3d", "gaze_point_3d", "confidence", "timestamp"}
        assert set(g["eye_centers_3d"]) == {0, 1} and g["eye_centers_3d"][1][0] < 0 < g["eye_centers_3d"][0][0]
        assert np.linalg.norm(g["gaze_normals_3d"][0]) == pytest.approx(1.0)
    finally:
        ctx.destroy(linger=0)
        emu.stop()


def test_clock_sync_maps_pupil_time_to_the_local_clock(tmp_path):
    """The emulator's Pupil time is far from the local clock (``clock_s``): the link's offset
    brings a sample's time back to when it was sent, within the round trip."""
    emu = PupilCoreEmulator(_stream(tmp_path), clock_s=-12345.678)
    link = open_link(emu.listen())
    try:
        assert link.sync.offset_s == pytest.approx(12345.678, abs=link.sync.rtt_s + 1e-3)
        assert link.local_time(time.monotonic() - 12345.678) == pytest.approx(time.monotonic(), abs=0.01)
        assert probe_frames(link)[0] == (W, H) and emu.frame_format == "bgr"
    finally:
        link.close()
        emu.stop()


def test_bad_gaze_messages_are_counted_with_one_log_line(tmp_path, caplog):
    junk = [[b"gaze.3d.01.", b"\xc1junk"], [b"gaze.3d.01."], [b"gaze.3d.01.", msgpack.packb({"timestamp": "x"})]]
    emu = PupilCoreEmulator(_stream(tmp_path, n=100), inject={30: junk}, log_sent=True)
    link = open_link(emu.listen())
    seen = []
    reader = GazeReader(link, on_record=lambda t, rec: seen.append(t))
    with caplog.at_level(logging.WARNING, logger="wearable_gaze.live.pupil_core_in"):
        reader.start()
        emu.finished.wait(5)
        reader.stop()
        reader.join(2)
    link.close()
    emu.stop()
    assert reader.stats.corrupt == 3
    bad = [r for r in caplog.records if "bad" in r.getMessage()]
    assert len(bad) == 1 and "not msgpack" in bad[0].getMessage()
    assert len(seen) >= 90 and reader.stats.records == len(seen) and np.all(np.diff(seen) > 0)


def test_device_url_and_an_absent_device_are_one_line():
    assert parse_device_url("pupil-core://10.0.0.2") == ("10.0.0.2", 50020, "bgr")
    assert parse_device_url("pupil-core://10.0.0.2:5?frames=jpeg") == ("10.0.0.2", 5, "jpeg")
    with pytest.raises(UserError, match=r"optionally \?frames=jpeg"):
        parse_device_url("pupil-core://10.0.0.2:5?frames=yuv")
    with pytest.raises(UserError, match="expected pupil-core://HOST:PORT"):
        parse_device_url("neon://10.0.0.2:8080")
    with pytest.raises(UserError, match="did not answer"):
        open_link("pupil-core://127.0.0.1:9")
    assert PupilCoreLink("h", 1).where == "pupil-core://h:1"


@pytest.mark.parametrize(("extra", "says"), [
    (["--device", "tobii://127.0.0.1:8080"], "expected pupil-core://HOST:PORT or neon://HOST[:PORT]"),
    (["--device", "pupil-core://127.0.0.1:9"], "did not answer"),
    (["--device", "pupil-core://127.0.0.1:9", "--eyes", "eyes.json"], "drop --eyes"),
    (["--serial", "socket://127.0.0.1:9"], "--serial needs --camera and --eyes"),
])
def test_live_device_options_are_checked_in_one_line(tmp_path, capsys, extra, says):
    from wearable_gaze.cli import main
    from wearable_gaze.formats.camera import camera_dict, write_camera
    from wearable_gaze.formats.markermap import marker_map_dict, write_marker_map

    K = np.array([[300.0, 0, 32], [0, 300, 24], [0, 0, 1]])
    write_camera(tmp_path / "camera.json", camera_dict(K, np.zeros(5), (W, H)))
    write_marker_map(tmp_path / "map.json", marker_map_dict("DICT_4X4_50", 100.0, {0: np.eye(4)}))
    code = main(["live", *extra, "--camera-calib", str(tmp_path / "camera.json"), "--markers",
                 str(tmp_path / "map.json"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and says in err[0], err


def test_emulate_as_pupil_core_refuses_a_session_without_eye_rays_in_one_line(tmp_path, capsys):
    import json

    from wearable_gaze.cli import main

    s = _stream(tmp_path)                                # writes tmp_path/scene.avi
    (tmp_path / "scene_timestamps.csv").write_text("frame,t\n" + "".join(f"{i},{t:.6f}\n"
                                                                         for i, t in enumerate(s.frame_times)))
    (tmp_path / "eye.csv").write_text("t,counter,left_x,left_y,right_x,right_y,left_valid,right_valid\n")
    (tmp_path / "session.json").write_text(json.dumps({
        "format": "wearable-gaze-session", "version": 1, "has_recording": True,
        "files": {"scene_video": "scene.avi", "scene_timestamps": "scene_timestamps.csv", "eye_samples": "eye.csv"}}))
    assert main(["emulate", str(tmp_path), "--as", "pupil-core", "--listen", "127.0.0.1:0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no eye rays (eye_rays.csv) and not a simulated session" in err[0], err
    assert main(["emulate", str(tmp_path), "--as", "pupil-core", "--pty"]) == 2
    assert "drop --pty" in capsys.readouterr().err


def test_a_device_clock_set_mid_session_is_synced_again(tmp_path, caplog):
    """Pupil time set back by 5000 s mid-stream (another program's ``T``): the clock is synced
    again and the session times run on at the sample rate (without it they would all be stamped
    a microsecond after the last one before the jump)."""
    emu = PupilCoreEmulator(_stream(tmp_path, n=400))                  # 2 s at 200 Hz
    link = open_link(emu.listen())
    seen = []
    reader = GazeReader(link, on_record=lambda t, rec: seen.append(t))
    ctx = zmq.Context()
    try:
        with caplog.at_level(logging.WARNING, logger="wearable_gaze.live.pupil_core_in"):
            reader.start()
            time.sleep(0.8)
            req = ctx.socket(zmq.REQ)
            req.connect(f"tcp://127.0.0.1:{emu.port}")
            assert _req(req, f"T {emu.pupil_time() - 5000.0}") == "Timesync successful."
            emu.finished.wait(5)
            reader.stop()
            reader.join(2)
    finally:
        ctx.destroy(linger=0)
        link.close()
        emu.stop()
    t = np.array(seen)
    assert link.resyncs == 1 and len([r for r in caplog.records if "jumped by" in r.getMessage()]) == 1
    assert len(t) > 300 and np.all(np.diff(t) > 0)
    assert np.sum(np.diff(t) < 1e-3) <= 5                  # only messages in flight across the jump
    assert t[-1] - t[0] == pytest.approx(399 / 200.0, abs=0.1)


def test_jpeg_frames_on_request(tmp_path):
    emu = PupilCoreEmulator(_stream(tmp_path))
    link = open_link(emu.listen() + "?frames=jpeg")
    try:
        assert probe_frames(link)[0] == (W, H) and emu.frame_format == "jpeg"
    finally:
        link.close()
        emu.stop()
