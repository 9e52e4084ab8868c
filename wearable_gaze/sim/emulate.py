"""An eye recorder in software: a session's serial byte stream played at its own pace.

The live app (``wearable-gaze live``) can then be tried, tested and benchmarked without the
hardware: point ``--serial`` at the emulator's ``socket://`` URL or pseudo-terminal, and
``--camera`` at the session's scene video (which replays at its own frame rate).

As a real recorder, the emulator's clock starts when a reader first connects (TCP) or opens the
terminal (pty) and then waits for no one: records sent while no reader is attached are lost, as
on a cable nobody listens to.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import threading
import time
import tty

import numpy as np

from ..errors import UserError
from ..formats.serial_protocol import DEFAULT_PROTOCOL, EyeRecord, LineProtocol, ParseError

CONNECT_SETTLE_S = 0.05   # pyserial's socket:// clears its input buffer just after connecting
PTY_OPEN_SETTLE_S = 0.2  # pyserial empties its input at the end of open(): the pty stream starts after


class RecorderEmulator:
    """Plays recorder records at their own times, optionally looped with the counter and the
    clock running on.

    Args:
        data: the recorder's byte stream (``eye_serial.bin``), whole records.
        protocol: its line protocol.
        loop: start again at the end; the clock and counter continue.
        duration_s: stop after this much stream time (default: the data's length, or forever
            when looping).
        inject: fault injection, ``{k: bytes}``: bytes sent right after the k-th record.
        log_sent: keep ``sent_log``, ``(time.monotonic(), k)`` just before the k-th record of the
            stream was written (tests compare a recording with what was sent when).

    Bytes that are not a valid record (a live recording keeps the garbage it received) are
    replayed after the record before them. The first pass sends the bytes as they are; looped
    passes re-encode each record with its new counter and time.

    Attributes:
        sent: records written so far; ``finished`` is set when the stream ends.
    """

    def __init__(self, data: bytes, protocol: LineProtocol = DEFAULT_PROTOCOL, loop: bool = False,
                 duration_s: float | None = None, inject: dict | None = None, log_sent: bool = False):
        term, prefix = protocol.terminator.encode(), protocol.prefix.encode()
        self.records: list[EyeRecord] = []
        self.raw: list[bytes] = []            # each record's bytes as received, then any garbage after it
        lead = b""
        chunks = data.split(term)
        if data.endswith(term):
            chunks.pop()                      # the empty tail after the last terminator
        for chunk in chunks:
            at = chunk.find(prefix)
            try:
                rec = protocol.parse(chunk[at:]) if at >= 0 else None
            except ParseError:
                rec = None
            if rec is None:                   # garbage or a broken record: replayed as it came
                if self.raw:
                    self.raw[-1] += chunk + term
                else:
                    lead += chunk + term
                continue
            if self.raw:
                self.raw[-1] += chunk[:at]
            else:
                lead += chunk[:at]
            self.records.append(rec)
            self.raw.append(chunk[at:] + term)
        if not data.endswith(term) and self.raw:          # no terminator after the last chunk
            self.raw[-1] = self.raw[-1][:-len(term)]
        if not self.records:
            raise UserError("the eye stream holds no valid record; give a session with eye_serial.bin "
                            "('wearable-gaze simulate' writes one, 'live --record' too)")
        self.raw[0] = lead + self.raw[0]
        t = np.array([r.t for r in self.records])
        self.t_first = float(t[0])
        step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0 / 60
        self.period_s = float(t[-1] - t[0]) + step
        self.protocol = protocol
        self.loop = loop
        self.duration_s = duration_s
        self.inject = dict(inject or {})
        self.sent = 0
        self.sent_log: list[tuple[float, int]] | None = [] if log_sent else None
        self.finished = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # --- the stream -------------------------------------------------------------------------

    def _schedule(self):
        """(wall offset from the start, bytes) for each record in order."""
        n = len(self.records)
        k = 0
        while True:
            lap, i = divmod(k, n)
            if lap and not self.loop:
                return
            r = self.records[i]
            dt = lap * self.period_s + r.t - self.t_first
            if self.duration_s is not None and dt > self.duration_s:
                return
            if lap:
                chunk = self.protocol.format(r._replace(counter=r.counter + lap * n, t=r.t + lap * self.period_s))
            else:
                chunk = self.raw[i]
            yield dt, chunk + self.inject.get(k, b"")
            k += 1

    def _play(self, write, t0: float) -> None:
        """Write each record at ``t0`` + its time; ``write`` returns False when nobody reads."""
        for k, (dt, chunk) in enumerate(self._schedule()):
            while True:
                wait = t0 + dt - time.monotonic()
                if wait <= 0 or self._stop.wait(min(wait, 0.1)):
                    break
            if self._stop.is_set():
                return
            t_send = time.monotonic()
            if write(chunk):
                self.sent += 1
                if self.sent_log is not None:
                    self.sent_log.append((t_send, k))

    # --- transports -------------------------------------------------------------------------

    def listen_tcp(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Serve the stream to one TCP reader at a time; returns its ``socket://`` URL.

        The clock starts when the first reader connects. A reader that disconnects misses the
        records sent until it reconnects (as when a cable is pulled).

        Raises:
            UserError: the address cannot be bound.
        """
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            srv.bind((host, port))
        except OSError as exc:
            srv.close()
            raise UserError(f"cannot listen on {host}:{port} ({exc.strerror}); pick a free port, "
                            "e.g. --listen 127.0.0.1:0 for any") from None
        srv.listen(1)
        reader = _TcpReader(srv)

        def run():
            try:
                if reader.accept(self._stop):
                    t0 = time.monotonic()     # the recorder's clock starts with the reader's camera
                    self._stop.wait(CONNECT_SETTLE_S)
                    self._play(reader.write, t0)
                    self._stop.wait(0.3)      # let the reader take the last bytes
            finally:
                reader.close()
                self.finished.set()

        h, p = srv.getsockname()
        self._start(run)
        return f"socket://{h}:{p}"

    def open_pty(self) -> str:
        """Serve the stream on a new pseudo-terminal; returns the path a reader opens as a
        serial port (``/dev/pts/N``). The clock starts when a reader first opens it; bytes
        written while no reader has it open are dropped."""
        master, slave = os.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        os.close(slave)                       # the master hangs up while no reader has the terminal open
        os.set_blocking(master, False)
        hup = select.poll()
        hup.register(master, select.POLLOUT | select.POLLHUP)

        def reader_attached(timeout_ms: int = 0) -> bool:
            ev = hup.poll(timeout_ms)
            return bool(ev) and not ev[0][1] & select.POLLHUP

        def write(chunk: bytes) -> bool:
            if not reader_attached():
                return False
            try:
                os.write(master, chunk)
                return True
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EIO):     # terminal buffer full, or the reader left
                    return False
                raise

        def run():
            try:
                while not self._stop.is_set():
                    if reader_attached(100):
                        # the reader is still opening: pyserial empties its input at the end of
                        # open(), so bytes written at once could be lost; the stream starts after
                        self._stop.wait(PTY_OPEN_SETTLE_S)
                        self._play(write, time.monotonic())
                        self._stop.wait(0.3)
                        break
                    self._stop.wait(0.05)     # poll returns at once with POLLHUP while nobody is there
            finally:
                os.close(master)
                self.finished.set()

        self._start(run)
        return path

    def _start(self, run) -> None:
        self._thread = threading.Thread(target=run, name="recorder-emulator", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        """End the stream and close the transport."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)


class _TcpReader:
    """The one TCP reader of ``RecorderEmulator.listen_tcp``'s listening socket ``srv``: taken
    when it connects, dropped when it goes (its records are then lost until it reconnects)."""

    def __init__(self, srv: socket.socket):
        self.srv = srv
        self.conn: socket.socket | None = None

    def take(self, wait_s: float) -> bool:
        """Accept a waiting reader (within ``wait_s``; 0: only one already there)."""
        self.srv.settimeout(wait_s)
        try:
            conn, _ = self.srv.accept()
        except (BlockingIOError, TimeoutError):
            return False
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.conn = conn
        return True

    def accept(self, stop: threading.Event) -> bool:
        """Wait for the first reader until ``stop`` is set; whether one came."""
        while not stop.is_set():
            if self.take(0.1):
                return True
        return False

    def write(self, chunk: bytes) -> bool:
        """Send ``chunk`` to the reader; False when there is none (or it just went)."""
        if self.conn is None and not self.take(0.0):  # a reader reconnecting: taken without waiting
            return False
        assert self.conn is not None
        try:
            self.conn.sendall(chunk)
            return True
        except OSError:
            self.conn.close()
            self.conn = None
            return False

    def close(self) -> None:
        """Close the reader's connection and the listening socket."""
        if self.conn is not None:
            self.conn.close()
        self.srv.close()
