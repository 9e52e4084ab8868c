"""Neon's real-time API on the wire (``live --device neon://``, ``emulate --as neon``; docs/live.md,
"Neon"): the byte layouts of Pupil Labs' Real-Time API as its Python client
(``pupil-labs-realtime-api`` 1.9) reads them, and the eye states as our per-eye view lines.

Sources: the client's ``streaming/gaze.py`` (the gaze payloads, told apart by their length: 9,
17, 25, 65, 89 or 105 bytes, network byte order), ``streaming/base.py`` (a packet's time is its
RTP timestamp over the SDP ``rtpmap`` clock rate plus the offset the last RTCP sender report
gives: the report's NTP time, Unix seconds, less its RTP time), ``streaming/nal_unit.py`` and
``streaming/video.py`` (H.264 in single-NAL or FU-A packets, RFC 6184; the decoder is primed with
the SDP's ``sprop-parameter-sets``), ``time_echo.py`` (the Time Echo protocol: the client sends
its time, ms, as ``!Q``; the phone answers ``!QQ``, that time and its own) and the guide
"Under the hood" of pupil-labs/pl-realtime-api (the gaze encoding ``com.pupillabs.gaze1``; the
stream URL ``rtsp://IP:PORT/?PARAMS``).

Frames. The eye states (eyeball centre, mm; optical axis, unit) are in Neon's scene-camera frame,
"the origin corresponds to the scene camera" (Neon's docs, "3D eye poses"), OpenCV axes
(``neon.T_HEAD_FROM_NEON_SCENE``, identity: our head frame). Pure functions: no I/O.
"""

from __future__ import annotations

import base64
import struct

import numpy as np

from .neon import MAX_CENTER_MM, MIN_APERTURE_MM, T_HEAD_FROM_NEON_SCENE
from .pupil_net import RaySample

DEFAULT_PORT = 8080                     # the Companion app's HTTP API (it falls back to another when taken)
GAZE_ENCODING = "com.pupillabs.gaze1"
RTP_CLOCK_HZ = 90000                    # the RTP clock of the emulator's streams (the client reads it from the SDP)
GAZE_PT, VIDEO_PT, EVENTS_PT = 99, 96, 101
NTP_UNIX_OFFSET_S = 2208988800          # seconds from 1900 (NTP) to 1970 (Unix)

EYESTATE_EYELID = struct.Struct("!ffBffffffffffffffffffff")     # the client's EyestateEyelidGazeData, 89 bytes
"""x, y (px), worn (255 or 0), then per eye (left, right): pupil diameter (mm), eyeball centre
(3, mm), optical axis (3); then per eye (left, right): eyelid angle top, bottom (rad), aperture
(mm)."""
EYESTATE = struct.Struct("!ffBffffffffffffff")                  # EyestateGazeData, 65 bytes (no lids)
GAZE_ONLY = struct.Struct("!ffB")                               # GazeData, 9 bytes (no eye states)


def gaze_payload(px, worn: bool, left, right, pupil_mm=(3.5, 3.5), lids=None) -> bytes:
    """One gaze datum with eye states and eyelids (89 bytes): ``px`` (2,) the gaze point in the
    scene image, px; ``left``, ``right`` (6,) eyeball centre (mm) and optical axis (unit), scene
    camera frame (NaN for an eye not seen); ``lids`` (6,) top, bottom angle (rad) and aperture
    (mm), left then right (default: open, 10 mm)."""
    lids = (-0.6, -1.2, 10.0, -0.6, -1.2, 10.0) if lids is None else lids
    return EYESTATE_EYELID.pack(float(px[0]), float(px[1]), 255 if worn else 0, float(pupil_mm[0]),
                                *map(float, left), float(pupil_mm[1]), *map(float, right), *map(float, lids))


def _eye(center, axis, aperture) -> tuple[tuple, bool]:
    """One eye's (6,) line in the head frame and whether it is usable: finite, the centre within
    ``MAX_CENTER_MM`` of the scene camera, the axis pointing forward, the lid open."""
    c = T_HEAD_FROM_NEON_SCENE[:3, :3] @ np.asarray(center, float) + T_HEAD_FROM_NEON_SCENE[:3, 3]
    a = T_HEAD_FROM_NEON_SCENE[:3, :3] @ np.asarray(axis, float)
    n = float(np.linalg.norm(a))
    ok = bool(np.all(np.isfinite(c)) and np.isfinite(n) and n > 0.5)
    if ok:
        a = a / n
        ok = bool(np.linalg.norm(c) <= MAX_CENTER_MM and a[2] > 0 and not aperture < MIN_APERTURE_MM)
    return tuple(float(v) for v in (*c, *a)), ok


