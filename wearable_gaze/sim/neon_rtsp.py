"""The Neon emulator's RTSP server (RFC 2326), as much of it as Pupil Labs' client (through aiortsp)
uses: OPTIONS, DESCRIBE, SETUP over UDP (``client_port``) or TCP (``interleaved``), PLAY,
GET_PARAMETER (keep-alive) and TEARDOWN. The stream is named by the URL's ``camera=`` parameter
(``gaze`` or ``world``, as the emulator's status gives it)."""

from __future__ import annotations

import asyncio
import re
import socket
import uuid

from ..formats.devices.neon_rtp import GAZE_ENCODING, GAZE_PT, VIDEO_PT, h264_fmtp, sdp
from .neon_play import Subscriber

PUBLIC = "OPTIONS, DESCRIBE, SETUP, PLAY, TEARDOWN, GET_PARAMETER"
SESSION_TIMEOUT_S = 60


def stream_sdp(emu, kind: str) -> str:
    """The SDP of the ``kind`` stream ('gaze' or 'world')."""
    if kind == "gaze":
        return sdp("application", GAZE_ENCODING, GAZE_PT)
    sps, pps = emu.player.encoder.parameter_sets
    return sdp("video", "H264", VIDEO_PT, h264_fmtp(sps, pps))


async def _request(reader) -> tuple[str, str, dict]:
    """One request: (method, URL, headers with lower-case names); interleaved data from the client
    (its RTCP receiver reports) is skipped."""
    while True:
        first = await reader.readexactly(1)
        if first == b"$":
            head = await reader.readexactly(3)
            await reader.readexactly(int.from_bytes(head[1:], "big"))
            continue
        head = first + await reader.readuntil(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        method, url = lines[0].split(" ")[:2]
        headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:] if ":" in ln)}
        await reader.readexactly(int(headers.get("content-length", 0)))
        return method, url, headers


class _Connection:
    """One client's RTSP connection and its one media session."""

    def __init__(self, emu, reader, writer):
        self.emu, self.reader, self.writer = emu, reader, writer
        self.loop = asyncio.get_running_loop()
        self.kind = None
        self.session = uuid.uuid4().hex[:16]
        self.udp = None
        self.sub: Subscriber | None = None
        self.send = None

    def respond(self, cseq: str, code: int = 200, headers: dict | None = None, body: str = "") -> None:
        lines = [f"RTSP/1.0 {code} {'OK' if code == 200 else 'Error'}", f"CSeq: {cseq}"]
        lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
        if body:
            lines.append(f"Content-Length: {len(body.encode())}")
        self.writer.write(("\r\n".join(lines) + "\r\n\r\n" + body).encode())

    def setup(self, transport: str) -> str | None:
        """The Transport answer, and ``send`` set, for the client's Transport; None if unusable."""
        peer = self.writer.get_extra_info("peername")[0]
        m = re.search(r"client_port=(\d+)-(\d+)", transport)
        if m:
            self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.udp.bind((self.emu.host, 0))
            here = self.udp.getsockname()[1]
            dest = (peer, int(m.group(1))), (peer, int(m.group(2)))
            udp = self.udp

            def send(channel, data):
                try:
                    udp.sendto(data, dest[channel])
                except OSError:
                    pass
            self.send = send
            return f"RTP/AVP;unicast;client_port={m.group(1)}-{m.group(2)};server_port={here}-{here}"
        m = re.search(r"interleaved=(\d+)-(\d+)", transport)
        if m:
            chans = int(m.group(1)), int(m.group(2))
            writer, loop = self.writer, self.loop

            def send(channel, data):
                frame = bytes((0x24, chans[channel])) + len(data).to_bytes(2, "big") + data
                loop.call_soon_threadsafe(writer.write, frame)
            self.send = send
            return f"RTP/AVP/TCP;unicast;interleaved={chans[0]}-{chans[1]}"
        return None

    async def serve(self) -> None:
        while True:
            method, url, h = await _request(self.reader)
            cseq = h.get("cseq", "0")
            m = re.search(r"camera=(\w+)", url)
            if m and m.group(1) in ("gaze", "world"):
                self.kind = m.group(1)
            sess = {"Session": f"{self.session};timeout={SESSION_TIMEOUT_S}"}
            if method == "OPTIONS":
                self.respond(cseq, headers={"Public": PUBLIC})
            elif self.kind is None:
                self.respond(cseq, 404)
            elif method == "DESCRIBE":
                self.respond(cseq, headers={"Content-Type": "application/sdp", "Content-Base": url},
                             body=stream_sdp(self.emu, self.kind))
            elif method == "SETUP":
                answer = self.setup(h.get("transport", ""))
                if answer is None:
                    self.respond(cseq, 461)
                else:
                    self.respond(cseq, headers={"Transport": answer, **sess})
            elif method == "PLAY" and self.send is not None:
                self.respond(cseq, headers={"Range": "npt=now-", **sess})
                await self.writer.drain()
                if self.sub is None:
                    self.sub = Subscriber(self.kind, self.send, next(self.emu._ssrc))
                    self.emu.player.add(self.sub)
            elif method in ("GET_PARAMETER", "TEARDOWN"):
                self.respond(cseq, headers=sess)
                if method == "TEARDOWN":
                    await self.writer.drain()
                    return
            else:
                self.respond(cseq, 455)
            await self.writer.drain()

    def close(self) -> None:
        if self.sub is not None:
            self.emu.player.remove(self.sub)
        if self.udp is not None:
            self.udp.close()
        self.writer.close()


async def serve_rtsp(emu, reader, writer) -> None:
    """Serve one client's RTSP connection until it tears down or goes away."""
    conn = _Connection(emu, reader, writer)
    try:
        await conn.serve()
    except (asyncio.IncompleteReadError, ConnectionError, ValueError, asyncio.LimitOverrunError):
        pass
    finally:
        conn.close()
