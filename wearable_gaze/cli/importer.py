"""``wearable-gaze import`` and ``export-recording``."""

from __future__ import annotations

from pathlib import Path

from ..formats.devices import MODULES
from . import args as A

FORMATS = tuple(MODULES)


def cmd_import(args) -> int:
    from ..formats.devices.common import ImportOptions
    from ..pipeline.importer import format_import, import_recording
    from ..progress import progress_bar

    opts = ImportOptions(markers=args.markers and Path(args.markers), camera=args.camera and Path(args.camera),
                         marker_size_mm=args.marker_size_mm,
                         kappa_recording=args.kappa_recording and Path(args.kappa_recording),
                         max_pose_gap_s=args.max_pose_gap)
    with progress_bar("importing", 1) as cb:
        manifest, report = import_recording(args.src, args.out, args.format, opts, cb)
    print(format_import(manifest, report, args.out))
    return 0


def cmd_export(args) -> int:
    from ..pipeline.importer import export_recording
    from ..progress import heartbeat

    with heartbeat("exporting"):                # a long session: a line every few seconds in a log
        command = export_recording(args.session, args.out, args.format, args.eye_states)
    print(f"wrote the simulated session {args.session} as a {args.format} recording in {args.out}; import it with: "
          f"{command}")
    return 0


def add_import(sub) -> None:
    """Declare the command and its arguments."""
    im = sub.add_parser("import", help="a recording from Pupil Core/Neon, Tobii Glasses 2/3 or Aria -> a session")
    im.add_argument("src", metavar="SRC", help="the recording's folder (docs/importers.md lists the files read)")
    im.add_argument("-o", "--out", required=True, metavar="SESSION", help="new session folder")
    im.add_argument("--format", choices=FORMATS, default=None, help="the device format (default: detected)")
    im.add_argument("--markers", metavar="markers.json", default=None,
                    help="marker map of the room: head poses tracked in the scene video (devices without poses)")
    im.add_argument("--camera", metavar="camera.json", default=None,
                    help="scene-camera calibration to use instead of the device's")
    im.add_argument("--marker-size-mm", type=A.positive_float, default=None, metavar="MM",
                    help="printed marker side, mm (Pupil Core's head-pose tracker works in marker sides)")
    im.add_argument("--kappa-recording", default=None, metavar="DIR",
                    help="a recording of known targets, for Neon's visual-axis offset (docs/importers.md)")
    im.add_argument("--max-pose-gap", type=A.positive_float, default=0.05, metavar="S",
                    help="drop eye samples with no device head pose within this, s (default 0.05)")
    im.set_defaults(func=cmd_import)


def add_export(sub) -> None:
    """Declare the command and its arguments."""
    ex = sub.add_parser("export-recording",
                        help="a simulated session -> a device's recording format (to try or test an importer)")
    ex.add_argument("session", metavar="SESSION", help="a session written by 'wearable-gaze simulate'")
    ex.add_argument("-o", "--out", required=True, metavar="DIR", help="new recording folder")
    ex.add_argument("--format", choices=FORMATS, required=True, help="the device format to write")
    ex.add_argument("--eye-states", action="store_true",
                    help="pupil-cloud: also write 3d_eye_states.csv, as a Neon export has (default: 2D gaze only, "
                         "as an Invisible export)")
    ex.set_defaults(func=cmd_export)
