"""``wearable-gaze simulate`` and ``emulate``."""

from __future__ import annotations

import sys

from ..errors import UserError
from . import args as A

DEFAULT_LISTEN = ("127.0.0.1", 5555)


def cmd_simulate(args) -> int:
    from ..progress import progress_bar
    from ..sim.simulate import simulate_scenario

    with progress_bar("rendering", 1) as cb:
        manifest = simulate_scenario(args.scenario, args.out, args.seed, args.duration, args.resolution, cb)
    files = manifest["files"]
    print(f"wrote session {args.out} (scenario {manifest['scenario']['name']}, seed {args.seed}): "
          f"{manifest.get('n_frames', 0)} frames, {manifest.get('n_eye_samples', 0)} eye samples, "
          f"{len(files)} files")
    return 0


def cmd_emulate(args) -> int:
    if args.device == "pupil-core":
        return _emulate_pupil_core(args)
    if args.device == "neon":
        return _emulate_neon(args)
    from ..formats.session import load_session
    from ..sim.emulate import RecorderEmulator

    sess = load_session(args.session)
    path = sess.path("eye_serial")
    if path is None or not path.is_file():
        raise UserError(f"{args.session}: no recorder byte stream (eye_serial.bin); simulated sessions and "
                        f"'live --record' recordings have one")
    emu = RecorderEmulator(path.read_bytes(), loop=args.loop, duration_s=args.duration)
    where = emu.open_pty() if args.pty else emu.listen_tcp(*(args.listen or DEFAULT_LISTEN))
    video = sess.path("scene_video")
    print(f"emulating the eye recorder of {args.session} on {where} ({len(emu.records)} records, "
          f"{emu.period_s:.1f} s{', looped' if args.loop else ''}); Ctrl-C stops. Try (docs/live.md):\n"
          f"  wearable-gaze live --serial {where} --camera {video} --markers {sess.path('marker_map') or 'map.json'} "
          f"--camera-calib CAL/camera.json --eyes CAL/eyes.json", file=sys.stderr, flush=True)
    _serve(emu)
    print(f"emulate: {emu.sent} records sent", file=sys.stderr)
    return 0


def _emulate_pupil_core(args) -> int:
    from ..formats.devices.pupil_net import DEFAULT_PORT
    from ..sim.pupil_core_emu import PupilCoreEmulator, device_stream

    _network_only(args, "--as pupil-core serves Pupil Capture's network API over TCP")
    emu = PupilCoreEmulator(device_stream(args.session), duration_s=args.duration)
    where = emu.listen(*(args.listen or ("127.0.0.1", DEFAULT_PORT)))
    print(f"emulating Pupil Capture's network API of {args.session} on {where} ({len(emu.stream.t)} gaze samples, "
          f"{len(emu.stream.frame_times)} frames; the stream starts at the first request); Ctrl-C stops. Try "
          f"(docs/live.md):\n  wearable-gaze live --device {where} --camera-calib CAL/camera.json --markers "
          f"{args.session}/markers.json", file=sys.stderr, flush=True)
    _serve(emu)
    print(f"emulate: {emu.sent} gaze messages, {emu.frames_sent} frames sent", file=sys.stderr)
    return 0


def _emulate_neon(args) -> int:
    from ..formats.devices.neon_rtp import DEFAULT_PORT
    from ..sim.neon_emu import NeonEmulator, session_camera
    from ..sim.pupil_core_emu import device_stream

    _network_only(args, "--as neon serves the Companion app's real-time API over the network")
    emu = NeonEmulator(device_stream(args.session), session_camera(args.session), duration_s=args.duration)
    where = emu.listen(*(args.listen or ("127.0.0.1", DEFAULT_PORT)))
    print(f"emulating the Neon Companion app's real-time API of {args.session} on {where} (RTSP on port "
          f"{emu.rtsp_port}, Time Echo on {emu.echo_port}; {len(emu.stream.t)} gaze samples, "
          f"{len(emu.stream.frame_times)} frames; the streams start at the first PLAY); Ctrl-C stops. Try "
          f"(docs/live.md):\n  wearable-gaze live --device {where} --camera-calib CAL/camera.json --markers "
          f"{args.session}/markers.json", file=sys.stderr, flush=True)
    _serve(emu)
    print(f"emulate: {emu.sent} gaze samples, {emu.frames_sent} frames sent", file=sys.stderr)
    return 0


def _network_only(args, serves: str) -> None:
    """One line, exit 2, for the serial recorder's options given to a network emulator."""
    if args.pty or args.loop:
        raise UserError(f"{serves}: drop {'--pty' if args.pty else '--loop'}")


def _serve(emu) -> None:
    """Until the emulator has sent its session (or Ctrl-C); then stop it."""
    try:
        while not emu.finished.wait(0.2):
            pass
    finally:
        emu.stop()


def add_simulate(sub) -> None:
    """Declare the command and its arguments."""
    sm = sub.add_parser("simulate", help="write a synthetic session (video, eye data, calibration, truth)")
    sm.add_argument("--scenario", default="lab-walkabout", metavar="NAME|FILE.json",
                    help="paper-table1, lab-walkabout, moving-target, calibration-only, survey, or a scenario "
                         "JSON file (docs/scenarios.md); default lab-walkabout")
    sm.add_argument("-o", "--out", required=True, metavar="SESSION_DIR", help="new session folder")
    sm.add_argument("--seed", type=A.seed, default=0, metavar="S", help="random seed (default: 0)")
    sm.add_argument("--duration", type=A.positive_float, default=None, metavar="S",
                    help="session length in seconds (default: the scenario's)")
    sm.add_argument("--resolution", type=A.resolution, default=None, metavar="WxH",
                    help="scene-camera resolution (default: the scenario's, 1280x720)")
    sm.set_defaults(func=cmd_simulate)


def add_emulate(sub) -> None:
    """Declare the command and its arguments."""
    em = sub.add_parser("emulate", help="play a session's eye-recorder stream at its own pace, for 'live' "
                                        "without the hardware")
    em.add_argument("session", metavar="SESSION", help="session folder with eye_serial.bin (simulated or recorded)")
    where = em.add_mutually_exclusive_group()
    where.add_argument("--listen", type=A.host_port, default=None, metavar="HOST:PORT",
                       help="serve one reader over TCP (default 127.0.0.1:5555; --as pupil-core: Pupil Remote's "
                            "address, default 127.0.0.1:50020; --as neon: the Companion app's HTTP API, default "
                            "127.0.0.1:8080); 'live --serial socket://HOST:PORT'")
    where.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal, read as a serial port")
    em.add_argument("--as", dest="device", choices=("serial", "pupil-core", "neon"), default="serial",
                    help="the eye tracker to be: 'serial' (the EMR-8-style recorder, default), 'pupil-core' (Pupil "
                         "Capture's network API: Pupil Remote, 3D gaze, Frame Publisher; 'live --device') or 'neon' "
                         "(the Companion app's real-time API: status, gaze with eye states, H.264 scene video)")
    em.add_argument("--loop", action="store_true", help="start again at the end, clock and counter running on")
    em.add_argument("--duration", type=A.positive_float, default=None, metavar="S", help="stop after S seconds")
    em.set_defaults(func=cmd_emulate)
