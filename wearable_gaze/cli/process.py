"""``wearable-gaze process`` and ``demo``."""

from __future__ import annotations

import sys
from pathlib import Path

from estimator import METHODS

from ..errors import UserError
from . import args as A


def check_rerun(args, inputs=()) -> None:
    """``--rerun``, checked before any work: rerun-sdk installed (one line naming the extra
    otherwise), and a file given is a place an .rrd can be written."""
    if getattr(args, "rerun", None) is None:
        if getattr(args, "rerun_frames", 0):
            raise UserError("--rerun-frames needs --rerun (out.rrd, a viewer's address, or nothing to spawn one)")
        return
    from ..errors import check_output
    from ..pipeline.report.rerun_view import parse_rerun_dest, require_rerun

    kind, where = parse_rerun_dest(args.rerun)
    require_rerun()
    if kind == "file":
        check_output(where, [p for p in inputs if p is not None], "--rerun")


EXIT_STATUS = ("exit status: 0 targets estimated and every step that ran succeeded; 2 no target could be estimated, "
               "or a bad input; 3 targets estimated but a step failed (e.g. export or report: its files are "
               "missing; the problems are on stderr and in summary.json)")


def cmd_process(args) -> int:
    from ..pipeline.process.session import process_session
    from ..pipeline.process.stepcache import format_result
    from ..progress import step_bars

    check_rerun(args, [args.session, args.camera, args.eyes, args.person, args.markers])
    res = process_session(args.session, args.out, args.method, args.camera, args.eyes, args.force,
                          overlay=not args.no_overlay, track_every=args.track_every,
                          progress_factory=step_bars(), person=args.person,
                          build_map=build_map_option(args),
                          sfm_map=args.map, overlay_video=args.overlay_video, rerun=args.rerun,
                          rerun_frames=args.rerun_frames, markers=args.markers, aois=args.aois)
    for note in res.summary.get("notes", []):
        print(f"wearable-gaze process: {note}", file=sys.stderr)
    print(format_result(res))
    for p in res.problems:
        print(f"wearable-gaze process: {p}", file=sys.stderr)
    return res.exit_status                  # 0 ok, 2 no target, 3 targets but a step failed (EXIT_STATUS)


def build_map_option(args) -> tuple | None:
    """``--build-map MM [--map-dict DICT]`` as (side mm, dictionary), or None; ``--map-dict``
    alone, which nothing would use, refused."""
    from ..pipeline.maps.markers import DEFAULT_DICT

    if args.build_map is None:
        if args.map_dict is not None:
            raise UserError("--map-dict names the dictionary of the markers --build-map MM builds a map of: give "
                            "--build-map too, or leave --map-dict out")
        return None
    return args.build_map, args.map_dict or DEFAULT_DICT


def cmd_demo(args) -> int:
    from ..pipeline.demo import run_demo

    return run_demo(None if args.out is None else Path(args.out), args.seed, args.duration, args.reuse)


def add_process(sub) -> None:
    """Declare the command and its arguments."""
    pr = sub.add_parser("process", help="a recorded session -> fixated 3D targets, plots and a report",
                        epilog=EXIT_STATUS)
    pr.add_argument("session", metavar="SESSION", help="session folder (docs/session.md)")
    pr.add_argument("-o", "--out", default=None, metavar="OUT", help="output folder (default SESSION/processed)")
    pr.add_argument("--method", choices=METHODS, default="voxel", help="estimator (default: voxel)")
    pr.add_argument("--camera", metavar="camera.json", help="use this camera calibration instead of the session's")
    pr.add_argument("--eyes", metavar="eyes.json", help="use this eye calibration instead of the session's")
    pr.add_argument("--person", metavar="person.json",
                    help="apply this person's per-eye gaze correction (from learn-bias) to the view lines")
    pr.add_argument("--force", action="store_true", help="redo every step")
    pr.add_argument("--no-overlay", action="store_true", help="skip the overlay animation in the report")
    pr.add_argument("--overlay-video", action="store_true",
                    help="also write the overlay at full resolution, every frame: OUT/overlay_full.mp4 (H.264)")
    pr.add_argument("--markers", metavar="MAP.json",
                    help="track the video in this marker map (from 'wearable-gaze map') instead of the session's")
    pr.add_argument("--aois", metavar="aois.json",
                    help="areas of interest in the room (docs/aois.md): also write the AOI tables and plot")
    pr.add_argument("--build-map", type=A.positive_float, metavar="MM",
                    help="build a marker map from the session's video, markers of this side (mm), and track in it "
                         "(in place of the session's map, if it has one)")
    pr.add_argument("--map-dict", type=A.marker_dictionary, default=None, metavar="DICT",
                    help="the markers' cv2.aruco dictionary for --build-map (default DICT_4X4_50)")
    pr.add_argument("--map", metavar="SFM_FOLDER",
                    help="localise the scene video in this markerless map (map --markerless) instead of tracking "
                         "the session's markers")
    pr.add_argument("--track-every", type=A.positive_int, default=2, metavar="N",
                    help="track one scene frame in N and interpolate the rest (default 2)")
    add_rerun_option(pr, "also save the results for the rerun viewer: --rerun out.rrd, or a viewer's address "
                         "(rerun+http://HOST:PORT/proxy), or --rerun alone to spawn one (pip install "
                         "'wearable-gaze[rerun]'; docs/viewing.md)")
    pr.add_argument("--rerun-frames", type=A.non_negative_int, default=0, metavar="N",
                    help="with --rerun: one scene frame in N as the camera's image (default 0: none)")
    pr.set_defaults(func=cmd_process)


def add_rerun_option(parser, help_text: str) -> None:
    """``--rerun [DEST]``: no value spawns a viewer (or connects to the local one)."""
    from ..pipeline.report.rerun_view import SPAWN

    parser.add_argument("--rerun", nargs="?", const=SPAWN, default=None, metavar="out.rrd|URL", help=help_text)


def add_demo(sub) -> None:
    """Declare the command and its arguments."""
    d = sub.add_parser("demo", help="simulate the default session (lab-walkabout), process it, compare with the truth")
    d.add_argument("--seed", type=A.seed, default=0, metavar="S", help="random seed (default: 0)")
    d.add_argument("--duration", type=A.positive_float, default=20.0, metavar="S", help="session length (default: 20)")
    d.add_argument("--out", default=None, metavar="DIR",
                   help="output folder, new or empty (default: a fresh ./wearable-gaze-demo-YYYYmmdd-HHMMSS)")
    d.add_argument("--reuse", action="store_true",
                   help="with --out: reuse the session and results an earlier demo left there")
    d.set_defaults(func=cmd_demo)
