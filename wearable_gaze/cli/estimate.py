"""``wearable-gaze estimate``: gazed points from a view-line CSV."""

from __future__ import annotations

import json

from estimator import METHODS

from ..errors import UserError
from . import args as A


def cmd_estimate(args) -> int:
    from ..pipeline.estimate import estimate_file, format_table  # noqa: PLC0415

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


def add_estimate(sub) -> None:
    """Declare the command and its arguments."""
    e = sub.add_parser("estimate", help="estimate gazed points from a view-line CSV")
    e.add_argument("viewlines", metavar="VIEWLINES.csv", help="view-line CSV (docs/formats.md)")
    e.add_argument("--method", choices=METHODS, default="voxel", help="estimator (default: voxel)")
    e.add_argument("--json", action="store_true", help="one JSON object per segment per line")
    e.add_argument("--sigma-deg", type=A.positive_float, default=1.0, metavar="S",
                   help="angular noise of a view line, degrees per axis (default: 1.0)")
    e.add_argument("--export-density", metavar="OUT.ply",
                   help="write the voxel density as a PLY point cloud (voxel and paper methods)")
    e.set_defaults(func=cmd_estimate)
