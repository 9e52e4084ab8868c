"""``wearable-gaze fixations``: segment a view-line CSV into fixations (the segment column)."""

from __future__ import annotations

from . import args as A

# option attribute -> SegmentConfig field
SETTINGS = {"window": "window", "jump_deg": "jump_deg", "min_fixation_s": "min_fixation_s", "max_gap_s": "max_gap_s"}


def cmd_fixations(args) -> int:
    from ..pipeline.steps.segmentation import fixations_file
    from ..progress import heartbeat

    settings = {field: getattr(args, attr) for attr, field in SETTINGS.items() if getattr(args, attr) is not None}
    with heartbeat("segmenting"):               # a long recording: a line every few seconds in a log
        r = fixations_file(args.viewlines, args.out, settings, args.eye_rate_hz)
    rate = "unknown rate" if r["rate_hz"] is None else f"{r['rate_hz']:.4g} Hz"
    c = r["config"]
    print(f"wrote {args.out}: {r['fixations']} fixation(s) in {r['rows']} rows; {r['unlabelled']} row(s) in no "
          f"fixation (segment -1: saccades, blinks, gaps); window {c['window']} samples ({rate}), jump "
          f"{c['jump_deg']:g} deg, fixations of {c['min_fixation_s']:g} s or more, gaps over {c['max_gap_s']:g} s "
          "end one")
    return 0


def add_fixations(sub) -> None:
    """Declare the command and its arguments."""
    f = sub.add_parser("fixations", help="view-line CSV -> the same with a segment column of fixations, as process "
                       "segments them")
    f.add_argument("viewlines", metavar="VIEWLINES.csv", help="view-line CSV (docs/formats.md), e.g. from viewlines")
    f.add_argument("-o", "--out", required=True, metavar="OUT.csv",
                   help="view-line CSV to write, with a segment column (-1: no fixation)")
    f.add_argument("--eye-rate-hz", type=A.positive_float, metavar="HZ",
                   help="the eye samples' rate, which sets the window (default: measured from the file's times)")
    f.add_argument("--window", type=A.positive_int, metavar="N",
                   help="samples on each side compared (default: 8, fewer below 60 Hz)")
    f.add_argument("--jump-deg", type=A.positive_float, metavar="DEG",
                   help="the least saccade counted (default: 1.5; the threshold is 5 sd of the session's "
                   "measured noise where that is more)")
    f.add_argument("--min-fixation-s", type=A.positive_float, metavar="S",
                   help="shorter fixations are dropped (default: 0.3)")
    f.add_argument("--max-gap-s", type=A.positive_float, metavar="S",
                   help="a gap in the samples longer than this ends a fixation (default: 0.5)")
    f.set_defaults(func=cmd_fixations)
