"""The ``wearable-gaze`` command line: each command parses its arguments, calls one library
function and prints (one module per command group: estimate, paper, calibrate, fixations, track,
sim, process, aoi, batch, person, live, importer). Bad input at any boundary gets one line on stderr and exit status 2,
never a traceback (``safety``).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from ..errors import UserError, one_line
from . import aoi, batch, calibrate, estimate, fixations, importer, live, paper, person, process, safety, sim, track
from .args import Parser


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command, in the order of ``wearable-gaze --help``."""
    p = Parser(prog="wearable-gaze",
               description="Where in 3D a person looks, from a head-worn binocular eye tracker.")
    p.add_argument("-v", "--verbose", action="count", default=0,
                   help="log what each step does (-vv: and its details, for debugging)")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for add in (estimate.add_estimate, paper.add_reproduce, calibrate.add_calibrate_camera,
                calibrate.add_calibrate_eyes, calibrate.add_viewlines, fixations.add_fixations, track.add_track,
                track.add_markers, track.add_map, sim.add_simulate, importer.add_import, importer.add_export,
                process.add_process, aoi.add_aoi, batch.add_batch, person.add_learn_bias, live.add_live,
                sim.add_emulate, process.add_demo):
        add(sub)
    return p


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("wearable-gaze")
    except PackageNotFoundError:
        from .. import __version__

        return __version__


def main(argv=None) -> int:
    """Run one command (``argv``: the arguments, default ``sys.argv[1:]``); returns the exit status:
    0 done, 2 bad input (one line on stderr), 1 a bug (``-v`` shows the traceback), 130 Ctrl-C, 141 the
    reader of stdout left (``| head``)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    name = f"wearable-gaze {args.command}"
    level = logging.getLogger().level
    handler = safety.log_to_stderr(args)
    try:
        safety.quiet_opencv()
        safety.check_inputs(args)
        safety.check_outputs(args)
        return args.func(args)
    except UserError as exc:
        print(f"{name}: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except BrokenPipeError:                     # the reader of stdout left (| head): no error of ours to report
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())     # nor at the interpreter's last flush
        return 141                              # 128 + SIGPIPE, as a shell reports a writer the pipe stopped
    except OSError as exc:                      # an output that cannot be written (or a device gone)
        where = exc.filename if exc.filename is not None else "?"
        fix = safety.OS_FIX.get(exc.errno, "check the path and try again")
        print(one_line(f"{name}: cannot write or read {where}: {exc.strerror or exc}; {fix}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:                     # a bug, not a bad input: say so, keep the traceback for -v
        if args.verbose:
            raise
        msg = one_line(str(exc))[:200]
        print(f"{name}: internal error ({type(exc).__name__}: {msg}); this is a bug: rerun with -v for the "
              "traceback and report it", file=sys.stderr)
        return 1
    finally:
        logging.getLogger().removeHandler(handler)
        logging.getLogger().setLevel(level)
