"""Publishing the live session's messages (docs/live.md): JSON lines to stdout and to a UDP or TCP
subscriber, each served by its own sender thread from a bounded queue, so that a subscriber
that reads slowly, or not at all, never holds up the live loop.

When a subscriber's queue is full the oldest waiting message is dropped (counted). A TCP
subscriber that accepts no byte for ``stuck_s`` while messages wait is disconnected, with a log
line; the session goes on.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import select
import socket
import sys
import threading
import time
from collections import deque
from urllib.parse import urlparse

from ..errors import UserError

log = logging.getLogger(__name__)

SEND_BUFFER_BYTES = 1 << 18     # a TCP subscriber's kernel send buffer


def parse_publish_url(url: str) -> tuple[str, str, int]:
    """``udp://HOST:PORT`` or ``tcp://HOST:PORT`` -> (scheme, host, port).

    Raises:
        UserError: anything else (a wrong scheme, no host, a port that is not 1..65535).
    """
    hint = "expected udp://HOST:PORT or tcp://HOST:PORT, port 1-65535, e.g. udp://127.0.0.1:9000"
    try:
        u = urlparse(url)
        port = u.port
    except ValueError:
        raise UserError(f"--publish {url!r}: {hint}") from None
    if u.scheme not in ("udp", "tcp") or not u.hostname or not port or u.path not in ("", "/"):
        raise UserError(f"--publish {url!r}: {hint}")
    return u.scheme, u.hostname, port


def is_loopback(host: str) -> bool:
    """True when ``host`` names this machine's loopback interface (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class Subscriber:
    """One destination: a bounded queue of encoded lines and a thread that sends them.

    Args:
        name: for log lines and the summary.
        maxsize: queue length in messages; when full, the oldest is dropped (``dropped``).
        stuck_s: a destination that accepts nothing for this long while messages wait is
            disconnected (where that means anything: TCP).

    Attributes:
        sent: messages handed to the destination; ``dropped``: dropped from the full queue or
        left unsent when it was disconnected; ``closed``: set once it is disconnected.
    """

    def __init__(self, name: str, maxsize: int = 1000, stuck_s: float = 5.0):
        self.name = name
        self.queue: deque[bytes] = deque()
        self.maxsize = maxsize
        self.stuck_s = stuck_s
        self.cond = threading.Condition()
        self.sent = 0
        self.dropped = 0
        self.inflight = 0                      # lines taken from the queue and being sent
        self.closed = False
        self.why: str | None = None            # why it was disconnected
        self.finishing = False
        self.last_progress = time.monotonic()
        self.thread = threading.Thread(target=self._run, daemon=True, name=f"publish-{name}")

    def start(self) -> None:
        self.thread.start()

    def put(self, line: bytes) -> None:
        """Queue one line; never blocks (the oldest line makes room, counted)."""
        with self.cond:
            if self.closed:
                self.dropped += 1
                return
            if len(self.queue) >= self.maxsize:
                self.queue.popleft()
                self.dropped += 1
            self.queue.append(line)
            self.cond.notify()

    def _take(self) -> list[bytes] | None:
        """Every waiting line (None at the end)."""
        with self.cond:
            while not self.queue and not self.finishing and not self.closed:
                self.cond.wait(0.5)
            if self.closed or (not self.queue and self.finishing):
                return None
            batch = list(self.queue)
            self.queue.clear()
            self.inflight = len(batch)
            return batch

    def _run(self) -> None:
        try:
            while True:
                batch = self._take()
                if batch is None:
                    return
                try:
                    self._send(batch)
                except _Stuck as exc:
                    self._disconnect(str(exc))
                    return
                except OSError as exc:
                    self._disconnect(f"{exc.strerror or exc}")
                    return
                with self.cond:
                    self.sent += self.inflight         # 0 if a disconnect counted them as dropped meanwhile
                    self.inflight = 0
                self.last_progress = time.monotonic()
        finally:
            self._close_transport()

    def _send(self, batch: list[bytes]) -> None:
        raise NotImplementedError

    def _close_transport(self) -> None:
        pass

    def _disconnect(self, why: str) -> None:
        with self.cond:
            if self.closed:
                return
            self.closed = True
            self.why = why
            self.dropped += self.inflight + len(self.queue)
            self.inflight = 0
            self.queue.clear()
            # said before the lock is let go: whoever sees ``closed`` can also read why in the log
            log.warning("publish: %s disconnected (%s); %d messages sent, %d dropped; the session goes on",
                        self.name, why, self.sent, self.dropped)

    def close(self, timeout_s: float = 1.0) -> None:
        """Send what is waiting (for up to ``timeout_s``), then stop."""
        with self.cond:
            self.finishing = True
            self.cond.notify_all()
        if self.thread.ident is not None:
            self.thread.join(timeout_s)
        if self.thread.is_alive():             # still blocked in a send: what is left is dropped
            self._disconnect(f"still not reading {timeout_s:g} s after the session ended")
            self._abort()

    def _abort(self) -> None:
        pass


