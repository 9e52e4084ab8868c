"""``wearable-gaze calibrate-camera``, ``calibrate-eyes`` and ``viewlines``."""

from __future__ import annotations

import json

from tracking.timeline import MAX_POSE_GAP_S

from . import args as A


def cmd_calibrate_camera(args) -> int:
    from ..formats.camera import calibration_dict
    from ..pipeline.steps.calibrate import calibrate_camera_files, format_camera_report
    from ..progress import progress_bar

    with progress_bar("detecting the board", 1) as cb:
        cal, paths = calibrate_camera_files(args.inputs, args.board, args.out, args.model, args.max_views, cb)
    if args.json:
        print(json.dumps(calibration_dict(cal)))
    else:
        print(format_camera_report(cal))
        print()
        for p in paths:
            print(f"wrote {p}")
    return 0


def cmd_calibrate_eyes(args) -> int:
    from ..pipeline.steps.calibrate import calibrate_eyes_files, format_eyes_report
    from ..progress import progress_bar

    with progress_bar("calibrating the eyes", 1) as cb:
        result = calibrate_eyes_files(args.source, args.camera, args.out, args.model, progress=cb)
    print(format_eyes_report(result))
    print(f"\nwrote {args.out}")
    return 0


def cmd_viewlines(args) -> int:
    from ..pipeline.steps.calibrate import viewlines_files
    from ..progress import heartbeat

    with heartbeat("view lines"):               # a long recording: a line every few seconds in a log
        counts = viewlines_files(args.eye, args.eyes, args.poses, args.out, args.max_gap, args.person)
    print(f"wrote {args.out}: {counts['written']} of {counts['samples']} samples "
          f"({counts['no_pose']} without a head pose within {args.max_gap} s, "
          f"{counts['both_eyes_invalid']} with both eyes invalid)")
    return 0


def add_calibrate_camera(sub) -> None:
    """Declare the command and its arguments."""
    cc = sub.add_parser("calibrate-camera", help="scene-camera intrinsics from board images or a video")
    cc.add_argument("inputs", nargs="+", metavar="INPUT", help="images, folders of images, or videos")
    cc.add_argument("--board", required=True, metavar="SPEC",
                    help="chessboard:COLSxROWS:SQUARE_MM (inner corners) or "
                         "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares)")
    cc.add_argument("-o", "--out", required=True, metavar="camera.json", help="camera JSON to write")
    cc.add_argument("--model", choices=("pinhole", "fisheye"), default="pinhole", help="lens model (default pinhole)")
    cc.add_argument("--max-views", type=A.positive_int, default=40, metavar="N",
                    help="views kept for coverage when more are found (default 40)")
    cc.add_argument("--json", action="store_true", help="print the camera JSON instead of the table")
    cc.set_defaults(func=cmd_calibrate_camera)


def add_calibrate_eyes(sub) -> None:
    """Declare the command and its arguments."""
    ce = sub.add_parser("calibrate-eyes", help="the nine-point eye calibration (paper eq. 1-2), wall tilt and "
                        "eye centres")
    ce.add_argument("source", metavar="CALIB_DIR_OR_CSV",
                    help="a session folder, its calibration/eye folder, or eye_calibration.csv")
    ce.add_argument("--camera", required=True, metavar="camera.json", help="scene-camera calibration (JSON or "
                    "OpenCV YAML/XML)")
    ce.add_argument("-o", "--out", required=True, metavar="eyes.json", help="eye calibration to write")
    ce.add_argument("--model", choices=("quadratic", "cubic", "tps"), default="quadratic",
                    help="raw -> image map: the paper's quadratic (default), or cubic / thin-plate with > 9 targets")
    ce.set_defaults(func=cmd_calibrate_eyes)


def add_viewlines(sub) -> None:
    """Declare the command and its arguments."""
    vl = sub.add_parser("viewlines", help="raw eye samples + eye calibration + head poses -> view-line CSV")
    vl.add_argument("eye", metavar="EYE.csv", help="eye samples (docs/session.md)")
    vl.add_argument("--eyes", required=True, metavar="eyes.json", help="from calibrate-eyes")
    vl.add_argument("--poses", required=True, metavar="POSES.csv", help="head poses (docs/formats.md)")
    vl.add_argument("-o", "--out", required=True, metavar="viewlines.csv", help="view-line CSV to write")
    vl.add_argument("--max-gap", type=A.positive_float, default=MAX_POSE_GAP_S, metavar="S",
                    help=f"use a sample only with head poses within S seconds on both sides (default {MAX_POSE_GAP_S})")
    vl.add_argument("--person", metavar="person.json",
                    help="apply this person's per-eye gaze correction (from learn-bias)")
    vl.set_defaults(func=cmd_viewlines)
