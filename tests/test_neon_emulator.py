"""The Neon emulator (issue 29) against Pupil Labs' own client, ``pupil-labs-realtime-api``, unmodified:
its status (HTTP and websocket), an event, the Time Echo clock offset, the gaze with eye states and
the H.264 scene video, each checked against the session it plays. And the wire layouts of
``formats.devices.neon_rtp`` against the client's parsers."""

import asyncio
import struct
import time

import cv2
import numpy as np
import pytest

from wearable_gaze.formats.devices import neon_rtp
from wearable_gaze.formats.devices.pupil_net import _nearest_point
from wearable_gaze.sim.neon_emu import NeonEmulator, session_camera
from wearable_gaze.sim.pupil_core_emu import device_stream
from wearable_gaze.sim.simulate import simulate_scenario

rt = pytest.importorskip("pupil_labs.realtime_api", reason="the [neon] extra (pupil-labs-realtime-api) is not "
                                                            "installed: pip install 'wearable-gaze[neon]'")
from pupil_labs.realtime_api.streaming.base import RTSPData  # noqa: E402
from pupil_labs.realtime_api.streaming.gaze import EyestateEyelidGazeData  # noqa: E402
from pupil_labs.realtime_api.time_echo import TimeOffsetEstimator  # noqa: E402


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("neon-emu") / "session"
    simulate_scenario({"base": "lab-walkabout", "duration_s": 4.0, "targets": {"random_count": 1},
                       "camera": {"resolution": [640, 360]}, "calibration": {"camera_views": 0}}, root, seed=5)
    return root


async def _client_run(host, port, n_gaze=120, n_frames=20):
    """What the client receives: status, websocket components, an event, the clock offset, gaze and
    frames (the two streams at once, as a live session reads them)."""
    async with rt.Device(host, port) as dev:
        status = await dev.get_status()
        comps = []

        async def updates():
            async for c in dev.status_updates():
                comps.append(c)
                if len(comps) == 4:
                    return
        await asyncio.wait_for(updates(), 5)
        event = await dev.send_event("start", event_timestamp_unix_ns=1_700_000_000_000_000_000)
    est = await TimeOffsetEstimator(host, status.phone.time_echo_port).estimate(20)
    gaze, frames = [], []

    async def g():
        async for d in rt.receive_gaze_data(status.direct_gaze_sensor().url):
            gaze.append((time.time(), d))
            if len(gaze) >= n_gaze:
                return

    async def v():
        async for f in rt.receive_video_frames(status.direct_world_sensor().url):
            frames.append((f.timestamp_unix_seconds, f.av_frame.to_ndarray(format="gray")))
            if len(frames) >= n_frames:
                return
    await asyncio.wait_for(asyncio.gather(g(), v()), 20)
    return status, comps, event, est, gaze, frames


@pytest.fixture(scope="module")
def received(session):
    emu = NeonEmulator(device_stream(session), session_camera(session), log_sent=True)
    url = emu.listen()
    host, port = url.removeprefix("neon://").split(":")
    try:
        out = asyncio.run(_client_run(host, int(port)))
    finally:
        emu.stop()
    return emu, out


def test_the_client_reads_the_status_the_websocket_and_an_event(received):
    emu, (status, comps, event, _, _, _) = received
    assert status.hardware.version == "2" and status.phone.time_echo_port == emu.echo_port
    assert status.direct_gaze_sensor().url == f"rtsp://127.0.0.1:{emu.rtsp_port}/?camera=gaze"
    assert status.direct_world_sensor().connected
    assert [type(c).__name__ for c in comps] == ["Phone", "Hardware", "Sensor", "Sensor"]
    assert event.timestamp == 1_700_000_000_000_000_000 and emu.events[-1]["name"] == "start"


def test_the_client_clock_offset_is_the_phones(received):
    emu, (_, _, _, est, _, _) = received
    # client minus phone, ms: the phone runs clock_s ahead; ms-rounded stamps on loopback
    assert abs(est.time_offset_ms.mean + emu.clock_s * 1000) < 1.5


def test_the_client_receives_each_sample_with_its_eye_states_and_time(session, received):
    emu, (_, _, _, _, gaze, _) = received
    s = emu.stream
    assert len(gaze) == 120 and all(isinstance(d, EyestateEyelidGazeData) for _, d in gaze)
    sent_k = np.array([k for _, k, _ in emu.player.sent_log])
    sent_t = np.array([t_phone for _, _, t_phone in emu.player.sent_log])
    cam = session_camera(session)
    checked = 0
    for arrival, d in gaze:
        near = np.abs(sent_t - d.timestamp_unix_seconds)           # its time: the phone's, to the RTP clock's tick
        assert near.min() < 1e-4
        k = int(sent_k[np.argmin(near)])
        for side, rays, valid in (("left", s.left, s.left_valid), ("right", s.right, s.right_valid)):
            got = np.array([getattr(d, f"{q}_{side}_{x}") for q in ("eyeball_center", "optical_axis") for x in "xyz"])
            if valid[k]:
                assert np.allclose(got[:3], rays[k, :3], atol=1e-4) and np.allclose(got[3:], rays[k, 3:], atol=1e-6)
            else:
                assert np.all(np.isnan(got))
        assert 0 < arrival + emu.clock_s - d.timestamp_unix_seconds < 0.5   # stamped before it arrived
        rec = neon_rtp.eye_state_sample(k, d.timestamp_unix_seconds, d)
        assert (rec.left_valid, rec.right_valid) == (bool(s.left_valid[k]), bool(s.right_valid[k]))
        p = _nearest_point(s.left[k], s.right[k]) if rec.left_valid and rec.right_valid else None
        if p is not None and p[2] > 100:                          # the 2D gaze: the lines' nearest point, projected
            assert np.allclose([d.x, d.y], cam.project(p[None])[0], atol=1e-2)
            checked += 1
    assert checked > 60


