"""``wearable-gaze track``, ``markers`` and ``map``."""

from __future__ import annotations

from ..errors import UserError
from . import args as A


def cmd_track(args) -> int:
    from ..pipeline.steps.track import track_video_files
    from ..progress import progress_bar

    with progress_bar("tracking", 1) as cb:
        counts = track_video_files(args.video, args.camera, args.out, markers=args.markers, reference=args.reference,
                                   reference_size_mm=args.reference_size_mm, overlay=args.overlay,
                                   timestamps=args.timestamps, progress=cb, smooth_s=args.smooth, sfm=args.map)
    print(f"wrote {args.out}: {counts['posed']} of {counts['frames']} frames with a pose"
          + (f"; overlay {args.overlay}" if args.overlay else ""))
    return 0


def cmd_markers(args) -> int:
    from ..pipeline.maps.sheets import parse_ids, write_marker_sheets

    for p in write_marker_sheets(args.dict, parse_ids(args.ids), args.size_mm, args.out, args.page, args.dpi):
        print(f"wrote {p}")
    return 0


def add_track(sub) -> None:
    """Declare the command and its arguments."""
    tk = sub.add_parser("track", help="head pose for every frame of a scene video (markers or a flat reference)")
    tk.add_argument("video", metavar="VIDEO", help="scene-camera video")
    tk.add_argument("--camera", required=True, metavar="camera.json", help="scene-camera calibration")
    src = tk.add_mutually_exclusive_group(required=True)
    src.add_argument("--markers", metavar="map.json", help="marker map (docs/formats.md)")
    src.add_argument("--map", metavar="SFM_FOLDER", help="a markerless map of the room (map --markerless)")
    src.add_argument("--reference", metavar="IMAGE", help="image of a flat textured surface in the room")
    tk.add_argument("--reference-size-mm", type=A.positive_float, nargs=2, metavar=("W", "H"),
                    help="the reference surface's width and height in mm")
    tk.add_argument("-o", "--out", required=True, metavar="poses.csv", help="pose CSV to write")
    tk.add_argument("--overlay", metavar="OUT.mp4", help="also write a video with markers and world axes drawn")
    tk.add_argument("--timestamps", metavar="CSV", help="frame times (frame,t); default the session's "
                    "scene_timestamps.csv beside the video, else frame / fps")
    tk.add_argument("--smooth", type=A.non_negative_float, default=0.0, metavar="S",
                    help="average poses over a centred window of S seconds (no lag offline; default off)")
    tk.set_defaults(func=cmd_track)


def add_markers(sub) -> None:
    """Declare the command and its arguments."""
    mk = sub.add_parser("markers", help="printable marker sheets at exact scale, and a marker-map template")
    mk.add_argument("--dict", default="DICT_4X4_50", metavar="DICT", help="cv2.aruco dictionary (default DICT_4X4_50)")
    mk.add_argument("--ids", required=True, metavar="IDS", help="e.g. 0-11 or 3,5,7-9")
    mk.add_argument("--size-mm", type=A.positive_float, required=True, metavar="MM", help="black square side, mm")
    mk.add_argument("-o", "--out", required=True, metavar="sheet.pdf|sheet.png", help="PDF, or PNG at --dpi")
    mk.add_argument("--page", choices=("a4", "letter", "a3"), default="a4", help="paper size (default a4)")
    mk.add_argument("--dpi", type=A.positive_int, default=300, metavar="N", help="raster resolution (default 300)")
    mk.set_defaults(func=cmd_markers)


