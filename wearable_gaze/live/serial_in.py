"""Eye-tracker input over pyserial: a serial port or a pyserial URL (``socket://``,
``rfc2217://``, ``loop://``), records parsed with a ``LineProtocol``, resynchronised after
garbage, checksums validated, counters kept, reconnection when the link drops.

``socket://`` URLs are read with a plain socket: pyserial's own handler discards the bytes of a
read in progress when the peer closes (the last records before a disconnect) and its input
buffer when it connects."""

from __future__ import annotations

import logging
import queue
import select
import socket
import threading
import time
from dataclasses import dataclass
from urllib.parse import urlparse

import serial

from ..formats.serial_protocol import DEFAULT_PROTOCOL, EyeRecord, LineProtocol, ParseError
from .input_thread import InputThread

log = logging.getLogger(__name__)


@dataclass
class SerialStats:
    records: int = 0          # valid records delivered
    corrupt: int = 0          # lines that failed to parse (checksum, fields, numbers)
    garbage_bytes: int = 0    # bytes skipped while resynchronising
    lost: int = 0             # records missing according to the counter (corrupt ones not counted again)
    dropped: int = 0          # records dropped because the consumer fell behind
    reconnects: int = 0


class LineSplitter:
    """Bytes in, complete candidate records out: everything before the record prefix is garbage;
    a record ends at the terminator; an over-long line (a lost terminator) is discarded."""

    def __init__(self, protocol: LineProtocol = DEFAULT_PROTOCOL, max_line: int = 256):
        self.prefix = protocol.prefix.encode()
        self.end = protocol.terminator.strip("\r").encode() or b"\n"
        self.buf = bytearray()
        self.max_line = max_line
        self.garbage = 0

    def feed(self, data: bytes) -> list[bytes]:
        self.buf += data
        out = []
        while True:
            start = self.buf.find(self.prefix)
            if start < 0:
                keep = len(self.prefix) - 1               # a prefix may be split across reads
                if len(self.buf) > keep:
                    self.garbage += len(self.buf) - keep
                    del self.buf[:len(self.buf) - keep]
                return out
            if start > 0:
                self.garbage += start
                del self.buf[:start]
            end = self.buf.find(self.end)
            nxt = self.buf.find(self.prefix, len(self.prefix))
            if 0 <= nxt and (end < 0 or nxt < end):        # a truncated record: a new one began
                out.append(bytes(self.buf[:nxt]))
                del self.buf[:nxt]
                continue
            if end < 0:
                if len(self.buf) > self.max_line:
                    self.garbage += len(self.buf)
                    self.buf.clear()
                return out
            out.append(bytes(self.buf[:end + 1]))
            del self.buf[:end + 1]


class SocketLink:
    """A ``socket://host:port`` link read with a plain TCP socket: ``read`` returns what has
    arrived (b"" after ``timeout`` s without data) and raises ``serial.SerialException`` only
    once everything the peer sent before closing has been returned."""

    def __init__(self, url: str, timeout: float = 0.05, connect_timeout: float = 2.0):
        u = urlparse(url)
        try:
            port = u.port
        except ValueError:
            port = None
        if not u.hostname or not port:
            raise ValueError(f"{url!r}: expected socket://HOST:PORT")
        self.timeout = timeout
        self.sock = socket.create_connection((u.hostname, port), timeout=connect_timeout)
        self.sock.setblocking(False)
        self.is_open = True

    def read(self, size: int) -> bytes:
        ready, _, _ = select.select([self.sock], [], [], self.timeout)
        if not ready:
            return b""
        try:
            data = self.sock.recv(size)
        except BlockingIOError:
            return b""
        if not data:
            raise serial.SerialException("connection closed by the peer")
        return data

    def close(self) -> None:
        self.is_open = False
        self.sock.close()


