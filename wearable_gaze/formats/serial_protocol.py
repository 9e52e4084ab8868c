"""The eye recorder's serial line protocol (documented in docs/serial.md).

The default protocol, the one the simulator writes, is one ASCII line per binocular sample::

    $EMR8,<counter>,<t_ms>,<left_x>,<left_y>,<right_x>,<right_y>,<valid>*<CS>\\r\\n

``counter`` counts samples modulo 65536; ``t_ms`` is the recorder's clock in milliseconds (one
decimal); the raw readings are sensor counts (two decimals); ``valid`` is a hexadecimal bit
mask (bit 0 left eye, bit 1 right eye); ``CS`` is the XOR of every byte between ``$`` and ``*``
as two upper-case hex digits (as NMEA 0183). A recorder with another layout is described by a
``LineProtocol`` (field order, separator, scale, validity, checksum) instead of code.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

FIELDS = ("counter", "t_ms", "left_x", "left_y", "right_x", "right_y", "valid")


class EyeRecord(NamedTuple):
    """One binocular sample as the recorder sends it.

    counter: sample counter (wraps); t: recorder time, s; left, right: (x, y) raw counts;
    left_valid, right_valid: whether each eye's reading is valid."""

    counter: int
    t: float
    left: tuple
    right: tuple
    left_valid: bool
    right_valid: bool


class ParseError(ValueError):
    """A line that is not a valid record (the reason is the message)."""


@dataclass(frozen=True)
class LineProtocol:
    """A line-oriented record format.

    Attributes:
        prefix: bytes that start a record (resynchronisation looks for them).
        separator: field separator.
        fields: field names in order; known names are those of ``FIELDS``, others are ignored.
        checksum: 'xor8' (NMEA-style ``*HH`` suffix) or 'none'.
        terminator: end of line.
        time_scale: seconds per unit of the time field (0.001 for milliseconds).
        valid_base: base of the validity mask (16 or 10).
        counter_modulo: the counter wraps at this value.
    """

    prefix: str = "$EMR8"
    separator: str = ","
    fields: tuple = FIELDS
    checksum: str = "xor8"
    terminator: str = "\r\n"
    time_scale: float = 0.001
    valid_base: int = 16
    counter_modulo: int = 65536
    decimals: dict = field(default_factory=lambda: {"t_ms": 1, "raw": 2})

    def format(self, rec: EyeRecord) -> bytes:
        """One record as bytes, terminator included."""
        vals = {
            "counter": str(int(rec.counter) % self.counter_modulo),
            "t_ms": f"{rec.t / self.time_scale:.{self.decimals['t_ms']}f}",
            "left_x": f"{rec.left[0]:.{self.decimals['raw']}f}",
            "left_y": f"{rec.left[1]:.{self.decimals['raw']}f}",
            "right_x": f"{rec.right[0]:.{self.decimals['raw']}f}",
            "right_y": f"{rec.right[1]:.{self.decimals['raw']}f}",
            "valid": format(int(rec.left_valid) | (int(rec.right_valid) << 1), "X" if self.valid_base == 16 else "d"),
        }
        body = self.separator.join([self.prefix.lstrip("$")] + [vals.get(f, "") for f in self.fields])
        start = "$" if self.prefix.startswith("$") else ""
        if self.checksum == "xor8":
            return f"{start}{body}*{xor8(body.encode()):02X}{self.terminator}".encode("ascii")
        return f"{start}{body}{self.terminator}".encode("ascii")

    def parse(self, line: bytes) -> EyeRecord:
        """Parse one line (with or without its terminator).

        Raises:
            ParseError: with the reason (bad prefix, checksum, field count, number).
        """
        try:
            text = line.decode("ascii").strip("\r\n")
        except UnicodeDecodeError:
            raise ParseError("non-ASCII bytes") from None
        if not text.startswith(self.prefix):
            raise ParseError(f"does not start with {self.prefix!r}")
        start = 1 if self.prefix.startswith("$") else 0
        if self.checksum == "xor8":
            star = text.rfind("*")
            if star < 0 or len(text) - star != 3:
                raise ParseError("no *HH checksum")
            body = text[start:star]
            try:
                want = int(text[star + 1:], 16)
            except ValueError:
                raise ParseError("checksum is not hexadecimal") from None
            if xor8(body.encode()) != want:
                raise ParseError("checksum mismatch")
        else:
            body = text[start:]
        parts = body.split(self.separator)[1:]
        if len(parts) != len(self.fields):
            raise ParseError(f"{len(parts)} fields, expected {len(self.fields)}")
        vals = dict(zip(self.fields, parts, strict=True))
        try:
            raw = [float(vals[k]) for k in ("left_x", "left_y", "right_x", "right_y")]
            valid = int(vals["valid"], self.valid_base)
            rec = EyeRecord(int(vals["counter"]), float(vals["t_ms"]) * self.time_scale,
                            (raw[0], raw[1]), (raw[2], raw[3]), bool(valid & 1), bool(valid & 2))
        except (KeyError, ValueError) as exc:
            raise ParseError(f"bad field value ({exc})") from None
        if not all(np.isfinite(raw)) or not np.isfinite(rec.t):
            raise ParseError("non-finite value")
        return rec


DEFAULT_PROTOCOL = LineProtocol()


def xor8(data: bytes) -> int:
    """XOR of all bytes (the NMEA 0183 checksum)."""
    c = 0
    for b in data:
        c ^= b
    return c


def encode_stream(t, raw, valid, protocol: LineProtocol = DEFAULT_PROTOCOL) -> bytes:
    """The byte stream of a recording.

    Args:
        t: (N,) recorder times, s.
        raw: (N, 2, 2) raw counts [sample, eye, (x, y)].
        valid: (N, 2) validity per eye.
    """
    out = bytearray()
    for i in range(len(t)):
        out += protocol.format(EyeRecord(i, float(t[i]), tuple(raw[i, 0]), tuple(raw[i, 1]),
                                         bool(valid[i, 0]), bool(valid[i, 1])))
    return bytes(out)
