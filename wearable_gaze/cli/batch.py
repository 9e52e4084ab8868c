"""``wearable-gaze batch``: many sessions processed as ``process`` would, in parallel (docs/batch.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from estimator import METHODS

from ..errors import check_output, one_line
from . import args as A


def scheduler_address(text):
    """A Dask scheduler's address: ``tcp://HOST:PORT`` (or ``tls://``, ``ucx://``), or
    ``HOST:PORT`` taken as TCP."""
    scheme, sep, rest = text.rpartition("://")
    host, colon, port = rest.rpartition(":")
    if (sep and scheme not in ("tcp", "tls", "ucx")) or not colon or not host or not port.isdigit() \
            or not 0 < int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a scheduler address tcp://HOST:PORT, e.g. "
                                         "tcp://node1:8786 (what 'dask scheduler' prints)")
    return text if sep else f"tcp://{text}"


def cmd_batch(args) -> int:
    from ..formats.aois import read_aois
    from ..pipeline.batch.run import BatchSettings, format_summary, run_batch
    from ..pipeline.process.options import check_map_options
    from ..progress import progress_bar
    from .process import build_map_option

    check_output(args.out, [*args.sessions, args.camera, args.eyes, args.markers, args.aois], "-o", folder=True)
    check_map_options(args.markers, args.build_map, None, True, False)        # before any session
    if args.aois is not None:
        read_aois(args.aois)                                                  # a bad file: before any session
    camera, eyes, markers, aois = (None if p is None else str(Path(p).resolve())
                                   for p in (args.camera, args.eyes, args.markers, args.aois))
    settings = BatchSettings(args.method, camera, eyes, args.force, not args.no_overlay, True,
                             args.track_every, build_map_option(args), markers, aois)
    with progress_bar("sessions", 1) as cb:
        res = run_batch(args.sessions, args.out, settings, workers=args.workers, scheduler=args.scheduler,
                        progress=cb)
    for name in res.failed + res.partial:
        st = res.statuses[name]
        print(one_line(f"wearable-gaze batch: {name} {st['state']}: {st.get('reason')}"), file=sys.stderr)
    print(format_summary(res))
    if res.interrupted:
        print("wearable-gaze batch: interrupted", file=sys.stderr)
    return res.exit_status            # 0 all done, 2 a session failed, 3 one partial, 130 interrupted


def add_batch(sub) -> None:
    """Declare the command and its arguments."""
    b = sub.add_parser("batch", help="many sessions processed as 'process' would, in parallel, here or on a Dask "
                                     "cluster; resumable, with one report",
                       epilog="exit status: 0 every session done; 2 a session failed (or a bad input); 3 a session "
                              "partial (targets, but a step failed), none failed; 130 interrupted")
    b.add_argument("sessions", nargs="+", metavar="SESSIONS",
                   help="session folders, or folders containing them (at any depth); native and imported alike")
    b.add_argument("-o", "--out", required=True, metavar="OUT",
                   help="output folder: OUT/NAME per session, batch.json, batch_report.html/.csv, all_targets.csv")
    where = b.add_mutually_exclusive_group()
    where.add_argument("--workers", type=A.positive_int, default=None, metavar="N",
                       help="worker processes on this machine (default: one per core)")
    where.add_argument("--scheduler", type=scheduler_address, metavar="tcp://HOST:PORT",
                       help="run on the Dask cluster of this scheduler (needs wearable-gaze[dask] here and on the "
                            "workers, and a file system they share)")
    b.add_argument("--method", choices=METHODS, default="voxel", help="estimator (default: voxel)")
    b.add_argument("--camera", metavar="camera.json", help="use this camera calibration for every session")
    b.add_argument("--eyes", metavar="eyes.json", help="use this eye calibration for every session")
    b.add_argument("--force", action="store_true", help="redo every session and step")
    b.add_argument("--no-overlay", action="store_true", help="skip the overlay animation in the reports")
    b.add_argument("--markers", metavar="MAP.json",
                   help="track every session's video in this marker map (from 'wearable-gaze map') instead of its own")
    b.add_argument("--aois", metavar="aois.json",
                   help="areas of interest (docs/aois.md): each session's AOI tables, and one table of sessions x "
                        "areas (batch_aoi_metrics.csv) with a plot per measure")
    b.add_argument("--build-map", type=A.positive_float, metavar="MM",
                   help="each session gets a marker map built from its video, markers of this side (mm), in place "
                        "of its own (as process --build-map)")
    b.add_argument("--map-dict", type=A.marker_dictionary, default=None, metavar="DICT",
                   help="the markers' cv2.aruco dictionary for --build-map (default DICT_4X4_50)")
    b.add_argument("--track-every", type=A.positive_int, default=2, metavar="N",
                   help="track one scene frame in N and interpolate the rest (default 2)")
    b.set_defaults(func=cmd_batch)
