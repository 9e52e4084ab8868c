"""Pupil Core's network API (Pupil Capture's IPC backbone, reached through Pupil Remote): the
message layouts read by ``live --device pupil-core://`` and written by ``emulate --as
pupil-core`` (docs/live.md, "Pupil Core"). Bytes in, typed records out, and back; no sockets here.

The layouts, as Pupil Capture sends them (pupil-labs/pupil, ``pupil_src/shared_modules``):

- Pupil Remote (``pupil_remote.py``, ``on_recv``): a ZMQ REP socket answering one string per
  request: ``SUB_PORT`` and ``PUB_PORT`` (the backbone's ports, as decimal strings), ``t`` (Pupil
  time, ``repr`` of a float, s), ``T <time>`` (sets Pupil time: "Timesync successful."), ``v``
  (version); a multipart request ``[topic, msgpack payload]`` (a notification, topic
  ``notify.<subject>``) is forwarded to the backbone and answered "Message forwarded.".
- Messages on the SUB port (``zmq_tools.py``, ``Msg_Receiver.recv``): multipart ``[topic,
  msgpack(dict)]``, then any extra frames the payload's ``__raw_data__`` held (the frame bytes).
- 3D gaze (``gaze_mapping/gazer_3d/gazer_headset.py``, ``Model3D_Binocular._predict_single`` and
  ``Gazer3D.predict``): topic ``gaze.3d.01.`` with ``eye_centers_3d`` and ``gaze_normals_3d``,
  ``{0: [x, y, z], 1: [x, y, z]}``, ``gaze_point_3d``, ``norm_pos``, ``confidence`` and
  ``timestamp`` (Pupil time, s); one eye alone: topic ``gaze.3d.0.`` or ``gaze.3d.1.`` with
  ``eye_center_3d`` and ``gaze_normal_3d``. The dict keys are ints in Capture's payloads; Pupil
  Player's exporter also reads them as the strings "0" and "1" (both are accepted here).
- Scene frames (``data_api/frame_publisher.py``, plugin ``Frame_Publisher``, started with the
  notification ``start_plugin`` ``{"name": "Frame_Publisher", "args": {"format": ...}}``): topic
  ``frame.world`` with ``width``, ``height``, ``index``, ``timestamp`` (Pupil time, s) and
  ``format`` ('jpeg', 'yuv', 'bgr', 'gray'), the image as the third frame.

Frames: eye0 is the wearer's RIGHT eye, eye1 the LEFT (``pupil_core.EYE_SIDE``). The eye centres
and normals are in the world camera's frame, OpenCV axes (x right, y down, z forward), mm, with
the origin at its optical centre: that is our head frame, ``pupil_core.T_HEAD_FROM_WORLD_CAMERA``
(the identity), the one mapping the importer uses too.
Clock: Pupil time, s, on the device's own clock; ``live`` maps it to the local clock through
Pupil Remote's ``t`` (docs/live.md).
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import msgpack
import numpy as np

from .pupil_core import EYE_SIDE, MAX_EYE_DISTANCE_MM, MIN_CONFIDENCE, T_HEAD_FROM_WORLD_CAMERA

GAZE_TOPIC = "gaze.3d."                       # the prefix a client subscribes to (binocular and monocular)
BINOCULAR_TOPIC = "gaze.3d.01."
FRAME_TOPIC = "frame.world"
FRAME_FORMATS = ("bgr", "jpeg", "gray")       # the Frame Publisher's formats read here ('yuv' is not)
FRAME_PUBLISHER = "Frame_Publisher"
DEFAULT_PORT = 50020                          # Pupil Remote's default port in Capture


class BadMessage(ValueError):
    """A message that is not a valid Pupil message of its topic (the reason is the message)."""


class RaySample(NamedTuple):
    """One gaze sample as per-eye view lines in the head frame (the world camera's, OpenCV axes).

    counter: the sample's number in the stream (Pupil gives none: the receiver counts); t: the
    sample's time, s (Pupil time as received); left, right: (6,) tuples, the eye centre (mm) then
    the unit gaze direction, head frame (NaN when that eye is not valid); left_valid, right_valid:
    whether each eye is usable; confidence: Pupil's, 0-1."""

    counter: int
    t: float
    left: tuple
    right: tuple
    left_valid: bool
    right_valid: bool
    confidence: float


class WorldFrame(NamedTuple):
    """A scene frame from the Frame Publisher: ``index`` (Capture's frame number), ``t`` (Pupil
    time, s), ``image`` (H, W, 3) uint8 BGR or (H, W) grey."""

    index: int
    t: float
    image: np.ndarray


_NAN6 = (float("nan"),) * 6


def unpack(payload: bytes) -> dict:
    """A msgpack payload as a dict (int map keys allowed, as Capture packs them).

    Raises:
        BadMessage: not msgpack, or not a map.
    """
    try:
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except (ValueError, msgpack.UnpackException, TypeError) as exc:
        raise BadMessage(f"payload is not msgpack ({type(exc).__name__})") from None
    if not isinstance(msg, dict):
        raise BadMessage(f"payload is a {type(msg).__name__}, not a map")
    return msg


def _vec(value, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, float).reshape(-1)
    except (TypeError, ValueError):
        raise BadMessage(f"{what} is not 3 numbers") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise BadMessage(f"{what} is not 3 finite numbers")
    return v


def _eye(center, normal, eye: int) -> tuple[tuple, bool]:
    """One eye's (6,) line in the head frame and whether it is usable (the importer's checks:
    the centre within ``MAX_EYE_DISTANCE_MM`` of the world camera, the normal unit and forward)."""
    c, n = _vec(center, f"eye {eye} centre"), _vec(normal, f"eye {eye} normal")
    c = T_HEAD_FROM_WORLD_CAMERA[:3, :3] @ c + T_HEAD_FROM_WORLD_CAMERA[:3, 3]
    n = T_HEAD_FROM_WORLD_CAMERA[:3, :3] @ n
    ok = bool(np.linalg.norm(c) <= MAX_EYE_DISTANCE_MM and abs(np.linalg.norm(n) - 1) <= 0.01 and n[2] >= 0)
    return (tuple(c) + tuple(n / np.linalg.norm(n))) if ok else _NAN6, ok


def _per_eye(msg: dict, key: str, eye: int):
    d = msg.get(key)
    if not isinstance(d, dict):
        raise BadMessage(f"no {key} map")
    v = d.get(eye, d.get(str(eye)))
    if v is None:
        raise BadMessage(f"{key} has no eye {eye}")
    return v


def parse_gaze(topic: str, payload: bytes, counter: int = 0, min_confidence: float = MIN_CONFIDENCE) -> RaySample:
    """A ``gaze.3d.*`` message as a ``RaySample``. A sample under ``min_confidence`` (Pupil's
    default 0.6) or with an eye that fails the checks keeps that eye invalid.

    Raises:
        BadMessage: not msgpack, no finite ``timestamp``, missing or malformed eye fields.
    """
    msg = unpack(payload)
    t = msg.get("timestamp")
    if not isinstance(t, (int, float)) or not np.isfinite(t):
        raise BadMessage("no finite timestamp")
    conf = msg.get("confidence", 1.0)
    conf = float(conf) if isinstance(conf, (int, float)) else float("nan")
    eyes = {}
    if topic.startswith(BINOCULAR_TOPIC):
        for e in (0, 1):
            eyes[e] = _eye(_per_eye(msg, "eye_centers_3d", e), _per_eye(msg, "gaze_normals_3d", e), e)
    elif topic.startswith((GAZE_TOPIC + "0.", GAZE_TOPIC + "1.")):
        e = int(topic[len(GAZE_TOPIC)])
        eyes[e] = _eye(msg.get("eye_center_3d"), msg.get("gaze_normal_3d"), e)
    else:
        raise BadMessage(f"topic {topic[:40]!r} is not 3D gaze")
    good = conf >= min_confidence
    side = {EYE_SIDE[e]: v for e, v in eyes.items()}
    left, lv = side.get("left", (_NAN6, False))
    right, rv = side.get("right", (_NAN6, False))
    return RaySample(counter, float(t), left, right, lv and good, rv and good, conf)


def gaze_message(t: float, left_line, right_line, confidence: float = 1.0) -> list[bytes]:
    """A ``gaze.3d.*`` message as Capture sends it (``[topic, payload]``): ``left_line``,
    ``right_line`` (6,) head-frame eye centre (mm) and unit direction, or None for a missing
    eye (binocular when both are given); ``gaze_point_3d`` is the lines' nearest point."""
    lines = {1: left_line, 0: right_line}                     # eye1 left, eye0 right
    have = {e: np.asarray(v, float) for e, v in lines.items() if v is not None}
    if not have:
        raise ValueError("a gaze message needs at least one eye")
    msg = {"confidence": float(confidence), "timestamp": float(t), "norm_pos": [0.5, 0.5]}
    if len(have) == 2:
        topic = BINOCULAR_TOPIC
        msg["eye_centers_3d"] = {e: v[:3].tolist() for e, v in have.items()}
        msg["gaze_normals_3d"] = {e: v[3:].tolist() for e, v in have.items()}
        msg["gaze_point_3d"] = _nearest_point(have[0], have[1]).tolist()
    else:
        (e, v), = have.items()
        topic = f"{GAZE_TOPIC}{e}."
        msg.update(eye_center_3d=v[:3].tolist(), gaze_normal_3d=v[3:].tolist(),
                   gaze_point_3d=(v[:3] + 500.0 * v[3:]).tolist())
    msg["topic"] = topic
    return [topic.encode(), msgpack.packb(msg, use_bin_type=True)]


def _nearest_point(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,) the midpoint of the shortest segment between two (6,) lines (far ahead if parallel)."""
    w, u, v = a[:3] - b[:3], a[3:], b[3:]
    uv = u @ v
    den = 1.0 - uv * uv
    if den < 1e-12:
        return 0.5 * (a[:3] + b[:3]) + 5000.0 * u
    s = (uv * (v @ w) - (u @ w)) / den
    r = ((v @ w) - uv * (u @ w)) / den
    return 0.5 * (a[:3] + s * u + b[:3] + r * v)


def frame_message(index: int, t: float, image: np.ndarray, fmt: str = "bgr") -> list[bytes]:
    """A ``frame.world`` message as the Frame Publisher sends it: ``[topic, payload, image
    bytes]``; ``image`` (H, W, 3) BGR uint8; ``fmt`` 'bgr', 'jpeg' or 'gray'."""
    h, w = image.shape[:2]
    if fmt == "bgr":
        data = np.ascontiguousarray(image).tobytes()
    elif fmt == "gray":
        data = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).tobytes()
    elif fmt == "jpeg":
        data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
    else:
        raise ValueError(f"frame format {fmt!r}: one of {FRAME_FORMATS}")
    msg = {"topic": FRAME_TOPIC, "width": int(w), "height": int(h), "index": int(index), "timestamp": float(t),
           "format": fmt}
    return [FRAME_TOPIC.encode(), msgpack.packb(msg, use_bin_type=True), data]


def parse_frame(parts: list[bytes]) -> WorldFrame:
    """A ``frame.world`` multipart message as a ``WorldFrame``.

    Raises:
        BadMessage: not three parts, a malformed payload, an unknown format, image bytes that do
            not match its size.
    """
    if len(parts) != 3:
        raise BadMessage(f"frame.world has {len(parts)} parts, not 3 (topic, payload, image)")
    msg = unpack(parts[1])
    try:
        w, h, index, t, fmt = (int(msg["width"]), int(msg["height"]), int(msg["index"]), float(msg["timestamp"]),
                               msg["format"])
    except (KeyError, TypeError, ValueError):
        raise BadMessage("frame.world payload lacks width, height, index, timestamp or format") from None
    data = parts[2]
    if fmt == "bgr" and len(data) == w * h * 3:
        img = np.frombuffer(data, np.uint8).reshape(h, w, 3)
    elif fmt == "gray" and len(data) == w * h:
        img = np.frombuffer(data, np.uint8).reshape(h, w)
    elif fmt == "jpeg":
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if img is None or img.shape[:2] != (h, w):
            raise BadMessage("frame.world JPEG does not decode to its width x height")
    elif fmt in FRAME_FORMATS:
        raise BadMessage(f"frame.world {fmt} image has {len(data)} bytes, not {w}x{h}")
    else:
        raise BadMessage(f"frame.world format {str(fmt)[:20]!r} is not one of {', '.join(FRAME_FORMATS)} (set the "
                         f"Frame Publisher's format to BGR or JPEG)")
    if not np.isfinite(t):
        raise BadMessage("frame.world timestamp is not finite")
    return WorldFrame(index, t, img)


def notification(subject: str, **fields) -> list[bytes]:
    """A notification as sent to Pupil Remote: ``[b'notify.<subject>', msgpack payload]``."""
    return [f"notify.{subject}".encode(), msgpack.packb({"subject": subject, **fields}, use_bin_type=True)]


def start_frame_publisher(fmt: str = "bgr") -> list[bytes]:
    """The notification that starts the Frame Publisher in ``fmt``."""
    return notification("start_plugin", name=FRAME_PUBLISHER, args={"format": fmt})