def test_the_client_decodes_the_scene_video_at_the_frames_times(received):
    emu, (_, _, _, _, gaze, frames) = received
    s = emu.stream
    assert len(frames) == 20
    p0 = emu.player.sent_log[0][2] - (s.t[emu.player.sent_log[0][1]] - min(s.t[0], s.frame_times[0]))
    cap = cv2.VideoCapture(str(s.video))
    video = []
    while (ok := cap.read())[0]:
        video.append(cv2.cvtColor(ok[1], cv2.COLOR_BGR2GRAY))
    t_frames = s.frame_times - min(s.t[0], s.frame_times[0]) + p0
    for t, gray in frames:
        j = int(np.argmin(np.abs(t_frames - t)))
        assert abs(t_frames[j] - t) < 1e-4                         # a frame's time: its own
        assert gray.shape == video[j].shape
        assert np.mean(np.abs(gray.astype(float) - video[j])) < 4.0  # H.264 at the encoder's quality


def test_the_payload_layout_is_the_clients():
    left, right = np.array([-31.0, 12.0, -40.0, 0.1, 0.05, 0.99]), np.array([32.0, 13.0, -41.0, -0.1, 0.0, 0.995])
    raw = neon_rtp.gaze_payload((800.5, 600.25), True, left, right, (4.0, 3.0), (-0.6, -1.2, 9.0, -0.5, -1.1, 0.4))
    assert len(raw) == 89
    d = EyestateEyelidGazeData.from_raw(RTSPData(raw, 12.5))
    assert (d.x, d.y, d.worn, d.pupil_diameter_left, d.pupil_diameter_right) == (800.5, 600.25, True, 4.0, 3.0)
    rec = neon_rtp.eye_state_sample(0, d.timestamp_unix_seconds, d)
    assert np.allclose(rec.left[:3], left[:3]) and np.allclose(rec.left[3:], left[3:] / np.linalg.norm(left[3:]))
    assert rec.left_valid and not rec.right_valid                   # the right lid is closed (0.4 mm)
    worn_off = EyestateEyelidGazeData.from_raw(RTSPData(neon_rtp.gaze_payload((1, 1), False, left, right), 0.0))
    assert not (neon_rtp.eye_state_sample(0, 0.0, worn_off).left_valid)


def test_rtcp_sender_report_and_fu_a_fragments():
    sr = neon_rtp.rtcp_sender_report(7, 1_700_000_000.25, 90000, 3, 99)
    _, pt, length, ssrc, sec, frac, ts = struct.unpack("!BBHIIII", sr[:20])
    assert (pt, length, ssrc, ts) == (200, 6, 7, 90000) and len(sr) == 28
    assert abs(sec + frac / 2**32 - neon_rtp.NTP_UNIX_OFFSET_S - 1_700_000_000.25) < 1e-6
    nal = bytes([0x65]) + bytes(range(256)) * 20
    parts = neon_rtp.h264_payloads(nal, mtu=1000)
    from pupil_labs.realtime_api.streaming.nal_unit import extract_payload_from_nal_unit
    joined = b"".join(bytes(extract_payload_from_nal_unit(p)) for p in parts)
    assert joined == b"\x00\x00\x00\x01" + nal and all(len(p) <= 1000 for p in parts)


def test_gaze_without_eye_states_is_the_cyclopean_ray_through_its_pixel(session):
    from pupil_labs.realtime_api.streaming.gaze import GazeData
    cam = session_camera(session)
    p = np.array([120.0, -60.0, 900.0])
    px = cam.project(p[None])[0]
    d = GazeData.from_raw(RTSPData(neon_rtp.GAZE_ONLY.pack(float(px[0]), float(px[1]), 255), 3.0))
    assert not neon_rtp.has_eye_states(d)
    rec = neon_rtp.cyclopean_sample(4, d.timestamp_unix_seconds, d, cam)
    assert rec.left_valid and not rec.right_valid and rec.t == 3.0
    assert np.allclose(rec.left[:3], 0) and np.allclose(rec.left[3:], p / np.linalg.norm(p), atol=1e-5)