def cmd_map(args) -> int:
    from ..pipeline.maps.markers import build_map_files, format_map_report, map_plot_path, parse_sizes
    from ..progress import progress_bar

    if args.markerless:
        return _cmd_markerless(args)
    if args.markers is not None or args.distance is not None:
        raise UserError("map: --markers and --distance are for --markerless (what places and scales a markerless map)")
    if args.size_mm is None and not args.sizes and args.extend is None:
        raise UserError("map: give the printed marker side, --size-mm MM (or --sizes ID=MM,...)")
    with progress_bar("marker map", 1) as cb:
        built = build_map_files(args.inputs, args.camera, args.out, args.dict, args.size_mm, parse_sizes(args.sizes),
                                args.origin_marker, args.max_frames or 300, cb, args.extend, not args.fixed_intrinsics)
    for line in format_map_report(built):
        print(line)
    print(f"wrote {args.out} and its top view {map_plot_path(args.out)}")
    return 0


def _cmd_markerless(args) -> int:
    from ..pipeline.maps.sfm import build_sfm_files, format_sfm_report
    from ..progress import progress_bar

    if args.extend is not None or args.sizes or args.fixed_intrinsics:
        raise UserError("map --markerless: --extend, --sizes and --fixed-intrinsics are for marker maps; a markerless "
                        "map is fixed by --origin-marker ID --size-mm MM or by --markers MAP.json")
    with progress_bar("markerless map", 1) as cb:
        build = build_sfm_files(args.inputs, args.camera, args.out, args.max_frames or 150, args.dict,
                                args.size_mm, args.origin_marker, args.markers, cb, args.distance)
    for line in format_sfm_report(build):
        print(line)
    out = args.out.rstrip("/") or "/"                  # `-o sfm/`, as the docs write it, is not `sfm//`
    print(f"wrote the markerless map {out}/ (sfm_map.json, features.npz, colmap/, sfm_top_view.png); "
          f"track with --map {out}/")
    return 0


def add_map(sub) -> None:
    """Declare the command and its arguments."""
    mp = sub.add_parser("map", help="a marker map from a survey video or photos of the room's markers")
    mp.add_argument("inputs", nargs="+", metavar="VIDEO_OR_IMAGES", help="survey videos, images or folders of images")
    mp.add_argument("--camera", required=True, metavar="camera.json|.yml",
                    help="the camera's calibration (ours, or an OpenCV YAML/XML file)")
    mp.add_argument("-o", "--out", required=True, metavar="map.json|FOLDER",
                    help="marker map to write (with --markerless: a new folder)")
    mp.add_argument("--dict", type=A.marker_dictionary, default=None, metavar="DICT",
                    help="cv2.aruco dictionary (default: the --extend map's, else DICT_4X4_50)")
    mp.add_argument("--extend", metavar="map.json",
                    help="an earlier map to extend or refine: its world and markers are kept, new ones added")
    mp.add_argument("--size-mm", type=A.positive_float, metavar="MM",
                    help="the printed markers' black square side (default: the --extend map's)")
    mp.add_argument("--sizes", metavar="ID=MM,...", help="per-marker sides, over --size-mm")
    mp.add_argument("--origin-marker", type=A.non_negative_int, metavar="ID",
                    help="the marker whose frame is the world (default: the one seen most)")
    mp.add_argument("--max-frames", type=A.positive_int, default=None, metavar="N",
                    help="frames used from each video, evenly spaced (default 300; 150 with --markerless)")
    mp.add_argument("--fixed-intrinsics", action="store_true",
                    help="use the calibration's intrinsics as they are (by default a survey of enough views refines "
                         "them with the map: docs/tracking.md)")
    mp.add_argument("--markerless", action="store_true",
                    help="reconstruct the textured room itself (pycolmap structure from motion) into the folder -o; "
                         "scaled by --origin-marker ID --size-mm MM or placed by --markers MAP.json")
    mp.add_argument("--distance", type=A.times_and_distance, metavar="T1,T2,MM",
                    help="with --markerless, no marker needed: the camera moved MM mm between T1 and T2 s of the "
                         "video (e.g. two tape-measured marks on the floor); the world is the camera's frame at T1")
    mp.add_argument("--markers", metavar="map.json",
                    help="with --markerless: the room's marker map, whose world the markerless map is fitted to "
                         "(by all its markers seen, or by --origin-marker alone)")
    mp.set_defaults(func=cmd_map)
