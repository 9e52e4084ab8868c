"""The ``wearable-gaze`` command line: each command parses, calls one library function, prints.

Bad input at any boundary gets one line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import errno
import json
import logging
import math
import os
import sys
from pathlib import Path

from .errors import UserError, check_output

log = logging.getLogger("wearable_gaze")


def _one_line(text: str) -> str:
    """``text`` as one printable line: whitespace runs become one space, control characters
    (a terminal escape in a file name or a header) are shown escaped."""
    text = " ".join(text.split())
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line naming the fix, exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {_one_line(message)} (see `{self.prog} --help`)\n")


def _float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a number") from None
    if not math.isfinite(v) or abs(v) > 1e9:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a finite number of a sensible size")
    return v


def _positive_float(text):
    v = _float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {ascii(text)}")
    return v


def _non_negative_float(text):
    v = _float(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be 0 (off) or positive, got {ascii(text)}")
    return v


def _positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a whole number") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {ascii(text)}")
    if v > 10**9:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is too large")
    return v


def _seed(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not a whole number") from None
    if not 0 <= v < 2**63:
        raise argparse.ArgumentTypeError(f"a seed is a whole number from 0 to 2^63-1, got {ascii(text)}")
    return v


def _publish_url(text):
    """``udp://HOST:PORT`` or ``tcp://HOST:PORT`` with a port 0-65535."""
    scheme, sep, rest = text.partition("://")
    host, colon, port = rest.rpartition(":")
    if not sep or scheme not in ("udp", "tcp") or not colon or not host or not port.isdigit() \
            or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not udp://HOST:PORT or tcp://HOST:PORT with a port "
                                         "0-65535, e.g. udp://127.0.0.1:5555")
    return text


# --- estimate ---------------------------------------------------------------------------------

def cmd_estimate(args) -> int:
    from .pipeline.estimate import estimate_file, format_table  # noqa: PLC0415

    if args.export_density and args.method not in ("voxel", "paper"):
        raise UserError("--export-density needs --method voxel or --method paper (the other methods keep no "
                        "density); add one of them or drop --export-density")
    results = estimate_file(args.viewlines, args.method, args.sigma_deg, args.export_density)
    if args.json:
        for r in results:
            print(json.dumps(r))
    else:
        print(format_table(results))
    return 0


# --- reproduce --------------------------------------------------------------------------------

def cmd_reproduce(args) -> int:
    from .paper.reproduce import reproduce_figure5, reproduce_table1  # noqa: PLC0415
    from .progress import progress_bar  # noqa: PLC0415

    out = Path(args.out)
    if args.what == "table1":
        with progress_bar("table 1 trials", args.trials * 5) as cb:
            result, paths = reproduce_table1(out, args.trials, args.seed, progress=cb)
        print(result.format())
    elif args.what == "calibration":
        from .formats.atomic import write_text  # noqa: PLC0415
        from .paper.calstudy import run_calibration_study  # noqa: PLC0415

        with progress_bar("calibration trials", args.trials) as cb:
            result = run_calibration_study(trials=args.trials, seed=args.seed, progress=cb)
        text = result.format()
        print(text)
        paths = [out / "calibration_study.md"]
        write_text(paths[0], text + "\n")
    else:
        result, paths = reproduce_figure5(out, args.seed)
        print(result.format())
    print()
    for p in paths:
        print(f"wrote {p}")
    return 0


# --- simulate -------------------------------------------------------------------------------

