"""What ``main`` does around every command: inputs and outputs checked before it runs, log lines
on stderr while it runs, no OpenCV or FFmpeg noise."""

from __future__ import annotations

import errno
import logging
import os
import sys
from pathlib import Path

from ..errors import UserError, check_output

# Per command: (output option, is a folder (or args -> whether it is), the options naming its inputs). main() refuses an
# output that is an input, a folder where a file is wanted (or the reverse), a parent that is a
# file or an unwritable folder, before the command runs.
OUTPUTS = {
    "estimate": [("export_density", False, ("viewlines",))],
    "fixations": [("out", False, ("viewlines",))],
    "reproduce": [("out", True, ())],
    "track": [("out", False, ("video", "camera", "markers", "reference", "timestamps")),
              ("overlay", False, ("video", "camera", "markers", "reference", "timestamps", "out"))],
    "map": [("out", lambda a: a.markerless, ("inputs", "camera", "extend", "markers"))],
    "simulate": [("out", True, ("scenario",))],
    "process": [("out", True, ("session", "camera", "eyes", "person", "markers", "aois"))],
    "aoi": [("out", True, ("aois", "markers"))],
    "learn-bias": [("out", False, ("session", "validation", "processed", "eyes"))],
    "import": [("out", True, ("src", "markers", "camera", "kappa_recording"))],
    "export-recording": [("out", True, ("session",))],
    "live": [("record", True, ("camera", "camera_calib", "eyes", "markers"))],
    "demo": [("out", True, ())],
}
OPTION = {"out": "-o", "export_density": "--export-density", "overlay": "--overlay", "record": "--record"}


# Input files whose readers (in files other code owns) do not name a fix: checked here first.
INPUT_FILES = {"track": [("video", "VIDEO", "the scene video"), ("reference", "--reference", "the reference image")]}


def check_inputs(args) -> None:
    for attr, opt, what in INPUT_FILES.get(args.command, ()):
        p = getattr(args, attr, None)
        if p is None or Path(p).is_file():
            continue
        hint = "is a folder" if Path(p).is_dir() else "no such file"
        raise UserError(f"{opt} {p}: {hint}; pass {what} (check the path)")


def check_outputs(args) -> None:
    for attr, folder, input_attrs in OUTPUTS.get(args.command, ()):
        out = getattr(args, attr, None)
        if out is None:
            continue
        inputs = []
        for a in input_attrs:
            v = getattr(args, a, None)
            if a == "scenario" and _named_scenario(v):
                continue                        # `simulate --scenario survey -o survey`: a name, not a file
            inputs += [] if v is None else [v] if isinstance(v, str) else list(v)
        opt = "--out" if attr == "out" and args.command in ("reproduce", "demo") else OPTION[attr]
        check_output(out, inputs, opt, folder=folder(args) if callable(folder) else folder)


def _named_scenario(value) -> bool:
    """A named scenario (``simulate`` reads it, not a file of that name)."""
    from ..sim.scenario import NAMED

    return value in NAMED


OS_FIX = {errno.EACCES: "the place is not writable: choose another or change its permissions",
          errno.EPERM: "the place is not writable: choose another or change its permissions",
          errno.EROFS: "the file system is read-only: choose another place",
          errno.EISDIR: "it is a folder: give a file name",
          errno.ENOTDIR: "a part of the path is a file, not a folder: choose another path",
          errno.EEXIST: "it exists already: choose a new name",
          errno.ENOSPC: "the disk is full: free some space or choose another disk",
          errno.EDQUOT: "the disk quota is exceeded: free some space or choose another disk",
          errno.ENAMETOOLONG: "the name is too long: choose a shorter path"}


def quiet_opencv() -> None:
    """No OpenCV / FFmpeg log lines on stderr: a bad input gets exactly one line. The environment
    is set before OpenCV is first imported (FFmpeg reads it then); the log level covers an OpenCV
    imported earlier in the same process."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")        # AV_LOG_QUIET
    from calibration.cvcompat import silence_logging

    silence_logging()


class LogFormatter(logging.Formatter):
    """``wearable-gaze COMMAND: warning: message`` (with -v: the logger's name too)."""

    def __init__(self, prog: str, verbose: bool):
        super().__init__()
        self.prog, self.verbose = prog, verbose

    def format(self, record):
        where = f" {record.name}" if self.verbose else ""
        text = f"{self.prog}: {record.levelname.lower()}{where}: {record.getMessage()}"
        if record.exc_info and self.verbose:
            text += "\n" + self.formatException(record.exc_info)
        return text


def log_to_stderr(args) -> logging.Handler:
    """A handler writing log lines to the current stderr while a command runs (main() removes it
    afterwards, so that running main() again in one process never writes to a stale stream)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(LogFormatter(f"wearable-gaze {args.command or ''}".strip(), args.verbose))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel({0: logging.WARNING, 1: logging.INFO}.get(args.verbose, logging.DEBUG))
    return handler
