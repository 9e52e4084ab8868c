"""Argument types shared by the commands: each refuses a bad value with one line naming the fix."""

from __future__ import annotations

import argparse
import math

from ..errors import one_line


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the fix, exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {one_line(message)} (see `{self.prog} --help`)\n")


def finite_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a number") from None
    if not math.isfinite(v) or abs(v) > 1e9:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a finite number of a sensible size")
    return v


def positive_float(text):
    v = finite_float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {ascii(text)}")
    return v


def probability(text):
    """A probability strictly between 0 and 1."""
    v = finite_float(text)
    if not 0 < v < 1:
        raise argparse.ArgumentTypeError(f"must lie between 0 and 1, got {ascii(text)}")
    return v


def non_negative_float(text):
    v = finite_float(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be 0 (off) or positive, got {ascii(text)}")
    return v


def whole_number(text):
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a whole number") from None


def positive_int(text):
    v = whole_number(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {ascii(text)}")
    if v > 10**9:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is too large")
    return v


def non_negative_int(text):
    v = whole_number(text)
    if not 0 <= v <= 10**9:
        raise argparse.ArgumentTypeError(f"must be a whole number from 0, got {ascii(text)}")
    return v


def marker_dictionary(text):
    """A ``cv2.aruco`` predefined dictionary name (checked here, at the command line, so that a
    step that may not need it does not run first)."""
    from calibration.camera import aruco_dictionary  # OpenCV only when this option is given

    try:
        aruco_dictionary(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def seed(text):
    v = whole_number(text)
    if not 0 <= v < 2**63:
        raise argparse.ArgumentTypeError(f"a seed is a whole number from 0 to 2^63-1, got {ascii(text)}")
    return v


def publish_url(text):
    """``udp://HOST:PORT`` or ``tcp://HOST:PORT`` with a port 1-65535, as the publisher's own
    ``parse_publish_url`` reads it (one parser: a URL passed here is one the publisher takes)."""
    from ..errors import UserError
    from ..live.publish import parse_publish_url

    try:
        parse_publish_url(text)
    except UserError:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not udp://HOST:PORT or tcp://HOST:PORT with a port "
                                         "1-65535, e.g. udp://127.0.0.1:5555") from None
    return text


def times_and_distance(text: str) -> tuple:
    """``T1,T2,MM`` -> (t1 s, t2 s, mm) for ``map --distance``."""
    try:
        t1, t2, mm = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not T1,T2,MM (two times in s, a distance in mm), e.g. "
                                         "5,12.5,3000") from None
    if not (t1 >= 0 and t2 >= 0 and t1 != t2 and mm > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: two different times >= 0 s and a distance > 0 mm")
    return t1, t2, mm


def resolution(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 1280x720") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"{text!r}: width and height must be 64-8192 pixels")
    return w, h


def host_port(text):
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not HOST:PORT, e.g. 127.0.0.1:5555 (port 0: any free one)")
    return host, int(port)
