"""Issue 12, live: publishing never blocks the loop (a subscriber that stops reading, a stdout
nobody reads), bad --publish URLs, UDP bound to loopback; the serial reader keeps the bytes
received just before a disconnect and counts a corrupt record once; a camera stall is a stall."""

import logging
import socket
import threading
import time

import pytest

from tests.helpers import drain_reader, eye_record_bytes
from wearable_gaze.errors import UserError
from wearable_gaze.live.publish import Publisher
from wearable_gaze.live.serial_in import EyeReader


def _listener():
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    return srv, f"tcp://127.0.0.1:{srv.getsockname()[1]}"


def _send_all(pub, n, size=1000):
    """Send n messages in a thread; returns the thread (joined for up to 20 s)."""
    th = threading.Thread(target=lambda: [pub.send({"type": "estimate", "k": k, "pad": "x" * size})
                                          for k in range(n)], daemon=True)
    th.start()
    th.join(20)
    return th


def test_a_tcp_subscriber_that_never_reads_does_not_block_publishing_and_is_disconnected(caplog):
    srv, url = _listener()
    caplog.set_level(logging.WARNING, logger="wearable_gaze.live.publish")
    pub = Publisher(url, stdout=False, maxsize=100, stuck_s=0.5)
    conn, _ = srv.accept()                                  # connected, and never read
    th = _send_all(pub, 20000)                              # 20 MB: far beyond the socket buffers
    assert not th.is_alive(), "publishing blocked on a subscriber that does not read"
    sub = pub.subscribers[0]
    assert pub.published == 20000 and sub.dropped > 0
    t0 = time.monotonic()
    while not sub.closed and time.monotonic() - t0 < 5:
        time.sleep(0.05)
    assert sub.closed, "a subscriber stuck for longer than stuck_s stays connected"
    assert sub.sent + sub.dropped == 20000                  # every message is either sent or counted as dropped
    assert any("disconnected" in r.getMessage() and url in r.getMessage() for r in caplog.records)
    assert pub.disconnected and url in pub.disconnected[0]
    th = _send_all(pub, 10)                                 # after the disconnect: counted, not sent
    assert not th.is_alive() and sub.sent + sub.dropped == 20010
    pub.close()
    conn.close()
    srv.close()


def test_a_reading_tcp_subscriber_gets_every_message_in_order():
    srv, url = _listener()
    pub = Publisher(url, stdout=False, maxsize=100000)
    conn, _ = srv.accept()
    got = bytearray()

    def read():
        while True:
            b = conn.recv(1 << 16)
            if not b:
                return
            got.extend(b)
    rt = threading.Thread(target=read, daemon=True)
    rt.start()
    _send_all(pub, 3000, size=50)
    pub.close(timeout_s=5)
    rt.join(5)
    import json
    ks = [json.loads(x)["k"] for x in bytes(got).decode().splitlines()]
    assert ks == list(range(3000)) and pub.dropped == 0
    conn.close()
    srv.close()


class _BlockedStream:
    """A stdout nobody reads: write blocks until released."""

    def __init__(self):
        self.release = threading.Event()
        self.lines = []

    def write(self, text):
        self.release.wait()
        self.lines += text.splitlines()

    def flush(self):
        pass


def test_stdout_that_nobody_reads_does_not_block_publishing():
    stream = _BlockedStream()
    pub = Publisher(None, stdout=True, stream=stream, maxsize=50)
    th = _send_all(pub, 5000, size=10)
    assert not th.is_alive(), "publishing blocked on stdout"
    sub = pub.subscribers[0]
    stream.release.set()
    pub.close(timeout_s=5)
    import json
    ks = [json.loads(x)["k"] for x in stream.lines]
    assert len(ks) + sub.dropped == 5000 and sub.dropped > 0            # every message written or counted
    assert ks[-50:] == list(range(4950, 5000))                          # the oldest were dropped, not the newest


@pytest.mark.parametrize("url", ["tcp://127.0.0.1:99999", "udp://127.0.0.1:abc", "http://127.0.0.1:9000",
                                 "udp://:9000", "tcp://127.0.0.1", "udp://127.0.0.1:0"])
def test_bad_publish_urls_are_refused_by_the_publisher(url):
    with pytest.raises(UserError, match="udp://HOST:PORT or tcp://HOST:PORT"):
        Publisher(url, stdout=False)


