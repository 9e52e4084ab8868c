"""``wearable-gaze aoi``: areas of interest in the room, over a processed session."""

from __future__ import annotations

from . import args as A


def cmd_aoi(args) -> int:
    from ..pipeline.steps.aoi import AoiConfig, aoi_folder, format_metrics

    conf = AoiConfig(assign_probability=args.assign_probability)
    res = aoi_folder(args.processed, args.aois, args.out, args.markers, conf)
    print(format_metrics(res, conf))
    print(f"wrote {args.out}: aoi_fixations.csv, aoi_metrics.csv, aoi_transitions.csv, aoi_dwell.png "
          "(docs/aois.md)")
    return 0


def add_aoi(sub) -> None:
    """Declare the command and its arguments."""
    a = sub.add_parser("aoi", help="areas of interest in the room: per fixation the probability of each, per area "
                       "dwell, visits, time to first fixation; transitions")
    a.add_argument("processed", metavar="PROCESSED", help="a folder written by 'wearable-gaze process'")
    a.add_argument("--aois", required=True, metavar="aois.json", help="the areas (docs/aois.md)")
    a.add_argument("-o", "--out", required=True, metavar="DIR", help="folder for the AOI tables and plot")
    a.add_argument("--markers", metavar="MAP.json", default=None,
                   help="marker map placing marker areas (default: the processed session's markers.json)")
    a.add_argument("--assign-probability", type=A.probability, default=0.5, metavar="P",
                   help="a fixation is assigned to its most probable area from this probability (default 0.5)")
    a.set_defaults(func=cmd_aoi)