class _Stuck(Exception):
    pass


class StreamSubscriber(Subscriber):
    """JSON lines to a text stream (stdout), written and flushed in the sender thread."""

    def __init__(self, stream, **kw):
        super().__init__("stdout", **kw)
        self.stream = stream

    def _send(self, batch):
        try:
            self.stream.write(b"".join(batch).decode())
            self.stream.flush()
        except ValueError as exc:              # a closed stream
            raise OSError(str(exc)) from None


class UdpSubscriber(Subscriber):
    """One datagram per line. Bound to the loopback interface when the destination is on it."""

    def __init__(self, host: str, port: int, **kw):
        super().__init__(f"udp://{host}:{port}", **kw)
        try:
            info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        except OSError as exc:
            raise UserError(f"--publish udp://{host}:{port}: cannot resolve {host!r} ({exc})") from None
        family, _, _, _, self.addr = info
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        if is_loopback(self.addr[0]):
            self.sock.bind(("::1" if family == socket.AF_INET6 else "127.0.0.1", 0))
        self.sock.settimeout(1.0)

    def _send(self, batch):
        for line in batch:
            try:
                self.sock.sendto(line, self.addr)
            except ConnectionRefusedError:
                pass                           # nobody listening (yet): UDP does not wait for one

    def _close_transport(self):
        self.sock.close()


class TcpSubscriber(Subscriber):
    """A TCP connection; a peer that takes no byte for ``stuck_s`` while lines wait is
    disconnected."""

    def __init__(self, host: str, port: int, connect_timeout_s: float = 2.0, **kw):
        super().__init__(f"tcp://{host}:{port}", **kw)
        try:
            self.sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as exc:
            raise UserError(f"--publish tcp://{host}:{port}: cannot connect ({exc}); start the listener "
                            f"first") from None
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # the kernel holds at most this much for the subscriber (Linux doubles it): a subscriber that
        # lags gets fresh messages from the queue, not a backlog of megabytes (minutes old at 600 Hz)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        self.sock.setblocking(False)

    def _send(self, batch):
        data = memoryview(b"".join(batch))
        while data:
            _, ready, _ = select.select([], [self.sock], [], 0.2)
            if ready:
                try:
                    n = self.sock.send(data)
                except BlockingIOError:
                    n = 0
                if n:
                    data = data[n:]
                    self.last_progress = time.monotonic()
                    continue
            if time.monotonic() - self.last_progress > self.stuck_s:
                raise _Stuck(f"took no data for {self.stuck_s:g} s")
            if self.closed:
                raise _Stuck("closed")

    def _close_transport(self):
        self.sock.close()

    def _abort(self):
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class Publisher:
    """JSON lines to stdout and/or a UDP or TCP endpoint (``udp://host:port``, ``tcp://host:port``).

    ``send`` encodes a message once and queues it for each subscriber; it never blocks.

    Args:
        url: the ``--publish`` URL, or None.
        stdout: also write the lines to ``stream`` (default ``sys.stdout``).
        maxsize, stuck_s: per subscriber (``Subscriber``).

    Raises:
        UserError: a bad URL, or a TCP listener that cannot be reached.
    """

    def __init__(self, url: str | None = None, stdout: bool = True, stream=None, maxsize: int = 1000,
                 stuck_s: float = 5.0):
        self.subscribers: list[Subscriber] = []
        kw = {"maxsize": maxsize, "stuck_s": stuck_s}
        if url:
            scheme, host, port = parse_publish_url(url)
            self.subscribers.append(UdpSubscriber(host, port, **kw) if scheme == "udp"
                                    else TcpSubscriber(host, port, **kw))
        if stdout:
            self.subscribers.append(StreamSubscriber(stream or sys.stdout, **kw))
        for s in self.subscribers:
            s.start()
        self.published = 0

    @staticmethod
    def encode(msg: dict) -> bytes:
        return (json.dumps(msg, separators=(",", ":")) + "\n").encode()

    def send(self, msg: dict) -> bytes:
        """Queue ``msg`` for every subscriber; returns the encoded line."""
        line = self.encode(msg)
        for s in self.subscribers:
            s.put(line)
        self.published += 1
        return line

    @property
    def dropped(self) -> int:
        """Messages some subscriber did not get (summed over subscribers)."""
        return sum(s.dropped for s in self.subscribers)

    @property
    def disconnected(self) -> list[str]:
        """'name (why)' of each subscriber that was disconnected."""
        return [f"{s.name} ({s.why})" for s in self.subscribers if s.why]

    def close(self, timeout_s: float = 1.0) -> None:
        """Send what is waiting, each subscriber for up to ``timeout_s`` (a subscriber that does
        not read is not waited for longer)."""
        for s in self.subscribers:
            with s.cond:
                s.finishing = True
                s.cond.notify_all()
        for s in self.subscribers:
            s.close(timeout_s)
