"""``wearable-gaze reproduce``: the paper's simulation results."""

from __future__ import annotations

from pathlib import Path

from . import args as A


def cmd_reproduce(args) -> int:
    from ..paper.reproduce import reproduce_figure5, reproduce_table1
    from ..progress import progress_bar

    out = Path(args.out)
    if args.what == "table1":
        with progress_bar("table 1 trials", args.trials * 5) as cb:
            result, paths = reproduce_table1(out, args.trials, args.seed, progress=cb)
        print(result.format())
    elif args.what == "calibration":
        from ..formats.atomic import write_text
        from ..paper.calstudy import run_calibration_study

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


def add_reproduce(sub) -> None:
    """Declare the command and its arguments."""
    r = sub.add_parser("reproduce", help="reproduce the paper's simulation results")
    r.add_argument("what", choices=("table1", "figure5", "calibration"), help="table1: Table 1 with Fig. 11 and "
                   "13; figure5: depth from single binocular pairs; calibration: the section 2.3.3 correction "
                   "table and the eye-centre estimate")
    r.add_argument("--trials", type=A.positive_int, default=20, metavar="N", help="trials per depth (default: 20)")
    r.add_argument("--seed", type=A.seed, default=0, metavar="S", help="random seed (default: 0)")
    r.add_argument("--out", default="reproduce-out", metavar="DIR", help="output folder (default: reproduce-out)")
    r.set_defaults(func=cmd_reproduce)
