"""``wearable-gaze live``: the live session."""

from __future__ import annotations

import sys

from ..errors import UserError
from . import args as A
from .process import add_rerun_option, check_rerun


def _check_inputs(args) -> None:
    """``--serial`` needs ``--camera`` and ``--eyes``; ``--device`` gives its own scene frames and
    eye rays, and takes neither."""
    if args.serial is not None:
        missing = [o for o, v in (("--camera", args.camera), ("--eyes", args.eyes)) if v is None]
        if missing:
            raise UserError(f"--serial needs {' and '.join(missing)} (the scene camera and the eye calibration)")
    else:
        given = (("--camera", args.camera), ("--eyes", args.eyes), ("--baud", args.baud))
        extra = [o for o, v in given if v is not None]
        if extra:
            raise UserError(f"--device sends its own scene frames and calibrated eye rays: drop {', '.join(extra)}")


def cmd_live(args) -> int:
    from ..live.app import run_live
    from ..live.device_app import run_device_live

    _check_inputs(args)
    check_rerun(args, [args.camera_calib, args.eyes, args.markers])
    status = None if args.quiet else sys.stderr
    try:
        if args.device is not None:
            st = run_device_live(args.device, args.camera_calib, args.markers, args.record, args.publish,
                                 args.duration, status_stream=status, rerun=args.rerun)
        else:
            st = run_live(args.serial, args.camera, args.camera_calib, args.eyes, args.markers, args.record,
                          args.publish, args.baud or 115200, args.duration, status_stream=status, rerun=args.rerun)
    except UserError:
        if status is not None:
            print(file=sys.stderr)            # past the status line
        raise
    print(f"\nlive: ended: {st.end_reason}; {st.samples} of the {st.eye_records} eye samples received processed "
          f"(the others dropped for room or still waiting for a frame at the end; all recorded), "
          f"{st.published} messages, "
          f"{st.distinct_targets} distinct targets ({st.targets} target messages), latency median "
          f"{st.latency_all.percentile(50):.1f} ms, p95 {st.latency_all.percentile(95):.1f} ms; {st.counters()}"
          + (f"; recorded {args.record}" if args.record else "")
          + (f"; rerun: {args.rerun}" if args.rerun is not None else ""), file=sys.stderr)
    return 0


def add_live(sub) -> None:
    """Declare the command and its arguments."""
    lv = sub.add_parser("live", help="live session: eye data (serial line or a networked eye tracker) + scene "
                                     "camera -> 3D targets, published and recorded")
    src = lv.add_mutually_exclusive_group(required=True)
    src.add_argument("--serial", metavar="PORT", help="serial port or pyserial URL (socket://, rfc2217://, loop://)")
    src.add_argument("--device", metavar="pupil-core://HOST:PORT",
                     help="a networked eye tracker: Pupil Core through Pupil Capture's network API (Pupil Remote's "
                          "address; its 3D gaze and the Frame Publisher's scene frames, raw BGR, or JPEG with "
                          "?frames=jpeg), or Pupil Neon through its real-time API (neon://HOST[:PORT], the Companion "
                          "app's address; needs the [neon] extra); docs/live.md")
    lv.add_argument("--baud", type=A.positive_int, default=None, metavar="N", help="baud rate (default 115200)")
    lv.add_argument("--camera", metavar="SOURCE", help="camera index, device path, URL or video file (--serial)")
    lv.add_argument("--camera-calib", required=True, metavar="camera.json", help="scene-camera calibration")
    lv.add_argument("--eyes", metavar="eyes.json", help="eye calibration (--serial)")
    lv.add_argument("--markers", required=True, metavar="map.json", help="marker map")
    lv.add_argument("--record", metavar="DIR", help="record everything as a session folder")
    lv.add_argument("--publish", type=A.publish_url, metavar="udp://HOST:PORT",
                    help="also send the JSON lines to udp:// or tcp://")
    add_rerun_option(lv, "also stream the session to the rerun viewer: --rerun alone spawns one (or connects to "
                         "the local one), --rerun rerun+http://HOST:PORT/proxy connects to one, --rerun out.rrd "
                         "saves it (pip install 'wearable-gaze[rerun]'; docs/viewing.md)")
    lv.add_argument("--duration", type=A.positive_float, default=None, metavar="S", help="stop after S seconds")
    lv.add_argument("--quiet", action="store_true", help="no status line")
    lv.set_defaults(func=cmd_live)
