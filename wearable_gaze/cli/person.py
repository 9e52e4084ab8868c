"""``wearable-gaze learn-bias``: a person's per-eye gaze correction from a validation session."""

from __future__ import annotations


def cmd_learn_bias(args) -> int:
    from ..pipeline.steps.person import format_person, learn_bias_file

    person = learn_bias_file(args.session, args.validation, args.out, args.processed, args.eyes)
    print(format_person(person))
    print(f"\nwrote {args.out} (apply it with 'wearable-gaze process SESSION --person {args.out}')")
    return 0


def add_learn_bias(sub) -> None:
    """Declare the command and its arguments."""
    lb = sub.add_parser("learn-bias", help="a processed validation session + its targets -> the person's per-eye "
                        "gaze correction (person.json)")
    lb.add_argument("session", metavar="SESSION", help="the validation session's folder, processed by 'process'")
    lb.add_argument("--validation", required=True, metavar="validation.json",
                    help="the targets fixated: positions (world, mm) and times (docs/calibration.md); a simulator's "
                         "truth/targets.json is accepted too")
    lb.add_argument("--processed", metavar="DIR", help="the folder 'process' wrote (default SESSION/processed)")
    lb.add_argument("--eyes", metavar="eyes.json",
                    help="eye calibration of the raw samples (default PROCESSED/eyes.json)")
    lb.add_argument("-o", "--out", required=True, metavar="person.json", help="the person's correction to write")
    lb.set_defaults(func=cmd_learn_bias)
