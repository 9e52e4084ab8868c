"""``wearable-gaze estimate``: gazed points from a view-line CSV: one per segment (segment -1,
no fixation, skipped), or the targets of its fixations (``--targets``)."""

from __future__ import annotations

import json
import sys
from dataclasses import replace

from estimator import METHODS

from ..errors import UserError
from . import args as A


def cmd_estimate(args) -> int:
    from ..pipeline.steps import estimate as est
    from ..pipeline.steps.estimate import DEFAULT_ERROR_MODEL, estimate_file, format_table, skipped_note
    from ..progress import heartbeat

    if args.export_density and args.method not in ("voxel", "paper"):
        raise UserError("--export-density needs --method voxel or --method paper (the other methods keep no "
                        "density); add one of them or drop --export-density")
    model = replace(DEFAULT_ERROR_MODEL, pose_offset_deg=0.0) if args.device_poses else DEFAULT_ERROR_MODEL
    with heartbeat("estimating"):               # a long file: a line every few seconds in a log
        results = estimate_file(args.viewlines, args.method, args.sigma_deg, args.export_density, args.one_point,
                                args.targets, None if args.no_error_model else model)
    problem = est.nothing_estimated(args.viewlines, results)
    if problem is not None:
        raise problem
    if args.json:                               # the skipped rows are an entry of their own (status 'skipped')
        for r in results:
            print(json.dumps(r))
        return 0
    print(format_table(results))
    note = skipped_note(results)
    if note:
        print(f"wearable-gaze estimate: {note}", file=sys.stderr)
    return 0


def add_estimate(sub) -> None:
    """Declare the command and its arguments."""
    e = sub.add_parser("estimate", help="estimate gazed points from a view-line CSV")
    e.add_argument("viewlines", metavar="VIEWLINES.csv", help="view-line CSV (docs/formats.md)")
    e.add_argument("--method", choices=METHODS, default="voxel", help="estimator (default: voxel)")
    e.add_argument("--json", action="store_true", help="one JSON object per segment (or target) per line")
    how = e.add_mutually_exclusive_group()
    how.add_argument("--targets", action="store_true",
                     help="merge the fixations (segment column from 'fixations') into targets as process does")
    how.add_argument("--one-point", action="store_true",
                     help="a file without a segment column: estimate all its rows as one point, even if they hold "
                          "several fixations")
    e.add_argument("--device-poses", action="store_true",
                   help="the head poses are a device's own or a still head (an imported session): --targets merges "
                        "without the per-fixation pose offset of poses tracked in the scene video, as process does")
    e.add_argument("--sigma-deg", type=A.positive_float, default=1.0, metavar="S",
                   help="angular noise of a view line, degrees per axis (default: 1.0)")
    e.add_argument("--no-error-model", action="store_true",
                   help="ml and voxel: report the inverse Fisher information (Cramer-Rao bound) as the covariance "
                        "instead of the error model's (docs/estimators.md)")
    e.add_argument("--export-density", metavar="OUT.ply",
                   help="write the voxel density as a PLY point cloud (voxel and paper methods)")
    e.set_defaults(func=cmd_estimate)
