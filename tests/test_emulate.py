"""The eye-recorder emulator: a session's serial stream at its own pace, over TCP or a pty."""

import json
import re
import socket
import threading
import time

import pytest

from tests.helpers import drain_reader, eye_record_bytes
from wearable_gaze.cli import main
from wearable_gaze.errors import UserError
from wearable_gaze.formats.serial_protocol import DEFAULT_PROTOCOL
from wearable_gaze.live.serial_in import EyeReader
from wearable_gaze.sim.emulate import RecorderEmulator

RATE = 200.0     # fast records keep the tests short


def _rec(i):
    return eye_record_bytes(i, RATE)


def _read_whole_stream(emu, url, n, on_record=None):
    """A reader of ``url`` until ``n`` records came and the emulator finished; both stopped."""
    reader = EyeReader(url, on_record=on_record)
    reader.start()
    recs = drain_reader(reader, n)
    assert emu.finished.wait(5)
    reader.stop()
    reader.join(2)
    emu.stop()
    return reader, recs


def test_garbage_and_broken_records_are_replayed_where_they_came():
    recs = [_rec(i) for i in range(6)]
    data = b"noise\r\n" + recs[0] + b"\x00junk" + recs[1] + recs[2][:12] + b"\r\n" + b"".join(recs[3:])
    emu = RecorderEmulator(data)
    assert [r.counter for r in emu.records] == [0, 1, 3, 4, 5]            # record 2 is cut short
    assert b"".join(emu.raw) == data                                     # first pass: byte for byte
    assert emu.period_s == pytest.approx(6 / RATE)                       # t 0 .. 5, plus one step
    laps = list(RecorderEmulator(b"".join(recs), loop=True, duration_s=2 * 6 / RATE - 1e-9)._schedule())
    second = [DEFAULT_PROTOCOL.parse(c) for _, c in laps[6:]]
    assert [r.counter for r in second] == list(range(6, 12))             # the counter runs on
    assert [r.t for r in second] == pytest.approx([i / RATE for i in range(6, 12)])
    assert [dt for dt, _ in laps] == pytest.approx([i / RATE for i in range(12)])


def test_a_stream_without_records_is_refused():
    with pytest.raises(UserError, match="no valid record"):
        RecorderEmulator(b"\x00\x01garbage\r\nmore\r\n")


def test_reader_gets_every_record_over_tcp_looped():
    emu = RecorderEmulator(b"".join(_rec(i) for i in range(40)), loop=True, duration_s=100 / RATE,
                           inject={10: b"\x00junk"})
    reader, recs = _read_whole_stream(emu, emu.listen_tcp(), 101)
    assert emu.sent == 101                                               # stream times 0 .. 100 / RATE
    assert [r.counter for r in recs] == list(range(101))
    assert reader.stats.corrupt == 0 and reader.stats.lost == 0 and reader.stats.garbage_bytes >= 5


def test_a_reader_that_reconnects_gets_the_stream_from_where_it_has_got_to():
    emu = RecorderEmulator(b"".join(_rec(i) for i in range(400)))        # 2 s
    host, port = emu.listen_tcp()[len("socket://"):].split(":")
    first = socket.create_connection((host, int(port)))
    time.sleep(0.3)
    a = first.recv(1 << 16)
    first.close()                                                        # the cable is pulled
    time.sleep(0.3)
    second = socket.create_connection((host, int(port)))
    time.sleep(0.3)
    b = second.recv(1 << 16)
    second.close()
    emu.stop()
    ca = [DEFAULT_PROTOCOL.parse(x).counter for x in a.split(b"\r\n")[:-1]]
    cb = [DEFAULT_PROTOCOL.parse(x).counter for x in b.split(b"\r\n")[:-1]]
    assert ca and cb and ca == list(range(len(ca)))
    assert cb[0] > ca[-1] + 1 and cb == list(range(cb[0], cb[0] + len(cb)))   # missed while unplugged


def test_reader_on_the_emulators_pseudo_terminal():
    emu = RecorderEmulator(b"".join(_rec(i) for i in range(60)))
    reader = EyeReader(emu.open_pty())
    reader.start()
    recs = drain_reader(reader, 60)
    emu.stop()
    reader.stop()
    reader.join(2)
    assert [r.counter for r in recs] == list(range(60))
    assert all(r.left_valid and r.right_valid == (r.counter % 7 != 0) for r in recs)


def test_emulate_cli_serves_a_session_and_bad_input_is_one_line(tmp_path, capsys):
    root = tmp_path / "s"
    root.mkdir()
    (root / "eye_serial.bin").write_bytes(b"".join(_rec(i) for i in range(20)))
    (root / "session.json").write_text(json.dumps({
        "format": "wearable-gaze-session", "version": 1, "has_recording": False,
        "files": {"eye_serial": "eye_serial.bin"}}))
    result = []
    th = threading.Thread(target=lambda: result.append(main(["emulate", str(root), "--pty"])), daemon=True)
    th.start()
    err, t0 = "", time.monotonic()
    while "/dev/pts/" not in err and time.monotonic() - t0 < 5:          # the path it prints for 'live --serial'
        time.sleep(0.02)
        err += capsys.readouterr().err
    path = re.search(r"(/dev/pts/\d+)", err).group(1)
    assert f"live --serial {path}" in err
    reader = EyeReader(path)
    reader.start()
    recs = drain_reader(reader, 20)
    th.join(5)
    reader.stop()
    reader.join(2)
    assert result == [0] and [r.counter for r in recs] == list(range(20))
    assert "20 records sent" in capsys.readouterr().err

    assert main(["emulate", str(tmp_path / "missing")]) == 2
    assert "no such session folder" in capsys.readouterr().err
    (root / "eye_serial.bin").write_bytes(b"garbage only\r\n")
    assert main(["emulate", str(root), "--pty"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no valid record" in err
    with pytest.raises(SystemExit) as exc:
        main(["emulate", str(root), "--listen", "localhost"])
    assert exc.value.code == 2 and "HOST:PORT" in capsys.readouterr().err


def test_the_send_log_has_each_record_once_in_order_before_it_arrives():
    emu = RecorderEmulator(b"".join(_rec(i) for i in range(40)), log_sent=True)
    arrivals = []
    _, recs = _read_whole_stream(emu, emu.listen_tcp(), 40,
                                 on_record=lambda t, r: arrivals.append((t, r.counter)) or (t, r))
    assert [k for _, k in emu.sent_log] == list(range(40)) and [r.counter for r in recs] == list(range(40))
    sent_t = [t for t, _ in emu.sent_log]
    assert sent_t == sorted(sent_t)
    assert all(t_sent <= t_arr for t_sent, (t_arr, _) in zip(sent_t, arrivals, strict=True))
