"""Pupil Neon in software: the Companion app's real-time API serving a session's eye rays (as eye
states) and scene video (H.264), for ``live --device neon://`` without the hardware (docs/live.md,
"Neon"). What Pupil Labs' client (``pupil-labs-realtime-api``) uses of it, on loopback:

- HTTP on the given port: ``GET /api/status`` (``{"message", "result": [components]}``: Phone with
  ``time_echo_port``, Hardware, and the DIRECT gaze and world Sensors with their RTSP address and
  ``params``), the same components one per text message on the websocket ``/api/status``, and
  ``POST /api/event`` (timestamped on the phone's clock);
- RTSP (RFC 2326) on a second port: OPTIONS, DESCRIBE (the SDP: ``com.pupillabs.gaze1`` or H264 with
  its ``sprop-parameter-sets``), SETUP (UDP ``client_port`` or TCP ``interleaved``), PLAY,
  GET_PARAMETER, TEARDOWN; the streams themselves are ``neon_play.Player``'s;
- Time Echo (``time_echo.py``) on a third port.

The phone's clock is Unix time plus ``clock_s`` (default ``DEFAULT_CLOCK_S``: a client that does
not use the Time Echo offset fails the tests). The streams start at the first PLAY and wait for no
one: samples sent while nobody plays are lost, as on a real network.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import itertools
import json
import random
import struct
import threading
import time

from ..errors import UserError
from ..formats.camera import load_camera
from ..formats.session import load_session
from .neon_play import Player, rtp_clock
from .neon_rtsp import serve_rtsp
from .pupil_core_emu import DeviceStream

DEFAULT_CLOCK_S = 3.25
"""The phone's clock minus the local Unix clock: as a phone's NTP-set clock may be off by."""
WS_GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


def session_camera(session):
    """The scene camera of ``session`` (its ``camera.json``, or a simulated session's truth)."""
    sess = load_session(session)
    for key in ("camera", "truth_camera"):
        p = sess.path(key)
        if p is not None and p.is_file():
            return load_camera(p)
    raise UserError(f"{session}: no camera.json (the emulator projects the gaze point into the scene image); "
                    "give a simulated session or a 'live --device --record' recording")


def _headers(lines) -> dict:
    """HTTP or RTSP header lines -> {lower-case name: value}."""
    return {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines if ":" in ln)}