def _resolution(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 1280x720") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"{text!r}: width and height must be 64-8192 pixels")
    return w, h


def cmd_simulate(args) -> int:
    from .progress import progress_bar  # noqa: PLC0415
    from .sim.simulate import simulate_scenario  # noqa: PLC0415

    with progress_bar("rendering", 1) as cb:
        manifest = simulate_scenario(args.scenario, args.out, args.seed, args.duration, args.resolution, cb)
    files = manifest["files"]
    print(f"wrote session {args.out} (scenario {manifest['scenario']['name']}, seed {args.seed}): "
          f"{manifest.get('n_frames', 0)} frames, {manifest.get('n_eye_samples', 0)} eye samples, "
          f"{len(files)} files")
    return 0


# --- calibration ------------------------------------------------------------------------------

def cmd_calibrate_camera(args) -> int:
    from .pipeline.calibrate import calibrate_camera_files, format_camera_report  # noqa: PLC0415
    from .progress import progress_bar  # noqa: PLC0415

    with progress_bar("detecting the board", 1) as cb:
        cal, paths = calibrate_camera_files(args.inputs, args.board, args.out, args.model, args.max_views, cb)
    if args.json:
        print(json.dumps(cal.to_dict()))
    else:
        print(format_camera_report(cal))
        print()
        for p in paths:
            print(f"wrote {p}")
    return 0


def cmd_calibrate_eyes(args) -> int:
    from .pipeline.calibrate import calibrate_eyes_files, format_eyes_report  # noqa: PLC0415
    from .progress import progress_bar  # noqa: PLC0415

    with progress_bar("calibrating the eyes", 1) as cb:
        result = calibrate_eyes_files(args.source, args.camera, args.out, args.model, progress=cb)
    print(format_eyes_report(result))
    print(f"\nwrote {args.out}")
    return 0


def cmd_viewlines(args) -> int:
    from .pipeline.calibrate import viewlines_files  # noqa: PLC0415

    counts = viewlines_files(args.eye, args.eyes, args.poses, args.out, args.max_gap)
    print(f"wrote {args.out}: {counts['written']} of {counts['samples']} samples "
          f"({counts['no_pose']} without a head pose within {args.max_gap} s, "
          f"{counts['both_eyes_invalid']} with both eyes invalid)")
    return 0


# --- tracking ---------------------------------------------------------------------------------

def cmd_track(args) -> int:
    from .pipeline.track import track_video  # noqa: PLC0415
    from .progress import progress_bar  # noqa: PLC0415

    with progress_bar("tracking", 1) as cb:
        counts = track_video(args.video, args.camera, args.out, markers=args.markers, reference=args.reference,
                             reference_size_mm=args.reference_size_mm, overlay=args.overlay,
                             timestamps=args.timestamps, progress=cb, smooth_s=args.smooth)
    print(f"wrote {args.out}: {counts['posed']} of {counts['frames']} frames with a pose"
          + (f"; overlay {args.overlay}" if args.overlay else ""))
    return 0


def cmd_markers(args) -> int:
    from .pipeline.track import parse_ids, write_marker_sheets  # noqa: PLC0415

    for p in write_marker_sheets(args.dict, parse_ids(args.ids), args.size_mm, args.out, args.page, args.dpi):
        print(f"wrote {p}")
    return 0


# --- live -------------------------------------------------------------------------------------

def cmd_live(args) -> int:
    from .live.app import run_live  # noqa: PLC0415

    status = None if args.quiet else sys.stderr
    try:
        st = run_live(args.serial, args.camera, args.camera_calib, args.eyes, args.markers, args.record, args.publish,
                      args.baud, args.duration, status_stream=status)
    except UserError:
        if status is not None:
            print(file=sys.stderr)            # past the status line
        raise
    print(f"\nlive: ended: {st.end_reason}; {st.samples} eye samples, {st.published} messages, "
          f"{st.distinct_targets} distinct targets ({st.targets} target messages), latency median "
          f"{st.latency_all.percentile(50):.1f} ms, p95 {st.latency_all.percentile(95):.1f} ms; {st.counters()}"
          + (f"; recorded {args.record}" if args.record else ""), file=sys.stderr)
    return 0


def _host_port(text):
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{ascii(text)} is not HOST:PORT, e.g. 127.0.0.1:5555 (port 0: any free one)")
    return host, int(port)


def cmd_emulate(args) -> int:
    from .formats.session import load_session  # noqa: PLC0415
    from .sim.emulate import RecorderEmulator  # noqa: PLC0415

    sess = load_session(args.session)
    path = sess.path("eye_serial")
    if path is None or not path.is_file():
        raise UserError(f"{args.session}: no recorder byte stream (eye_serial.bin); simulated sessions and "
                        f"'live --record' recordings have one")
    emu = RecorderEmulator(path.read_bytes(), loop=args.loop, duration_s=args.duration)
    where = emu.open_pty() if args.pty else emu.listen_tcp(*args.listen)
    video = sess.path("scene_video")
    print(f"emulating the eye recorder of {args.session} on {where} ({len(emu.records)} records, "
          f"{emu.period_s:.1f} s{', looped' if args.loop else ''}); Ctrl-C stops. Try (docs/live.md):\n"
          f"  wearable-gaze live --serial {where} --camera {video} --markers {sess.path('marker_map') or 'map.json'} "
          f"--camera-calib CAL/camera.json --eyes CAL/eyes.json", file=sys.stderr, flush=True)
    try:
        while not emu.finished.wait(0.2):
            pass
    finally:
        emu.stop()
    print(f"emulate: {emu.sent} records sent", file=sys.stderr)
    return 0


# --- demo -------------------------------------------------------------------------------------

def cmd_process(args) -> int:
    from .pipeline.process import format_result, process_session  # noqa: PLC0415
    from .progress import progress_bar  # noqa: PLC0415

    res = process_session(args.session, args.out, args.method, args.camera, args.eyes, args.force,
                          overlay=not args.no_overlay, track_every=args.track_every,
                          progress_factory=lambda name: progress_bar(name, 1))
    print(format_result(res))
    for p in res.problems:
        print(f"wearable-gaze process: {p}", file=sys.stderr)
    return res.exit_status                  # 2 when no target could be estimated


def cmd_demo(args) -> int:
    from .pipeline.demo import run_demo  # noqa: PLC0415

    return run_demo(Path(args.out), args.seed, args.duration)


def build_parser() -> argparse.ArgumentParser:
    from estimator import METHODS  # noqa: PLC0415

    p = _Parser(prog="wearable-gaze",
                description="Where in 3D a person looks, from a head-worn binocular eye tracker.")
    p.add_argument("-v", "--verbose", action="store_true", help="log what each step does")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    e = sub.add_parser("estimate", help="estimate gazed points from a view-line CSV")
    e.add_argument("viewlines", metavar="VIEWLINES.csv", help="view-line CSV (docs/formats.md)")
    e.add_argument("--method", choices=METHODS, default="voxel", help="estimator (default: voxel)")
    e.add_argument("--json", action="store_true", help="one JSON object per segment per line")
    e.add_argument("--sigma-deg", type=_positive_float, default=1.0, metavar="S",
                   help="angular noise of a view line, degrees per axis (default: 1.0)")
    e.add_argument("--export-density", metavar="OUT.ply",
                   help="write the voxel density as a PLY point cloud (voxel and paper methods)")
    e.set_defaults(func=cmd_estimate)

    r = sub.add_parser("reproduce", help="reproduce the paper's simulation results")
    r.add_argument("what", choices=("table1", "figure5", "calibration"), help="table1: Table 1 with Fig. 11 and "
                   "13; figure5: depth from single binocular pairs; calibration: the section 2.3.3 correction "
                   "table and the eye-centre estimate")
    r.add_argument("--trials", type=_positive_int, default=20, metavar="N", help="trials per depth (default: 20)")
    r.add_argument("--seed", type=_seed, default=0, metavar="S", help="random seed (default: 0)")
    r.add_argument("--out", default="reproduce-out", metavar="DIR", help="output folder (default: reproduce-out)")
    r.set_defaults(func=cmd_reproduce)

    cc = sub.add_parser("calibrate-camera", help="scene-camera intrinsics from board images or a video")
    cc.add_argument("inputs", nargs="+", metavar="INPUT", help="images, folders of images, or videos")
    cc.add_argument("--board", required=True, metavar="SPEC",
                    help="chessboard:COLSxROWS:SQUARE_MM (inner corners) or "
                         "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares)")
    cc.add_argument("-o", "--out", required=True, metavar="camera.json", help="camera JSON to write")
    cc.add_argument("--model", choices=("pinhole", "fisheye"), default="pinhole", help="lens model (default pinhole)")
    cc.add_argument("--max-views", type=_positive_int, default=40, metavar="N",
                    help="views kept for coverage when more are found (default 40)")
    cc.add_argument("--json", action="store_true", help="print the camera JSON instead of the table")
    cc.set_defaults(func=cmd_calibrate_camera)

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

    vl = sub.add_parser("viewlines", help="raw eye samples + eye calibration + head poses -> view-line CSV")
    vl.add_argument("eye", metavar="EYE.csv", help="eye samples (docs/session.md)")
    vl.add_argument("--eyes", required=True, metavar="eyes.json", help="from calibrate-eyes")
    vl.add_argument("--poses", required=True, metavar="POSES.csv", help="head poses (docs/formats.md)")
    vl.add_argument("-o", "--out", required=True, metavar="viewlines.csv", help="view-line CSV to write")
    vl.add_argument("--max-gap", type=_positive_float, default=0.1, metavar="S",
                    help="use a sample only with head poses within S seconds on both sides (default 0.1)")
    vl.set_defaults(func=cmd_viewlines)

    tk = sub.add_parser("track", help="head pose for every frame of a scene video (markers or a flat reference)")
    tk.add_argument("video", metavar="VIDEO", help="scene-camera video")
    tk.add_argument("--camera", required=True, metavar="camera.json", help="scene-camera calibration")
    src = tk.add_mutually_exclusive_group(required=True)
    src.add_argument("--markers", metavar="map.json", help="marker map (docs/formats.md)")
    src.add_argument("--reference", metavar="IMAGE", help="image of a flat textured surface in the room")
    tk.add_argument("--reference-size-mm", type=_positive_float, nargs=2, metavar=("W", "H"),
                    help="the reference surface's width and height in mm")
    tk.add_argument("-o", "--out", required=True, metavar="poses.csv", help="pose CSV to write")
    tk.add_argument("--overlay", metavar="OUT.mp4", help="also write a video with markers and world axes drawn")
    tk.add_argument("--timestamps", metavar="CSV", help="frame times (frame,t); default the session's "
                    "scene_timestamps.csv beside the video, else frame / fps")
    tk.add_argument("--smooth", type=_non_negative_float, default=0.0, metavar="S",
                    help="average poses over a centred window of S seconds (no lag offline; default off)")
    tk.set_defaults(func=cmd_track)

    mk = sub.add_parser("markers", help="printable marker sheets at exact scale, and a marker-map template")
    mk.add_argument("--dict", default="DICT_4X4_50", metavar="DICT", help="cv2.aruco dictionary (default DICT_4X4_50)")
    mk.add_argument("--ids", required=True, metavar="IDS", help="e.g. 0-11 or 3,5,7-9")
    mk.add_argument("--size-mm", type=_positive_float, required=True, metavar="MM", help="black square side, mm")
    mk.add_argument("-o", "--out", required=True, metavar="sheet.pdf|sheet.png", help="PDF, or PNG at --dpi")
    mk.add_argument("--page", choices=("a4", "letter", "a3"), default="a4", help="paper size (default a4)")
    mk.add_argument("--dpi", type=_positive_int, default=300, metavar="N", help="raster resolution (default 300)")
    mk.set_defaults(func=cmd_markers)

    sm = sub.add_parser("simulate", help="write a synthetic session (video, eye data, calibration, truth)")
    sm.add_argument("--scenario", default="lab-walkabout", metavar="NAME|FILE.json",
                    help="paper-table1, lab-walkabout, moving-target, calibration-only, or a scenario "
                         "JSON file (docs/scenarios.md); default lab-walkabout")
    sm.add_argument("-o", "--out", required=True, metavar="SESSION_DIR", help="new session folder")
    sm.add_argument("--seed", type=_seed, default=0, metavar="S", help="random seed (default: 0)")
    sm.add_argument("--duration", type=_positive_float, default=None, metavar="S",
                    help="session length in seconds (default: the scenario's)")
    sm.add_argument("--resolution", type=_resolution, default=None, metavar="WxH",
                    help="scene-camera resolution (default: the scenario's, 1280x720)")
    sm.set_defaults(func=cmd_simulate)

    pr = sub.add_parser("process", help="a recorded session -> fixated 3D targets, plots and a report")
    pr.add_argument("session", metavar="SESSION", help="session folder (docs/session.md)")
    pr.add_argument("-o", "--out", default=None, metavar="OUT", help="output folder (default SESSION/processed)")
    pr.add_argument("--method", choices=METHODS, default="voxel", help="estimator (default: voxel)")
    pr.add_argument("--camera", metavar="camera.json", help="use this camera calibration instead of the session's")
    pr.add_argument("--eyes", metavar="eyes.json", help="use this eye calibration instead of the session's")
    pr.add_argument("--force", action="store_true", help="redo every step")
    pr.add_argument("--no-overlay", action="store_true", help="skip the overlay animation in the report")
    pr.add_argument("--track-every", type=_positive_int, default=2, metavar="N",
                    help="track one scene frame in N and interpolate the rest (default 2)")
    pr.set_defaults(func=cmd_process)

    lv = sub.add_parser("live", help="live session: serial eye data + scene camera -> 3D targets, published and "
                                     "recorded")
    lv.add_argument("--serial", required=True, metavar="PORT",
                    help="serial port or pyserial URL (socket://, rfc2217://, loop://)")
    lv.add_argument("--baud", type=_positive_int, default=115200, metavar="N", help="baud rate (default 115200)")
    lv.add_argument("--camera", required=True, metavar="SOURCE", help="camera index, device path, URL or video file")
    lv.add_argument("--camera-calib", required=True, metavar="camera.json", help="scene-camera calibration")
    lv.add_argument("--eyes", required=True, metavar="eyes.json", help="eye calibration")
    lv.add_argument("--markers", required=True, metavar="map.json", help="marker map")
    lv.add_argument("--record", metavar="DIR", help="record everything as a session folder")
    lv.add_argument("--publish", type=_publish_url, metavar="udp://HOST:PORT",
                    help="also send the JSON lines to udp:// or tcp://")
    lv.add_argument("--duration", type=_positive_float, default=None, metavar="S", help="stop after S seconds")
    lv.add_argument("--quiet", action="store_true", help="no status line")
    lv.set_defaults(func=cmd_live)

    em = sub.add_parser("emulate", help="play a session's eye-recorder stream at its own pace, for 'live' "
                                        "without the hardware")
    em.add_argument("session", metavar="SESSION", help="session folder with eye_serial.bin (simulated or recorded)")
    where = em.add_mutually_exclusive_group()
    where.add_argument("--listen", type=_host_port, default=("127.0.0.1", 5555), metavar="HOST:PORT",
                       help="serve one reader over TCP (default 127.0.0.1:5555); 'live --serial socket://HOST:PORT'")
    where.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal, read as a serial port")
    em.add_argument("--loop", action="store_true", help="start again at the end, clock and counter running on")
    em.add_argument("--duration", type=_positive_float, default=None, metavar="S", help="stop after S seconds")
    em.set_defaults(func=cmd_emulate)

    d = sub.add_parser("demo", help="simulate the default session (lab-walkabout), process it, compare with the truth")
    d.add_argument("--seed", type=_seed, default=0, metavar="S", help="random seed (default: 0)")
    d.add_argument("--duration", type=_positive_float, default=20.0, metavar="S", help="session length (default: 20)")
    d.add_argument("--out", default="wearable-gaze-demo", metavar="DIR", help="output folder")
    d.set_defaults(func=cmd_demo)
    return p


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    try:
        return version("wearable-gaze")
    except PackageNotFoundError:
        from . import __version__  # noqa: PLC0415

        return __version__


# Per command: (output option, is a folder, the options naming its inputs). main() refuses an
# output that is an input, a folder where a file is wanted (or the reverse), a parent that is a
# file or an unwritable folder, before the command runs.
OUTPUTS = {
    "estimate": [("export_density", False, ("viewlines",))],
    "reproduce": [("out", True, ())],
    "calibrate-camera": [("out", False, ("inputs",))],
    "calibrate-eyes": [("out", False, ("source", "camera"))],
    "viewlines": [("out", False, ("eye", "eyes", "poses"))],
    "track": [("out", False, ("video", "camera", "markers", "reference", "timestamps")),
              ("overlay", False, ("video", "camera", "markers", "reference", "timestamps", "out"))],
    "markers": [("out", False, ())],
    "simulate": [("out", True, ("scenario",))],
    "process": [("out", True, ("session", "camera", "eyes"))],
    "live": [("record", True, ("camera", "camera_calib", "eyes", "markers"))],
    "demo": [("out", True, ())],
}
OPTION = {"out": "-o", "export_density": "--export-density", "overlay": "--overlay", "record": "--record"}


# Input files whose readers (in files other code owns) do not name a fix: checked here first.
INPUT_FILES = {"track": [("video", "VIDEO", "the scene video"), ("reference", "--reference", "the reference image")]}


def _check_inputs(args) -> None:
    for attr, opt, what in INPUT_FILES.get(args.command, ()):
        p = getattr(args, attr, None)
        if p is None or Path(p).is_file():
            continue
        hint = "is a folder" if Path(p).is_dir() else "no such file"
        raise UserError(f"{opt} {p}: {hint}; pass {what} (check the path)")


def _check_outputs(args) -> None:
    for attr, folder, input_attrs in OUTPUTS.get(args.command, ()):
        out = getattr(args, attr, None)
        if out is None:
            continue
        inputs = []
        for a in input_attrs:
            v = getattr(args, a, None)
            inputs += [] if v is None else [v] if isinstance(v, str) else list(v)
        opt = "--out" if attr == "out" and args.command in ("reproduce", "demo") else OPTION[attr]
        check_output(out, inputs, opt, folder=folder)


OS_FIX = {errno.EACCES: "the place is not writable: choose another or change its permissions",
          errno.EPERM: "the place is not writable: choose another or change its permissions",
          errno.EROFS: "the file system is read-only: choose another place",
          errno.EISDIR: "it is a folder: give a file name",
          errno.ENOTDIR: "a part of the path is a file, not a folder: choose another path",
          errno.EEXIST: "it exists already: choose a new name",
          errno.ENOSPC: "the disk is full: free some space or choose another disk",
          errno.EDQUOT: "the disk quota is exceeded: free some space or choose another disk",
          errno.ENAMETOOLONG: "the name is too long: choose a shorter path"}


def _quiet_opencv() -> None:
    """No OpenCV / FFmpeg log lines on stderr: a bad input gets exactly one line."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")        # AV_LOG_QUIET
    if "cv2" in sys.modules:
        cv2 = sys.modules["cv2"]
        try:
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        except AttributeError:  # pragma: no cover - very old OpenCV
            pass


class _LogFormatter(logging.Formatter):
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


def _log_to_stderr(args) -> logging.Handler:
    """A handler writing log lines to the current stderr while a command runs (main() removes it
    afterwards, so that running main() again in one process never writes to a stale stream)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_LogFormatter(f"wearable-gaze {args.command or ''}".strip(), args.verbose))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(logging.INFO if args.verbose else logging.WARNING)
    return handler


def main(argv=None) -> int:
    _quiet_opencv()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    name = f"wearable-gaze {args.command}"
    level = logging.getLogger().level
    handler = _log_to_stderr(args)
    try:
        import cv2  # noqa: PLC0415

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        _check_inputs(args)
        _check_outputs(args)
        return args.func(args)
    except UserError as exc:
        print(f"{name}: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:                      # an output that cannot be written (or a device gone)
        where = exc.filename if exc.filename is not None else "?"
        fix = OS_FIX.get(exc.errno, "check the path and try again")
        print(_one_line(f"{name}: cannot write or read {where}: {exc.strerror or exc}; {fix}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:                     # a bug, not a bad input: say so, keep the traceback for -v
        if args.verbose:
            raise
        msg = _one_line(str(exc))[:200]
        print(f"{name}: internal error ({type(exc).__name__}: {msg}); this is a bug: rerun with -v for the "
              "traceback and report it", file=sys.stderr)
        return 1
    finally:
        logging.getLogger().removeHandler(handler)
        logging.getLogger().setLevel(level)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