def eye_state_sample(counter: int, t: float, datum) -> RaySample:
    """A client gaze datum with eye states (``EyestateGazeData`` and the kinds with eyelids) as
    per-eye view lines, head frame; an eye is invalid when not worn, implausible (``_eye``) or
    its lid closed. ``t``: the datum's time, s."""
    worn = bool(datum.worn)
    out = []
    for side in ("left", "right"):
        c = [getattr(datum, f"eyeball_center_{side}_{x}") for x in "xyz"]
        a = [getattr(datum, f"optical_axis_{side}_{x}") for x in "xyz"]
        line, ok = _eye(c, a, getattr(datum, f"eyelid_aperture_{side}", np.inf))
        out.append((line, ok and worn))
    (left, lv), (right, rv) = out
    return RaySample(counter, float(t), left, right, lv, rv, 1.0 if worn else 0.0)


def cyclopean_sample(counter: int, t: float, datum, camera) -> RaySample:
    """A gaze datum without eye states (eye state off in the Companion app; Pupil Invisible): the
    ray from the scene camera's centre through the gaze pixel (undistorted with ``camera``), in
    the left eye's slot, the right invalid."""
    xy = camera.undistort_points(np.array([[datum.x, datum.y]], float))[0]
    d = np.array([xy[0], xy[1], 1.0])
    d /= np.linalg.norm(d)
    nan6 = (float("nan"),) * 6
    line = (0.0, 0.0, 0.0, *map(float, d))
    return RaySample(counter, float(t), line, nan6, bool(datum.worn), False, 1.0 if datum.worn else 0.0)


def has_eye_states(datum) -> bool:
    """Whether a client gaze datum carries eye states."""
    return hasattr(datum, "eyeball_center_left_x")


# --- RTP, RTCP, SDP (the emulator's side) -------------------------------------------------------

def rtp_packet(pt: int, seq: int, ts: int, ssrc: int, payload: bytes, marker: bool = False) -> bytes:
    """An RTP packet (RFC 3550: version 2, no padding, extension or CSRC)."""
    return struct.pack("!BBHII", 0x80, (0x80 if marker else 0) | pt, seq & 0xFFFF, ts & 0xFFFFFFFF,
                       ssrc) + payload


def rtcp_sender_report(ssrc: int, unix_s: float, rtp_ts: int, packets: int, octets: int) -> bytes:
    """An RTCP sender report (RFC 3550 6.4.1, no report blocks): the sender's wall clock
    ``unix_s`` (as NTP) at RTP time ``rtp_ts``."""
    ntp = unix_s + NTP_UNIX_OFFSET_S
    sec = int(ntp)
    frac = int((ntp - sec) * 2**32) & 0xFFFFFFFF
    return struct.pack("!BBHIIIIII", 0x80, 200, 6, ssrc, sec, frac, rtp_ts & 0xFFFFFFFF, packets & 0xFFFFFFFF,
                       octets & 0xFFFFFFFF)


def split_annexb(data: bytes) -> list[bytes]:
    """The NAL units of an Annex B byte stream (start codes removed)."""
    units, i, n = [], 0, len(data)
    starts = []
    while True:
        j = data.find(b"\x00\x00\x01", i)
        if j < 0:
            break
        starts.append(j + 3)
        i = j + 3
    for k, s in enumerate(starts):
        end = starts[k + 1] - 3 if k + 1 < len(starts) else n
        unit = data[s:end]
        while unit.endswith(b"\x00") and k + 1 < len(starts):
            unit = unit[:-1]                # the 4-byte start code's leading zero
        if unit:
            units.append(unit)
    return units


def h264_payloads(nal: bytes, mtu: int = 1400) -> list[bytes]:
    """One NAL unit as RTP payloads (RFC 6184): whole when it fits ``mtu``, else FU-A fragments."""
    if len(nal) <= mtu:
        return [nal]
    head, body = nal[0], nal[1:]
    indicator = (head & 0xE0) | 28
    out = []
    for k in range(0, len(body), mtu - 2):
        chunk = body[k:k + mtu - 2]
        fu = head & 0x1F
        if k == 0:
            fu |= 0x80
        if k + mtu - 2 >= len(body):
            fu |= 0x40
        out.append(bytes((indicator, fu)) + chunk)
    return out


def sdp(kind: str, encoding: str, pt: int, fmtp: str | None = None) -> str:
    """The SDP of one stream (``kind``: 'video' or 'application'), its ``rtpmap`` at
    ``RTP_CLOCK_HZ``."""
    lines = ["v=0", "o=- 0 0 IN IP4 127.0.0.1", "s=wearable-gaze Neon emulator", "t=0 0", "a=control:*",
             f"m={kind} 0 RTP/AVP {pt}", f"a=rtpmap:{pt} {encoding}/{RTP_CLOCK_HZ}", "a=control:trackID=0"]
    if fmtp:
        lines.append(f"a=fmtp:{pt} {fmtp}")
    return "\r\n".join(lines) + "\r\n"


def h264_fmtp(sps: bytes, pps: bytes) -> str:
    """The H.264 ``fmtp`` with the parameter sets the client primes its decoder with."""
    sets = ",".join(base64.b64encode(x).decode() for x in (sps, pps))
    return f"packetization-mode=1;sprop-parameter-sets={sets}"