class NeonEmulator:
    """The Companion app's real-time API playing a ``DeviceStream``.

    Args:
        stream: what to play. camera: the scene camera (for the 2D gaze point). duration_s: stop
            after this much stream time. clock_s: the phone's clock minus Unix time. log_sent:
            keep the player's ``sent_log``.
    """

    def __init__(self, stream: DeviceStream, camera, duration_s=None, clock_s: float = DEFAULT_CLOCK_S,
                 log_sent: bool = False):
        self.clock_s = clock_s
        epoch = self.phone_time()
        self.player = Player(stream, camera, self.phone_time, rtp_clock(epoch), duration_s, log_sent)
        self.stream = stream
        self.loop = asyncio.new_event_loop()
        self._threads: list[threading.Thread] = []
        self._servers = []
        self._ssrc = itertools.count(random.randrange(1, 2**31))
        self.host = "127.0.0.1"
        self.events: list[dict] = []
        self._writers: set = set()                   # the open connections, closed by ``stop``

    def phone_time(self) -> float:
        """The phone's clock now, Unix s."""
        return time.time() + self.clock_s

    @property
    def finished(self) -> threading.Event:
        return self.player.finished

    @property
    def sent(self) -> int:
        return self.player.sent

    @property
    def frames_sent(self) -> int:
        return self.player.frames_sent

    def listen(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Serve HTTP on ``host:port`` (0: any free port), RTSP and Time Echo on free ports; returns
        the ``neon://HOST:PORT`` address ``live --device`` takes.

        Raises:
            UserError: the address cannot be bound.
        """
        self.host = host

        async def start():
            http = await asyncio.start_server(self._tracked(self._http), host, port)
            rtsp = await asyncio.start_server(self._tracked(self._rtsp), host, 0)
            echo = await asyncio.start_server(self._tracked(self._echo), host, 0)
            return http, rtsp, echo

        try:
            self._servers = list(self.loop.run_until_complete(start()))
        except OSError as exc:
            raise UserError(f"cannot listen on {host}:{port} ({exc.strerror or exc}); pick a free port, e.g. "
                            "--listen 127.0.0.1:0 for any") from None
        self.port, self.rtsp_port, self.echo_port = (s.sockets[0].getsockname()[1] for s in self._servers)
        for fn in (self.loop.run_forever, self.player.run):
            th = threading.Thread(target=fn, daemon=True, name="neon-emulator")
            th.start()
            self._threads.append(th)
        return f"neon://{host}:{self.port}"

    def _tracked(self, handler):
        async def serve(reader, writer):
            self._writers.add(writer)
            try:
                await handler(reader, writer)
            finally:
                self._writers.discard(writer)
        return serve

    def stop(self, timeout: float = 2.0) -> None:
        """End the streams and close every server (the ports are free again)."""
        self.player.stop_event.set()

        async def close():
            for s in self._servers:
                s.close()
            for w in list(self._writers):
                w.close()
            for _ in range(20):                      # the handlers see their connections end
                if len(asyncio.all_tasks()) <= 1:
                    break
                await asyncio.sleep(0.01)

        if self.loop.is_running():
            asyncio.run_coroutine_threadsafe(close(), self.loop).result(timeout)
            self.loop.call_soon_threadsafe(self.loop.stop)
        for th in self._threads:
            th.join(timeout)
        if not self.loop.is_running():
            self.loop.close()

    # --- HTTP and the status websocket ----------------------------------------------------------

    def components(self) -> list[dict]:
        """The status: Phone, Hardware and the DIRECT gaze and world sensors (models.py ``Status``)."""
        phone = {"battery_level": 87, "battery_state": "OK", "device_id": "emulated", "device_name": "Neon emulator",
                 "ip": self.host, "memory": 2**34, "memory_state": "OK", "time_echo_port": self.echo_port}
        hw = {"version": "2", "module_serial": "emulated", "glasses_serial": "-1", "world_camera_serial": "-1"}

        def sensor(name):
            return {"model": "Sensor", "data": {"sensor": name, "conn_type": "DIRECT", "connected": True,
                                                "ip": self.host, "port": self.rtsp_port, "protocol": "rtsp",
                                                "params": f"camera={name}", "stream_error": False}}
        return [{"model": "Phone", "data": phone}, {"model": "Hardware", "data": hw}, sensor("gaze"), sensor("world")]

    async def _http(self, reader, writer) -> None:
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            lines = head.decode("latin-1").split("\r\n")
            method, path = lines[0].split(" ")[:2]
            headers = _headers(lines[1:])
            body = await reader.readexactly(int(headers.get("content-length", 0)))
            if path == "/api/status" and headers.get("upgrade", "").lower() == "websocket":
                await self._websocket(headers, reader, writer)
                return
            code, result = self._answer(method, path, body)
            data = json.dumps(result).encode()
            writer.write(f"HTTP/1.1 {code} {'OK' if code == 200 else 'Error'}\r\nContent-Type: application/json\r\n"
                         f"Content-Length: {len(data)}\r\nConnection: close\r\n\r\n".encode() + data)
            await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, ValueError):
            pass
        finally:
            writer.close()

    def _answer(self, method: str, path: str, body: bytes) -> tuple[int, dict]:
        if method == "GET" and path == "/api/status":
            return 200, {"message": "Success", "result": self.components()}
        if method == "POST" and path == "/api/event":
            try:
                event = json.loads(body or b"{}")
            except ValueError:
                return 400, {"message": "the event is not JSON"}
            ts = int(event.get("timestamp") or self.phone_time() * 1e9)
            self.events.append({"name": event.get("name"), "timestamp": ts})
            return 200, {"message": "Event sent.", "result": {"name": event.get("name"), "recording_id": None,
                                                               "timestamp": ts}}
        return 404, {"message": f"the emulator does not serve {method} {path}"}

    async def _websocket(self, headers, reader, writer) -> None:
        accept = base64.b64encode(hashlib.sha1((headers["sec-websocket-key"] + WS_GUID).encode()).digest()).decode()
        writer.write(("HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                      f"Sec-WebSocket-Accept: {accept}\r\n\r\n").encode())
        for comp in self.components():
            data = json.dumps(comp).encode()
            n = len(data)
            head = bytes((0x81, n)) if n < 126 else bytes((0x81, 126)) + struct.pack("!H", n)
            writer.write(head + data)
        await writer.drain()
        while await reader.read(4096):               # until the client closes (its frames are not needed)
            pass

    # --- Time Echo --------------------------------------------------------------------------------

    async def _echo(self, reader, writer) -> None:
        try:
            while True:
                t1 = await reader.readexactly(8)
                writer.write(t1 + struct.pack("!Q", int(self.phone_time() * 1000)))
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()

    # --- RTSP -------------------------------------------------------------------------------------

    async def _rtsp(self, reader, writer) -> None:
        await serve_rtsp(self, reader, writer)