class EyeReader(InputThread):
    """Reads records in a thread and puts ``(arrival_s, EyeRecord)`` on a bounded queue
    (``time.monotonic()`` arrival times). Raw bytes go to ``raw_sink(bytes)`` if given (the
    recorder keeps them). With ``on_record(arrival_s, record)``, every intact record is handed
    to it in this thread, before the queue (so it sees records the queue has no room for), and
    its return value is queued instead of ``(arrival_s, record)``.

    Args:
        port: a device (``/dev/ttyUSB0``) or a pyserial URL.
        baudrate, bytesize, parity, stopbits: serial settings.
        protocol: the record format.
        reconnect_s: wait between reconnection attempts.
    """

    def __init__(self, port: str, baudrate: int = 115200, protocol: LineProtocol = DEFAULT_PROTOCOL,
                 maxsize: int = 2000, reconnect_s: float = 0.5, raw_sink=None, bytesize=8, parity="N", stopbits=1,
                 on_record=None):
        super().__init__("eye-reader")
        self.port, self.baudrate = port, baudrate
        self.settings = dict(bytesize=bytesize, parity=parity, stopbits=stopbits)
        self.protocol = protocol
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.stats = SerialStats()
        self.reconnect_s = reconnect_s
        self.raw_sink = raw_sink
        self.on_record = on_record
        self._corrupt_since_good = 0
        self.error: str | None = None
        self._last_counter = None
        self.connected = threading.Event()

    def open(self):
        if str(self.port).startswith("socket://"):
            return SocketLink(self.port)
        return serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.05, **self.settings)

    @staticmethod
    def _read(link) -> bytes:
        """What has arrived: sized by ``in_waiting`` where the link has it, so that a link that
        fails mid-read (a pulled USB cable) has no received bytes inside the failed call."""
        if isinstance(link, SocketLink):
            return link.read(4096)
        try:
            waiting = link.in_waiting
        except (serial.SerialException, OSError, AttributeError, NotImplementedError):
            waiting = 4096
        return link.read(max(1, min(waiting, 4096)))

    def _run(self):
        splitter = LineSplitter(self.protocol)
        first = True
        while not self.stop_event.is_set():
            try:
                link = self.open()
            except (serial.SerialException, OSError, ValueError) as exc:
                if first:
                    self.error = f"cannot open {self.port}: {exc}"
                    self.connected.set()
                    return
                time.sleep(self.reconnect_s)
                continue
            if not first:
                self.stats.reconnects += 1
            first = False
            self.connected.set()
            try:
                while not self.stop_event.is_set():
                    data = self._read(link)
                    if not data:
                        if not getattr(link, "is_open", True):
                            raise serial.SerialException("port closed")
                        continue
                    now = time.monotonic()
                    if self.raw_sink is not None:
                        self.raw_sink(data)
                    for line in splitter.feed(data):
                        self._handle(line, now)
                    self.stats.garbage_bytes = splitter.garbage
            except (serial.SerialException, OSError) as exc:
                self.error = None if self.stop_event.is_set() else f"link lost ({exc}); reconnecting"
                if self.error:
                    log.info("eye data: %s", self.error)
            finally:
                try:
                    link.close()
                except Exception:
                    pass
            if not self.stop_event.is_set():
                time.sleep(self.reconnect_s)

    def _handle(self, line: bytes, now: float):
        try:
            rec = self.protocol.parse(line)
        except ParseError:
            self.stats.corrupt += 1
            self._corrupt_since_good += 1
            return
        if self._last_counter is not None:
            gap = (rec.counter - self._last_counter - 1) % self.protocol.counter_modulo
            if gap < self.protocol.counter_modulo // 2:
                self.stats.lost += max(0, gap - self._corrupt_since_good)   # a corrupt record is counted once
        self._corrupt_since_good = 0
        self._last_counter = rec.counter
        self.stats.records += 1
        item = self.on_record(now, rec) if self.on_record is not None else (now, rec)
        try:
            self.queue.put_nowait(item)
        except queue.Full:
            self.stats.dropped += 1



__all__ = ["EyeReader", "EyeRecord", "LineSplitter", "SerialStats", "SocketLink"]