def test_udp_publisher_binds_to_loopback_for_a_loopback_destination():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2)
    pub = Publisher(f"udp://127.0.0.1:{rx.getsockname()[1]}", stdout=False)
    assert pub.subscribers[0].sock.getsockname()[0] == "127.0.0.1"    # not 0.0.0.0: no other interface
    pub.send({"type": "estimate"})
    data, _ = rx.recvfrom(4096)
    assert b'"estimate"' in data
    pub.close()
    rx.close()


def _send_and_close(records: bytes, port_holder):
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port_holder.append(srv.getsockname()[1])
    conn, _ = srv.accept()
    time.sleep(0.3)              # past any input-buffer reset a socket:// client makes when it connects
    conn.sendall(records)
    conn.close()                 # the cable is pulled at once after the last records
    srv.close()


def test_records_received_just_before_a_disconnect_are_kept():
    port = []
    data = b"".join(eye_record_bytes(i) for i in range(30))
    th = threading.Thread(target=_send_and_close, args=(data, port), daemon=True)
    th.start()
    while not port:
        time.sleep(0.01)
    raw = bytearray()
    reader = EyeReader(f"socket://127.0.0.1:{port[0]}", reconnect_s=5.0, raw_sink=raw.extend)
    reader.start()
    recs = drain_reader(reader, 30, timeout=3)
    reader.stop()
    reader.join(2)
    assert [r.counter for r in recs] == list(range(30))
    assert bytes(raw) == data


def test_a_corrupt_record_is_counted_once_not_also_as_lost():
    import serial

    link = serial.serial_for_url("loop://", timeout=0.05)
    stream = bytearray()
    for i in range(20):
        r = bytearray(eye_record_bytes(i))
        if i == 5:                                        # record 5 arrives with a wrong checksum
            r[8] = ord("7") if r[8] != ord("7") else ord("6")
        if i in (12, 13):                                 # records 12 and 13 never arrive
            continue
        stream += r
    link.write(bytes(stream))
    reader = EyeReader("loop://")
    reader.open = lambda: link
    reader.start()
    recs = drain_reader(reader, 17)
    reader.stop()
    reader.join(2)
    assert len(recs) == 17
    assert reader.stats.corrupt == 1 and reader.stats.lost == 2


def test_a_camera_stall_is_one_stall_not_a_run_of_missed_frames(tmp_path):
    from wearable_gaze.live.camera_in import FrameSource
    from wearable_gaze.sim.simulate import simulate_scenario

    root = tmp_path / "s"
    simulate_scenario({"base": "lab-walkabout", "duration_s": 0.5, "camera": {"resolution": [320, 180]},
                       "calibration": {"eye": False, "camera_views": 0}}, root, 1)
    src = FrameSource(str(root / "scene.mp4"), maxsize=100)
    src.is_file = False                                  # timed as a device: by arrival, gaps counted

    class Device:                                        # a camera delivering 30 fps that hangs once for 0.6 s
        def __init__(self, cap):
            self.cap, self.n = cap, 0
            self.frame = cap.read()[1]

        def read(self):
            self.n += 1
            time.sleep(0.6 if self.n == 5 else 1 / 30)
            return True, self.frame

        def release(self):
            self.cap.release()
    src.cap = Device(src.cap)
    src.start()
    t0 = time.monotonic()
    while src.stats.frames < 15 and time.monotonic() - t0 < 5:
        time.sleep(0.05)
    src.stop()
    src.join(2)
    assert src.stats.frames >= 15
    assert src.stats.stalls == 1 and src.stats.missed == 0 and src.stats.skipped == 0


def test_closing_does_not_wait_long_for_a_subscriber_that_does_not_read():
    """The session's end (SIGTERM) waits at most ``timeout_s`` per subscriber; what it could not
    send is counted as dropped (the old publisher took 43 s to exit after SIGTERM)."""
    srv, url = _listener()
    pub = Publisher(url, stdout=False, maxsize=100000, stuck_s=60.0)
    conn, _ = srv.accept()
    th = _send_all(pub, 20000)
    assert not th.is_alive()
    t0 = time.monotonic()
    closer = threading.Thread(target=pub.close, kwargs={"timeout_s": 0.5}, daemon=True)
    closer.start()
    closer.join(10)
    assert not closer.is_alive(), "close waited for a subscriber that does not read"
    sub = pub.subscribers[0]
    assert time.monotonic() - t0 < 5 and sub.closed and sub.sent + sub.dropped == 20000 and sub.dropped > 0
    conn.close()
    srv.close()
