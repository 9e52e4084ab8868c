"""Eye-tracker input over pyserial: a serial port or a pyserial URL (``socket://``,
``rfc2217://``, ``loop://``), records parsed with a ``LineProtocol``, resynchronised after
garbage, checksums validated, counters kept, reconnection when the link drops."""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass

import serial

from ..emr import DEFAULT_PROTOCOL, EyeRecord, LineProtocol, ParseError


@dataclass
class SerialStats:
    records: int = 0          # valid records delivered
    corrupt: int = 0          # lines that failed to parse (checksum, fields, numbers)
    garbage_bytes: int = 0    # bytes skipped while resynchronising
    lost: int = 0             # records missing according to the counter
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


class EyeReader(threading.Thread):
    """Reads records in a thread and puts ``(arrival_s, EyeRecord)`` on a bounded queue
    (``time.monotonic()`` arrival times). Raw bytes go to ``raw_sink(bytes)`` if given (the
    recorder keeps them).

    Args:
        port: a device (``/dev/ttyUSB0``) or a pyserial URL.
        baudrate, bytesize, parity, stopbits: serial settings.
        protocol: the record format.
        reconnect_s: wait between reconnection attempts.
    """

    def __init__(self, port: str, baudrate: int = 115200, protocol: LineProtocol = DEFAULT_PROTOCOL,
                 maxsize: int = 2000, reconnect_s: float = 0.5, raw_sink=None, bytesize=8, parity="N", stopbits=1):
        super().__init__(daemon=True, name="eye-reader")
        self.port, self.baudrate = port, baudrate
        self.settings = dict(bytesize=bytesize, parity=parity, stopbits=stopbits)
        self.protocol = protocol
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.stats = SerialStats()
        self.stop_event = threading.Event()
        self.reconnect_s = reconnect_s
        self.raw_sink = raw_sink
        self.error: str | None = None
        self._last_counter = None
        self.connected = threading.Event()

    def open(self):
        return serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.05, **self.settings)

    def run(self):
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
                    data = link.read(4096)
                    if not data:
                        if isinstance(link, serial.Serial) and not link.is_open:
                            raise serial.SerialException("port closed")
                        if getattr(link, "_socket", "x") is None:       # socket:// peer went away
                            raise serial.SerialException("connection closed")
                        continue
                    now = time.monotonic()
                    if self.raw_sink is not None:
                        self.raw_sink(data)
                    for line in splitter.feed(data):
                        self._handle(line, now)
                    self.stats.garbage_bytes = splitter.garbage
            except (serial.SerialException, OSError) as exc:
                self.error = None if self.stop_event.is_set() else f"link lost ({exc}); reconnecting"
            finally:
                try:
                    link.close()
                except Exception:  # noqa: BLE001
                    pass
            if not self.stop_event.is_set():
                time.sleep(self.reconnect_s)

    def _handle(self, line: bytes, now: float):
        try:
            rec = self.protocol.parse(line)
        except ParseError:
            self.stats.corrupt += 1
            return
        if self._last_counter is not None:
            gap = (rec.counter - self._last_counter - 1) % self.protocol.counter_modulo
            if gap < self.protocol.counter_modulo // 2:
                self.stats.lost += gap
        self._last_counter = rec.counter
        self.stats.records += 1
        try:
            self.queue.put_nowait((now, rec))
        except queue.Full:
            self.stats.dropped += 1

    def stop(self):
        self.stop_event.set()


__all__ = ["EyeReader", "EyeRecord", "LineSplitter", "SerialStats"]
