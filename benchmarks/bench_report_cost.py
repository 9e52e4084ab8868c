"""What the report costs beside the rest of ``process`` (issue 28: "the report costs at most a
quarter of a process run, whatever the number of targets"), on one core: the demo's session
(lab-walkabout, 1280x720, four targets), a simulated session with many targets, the real Tobii
G2 sample (12 targets, no scene video) and the real Aria sample (imported, no scene video).

Each session is processed without the report, then again with it (every other step skipped):
the report's share is its cost over the sum. Wall time and CPU time (this process's, all its
threads) are both given: on a machine shared with other work, the CPU time is the steadier one.

    python benchmarks/bench_report_cost.py [--duration 20] [--seed 0] [--targets 12] [--only demo,many,g2,aria]
                                           [--detections]

``--detections``: for a session with a scene video, the report twice more, the overlay detecting
the markers itself (``OverlayInputs.detections`` None: what the report did before the tracking
step kept its detections) and given the tracking step's (``.marker_detections.npz``, what
``process`` now passes it), both with matplotlib already imported, which the first report run
paid: the two costs in one run, under the same load.

Target: the report's share at most 25 % on every session.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)

from wearable_gaze.pipeline.importer import import_recording
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.sim.simulate import simulate_scenario

REPO = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("WEARABLE_GAZE_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


def sessions(args, tmp: Path) -> list[tuple[str, Path]]:
    """[(name, session folder)] of the sessions asked for (the real ones when their data is there)."""
    out = []
    if "demo" in args.only:
        simulate_scenario({"base": "lab-walkabout", "duration_s": args.duration}, tmp / "demo", args.seed)
        out.append(("demo (4 targets)", tmp / "demo"))
    if "many" in args.only:
        simulate_scenario({"base": "lab-walkabout", "duration_s": args.duration,
                           "targets": {"random_count": args.targets, "random_depth_mm": [700.0, 3500.0]}},
                          tmp / "many", args.seed)
        out.append((f"simulated, {args.targets} true targets", tmp / "many"))
    for key, name, rel in (("g2", "real Tobii G2", "glassesvalidator_tobii_g2_example/recording"),
                           ("aria", "real Aria gen1", "aria_mps_sample_gen1")):
        if key in args.only and (REAL / rel).is_dir():
            import_recording(REAL / rel, tmp / key)
            out.append((name, tmp / key))
        elif key in args.only:
            print(f"{name}: {REAL / rel} not found, left out (set WEARABLE_GAZE_REAL_DATA)")
    return out


def timed(fn) -> tuple[float, float, object]:
    """(wall s, CPU s, result) of ``fn()``."""
    w, c = time.perf_counter(), time.process_time()
    res = fn()
    return time.perf_counter() - w, time.process_time() - c, res


def tracking_detections(out: Path):
    """The tracking step's marker detections (``.marker_detections.npz``), or None: it kept none
    (no scene video, no marker map)."""
    from wearable_gaze.formats.marker_detections import NAME, read_marker_detections

    return read_marker_detections(out / NAME) if (out / NAME).is_file() else None


def report_with(root: Path, out: Path, detections: dict | None) -> float:
    """CPU s of the report step alone (its record dropped from .steps.json) with ``detections``
    handed to the overlay (None: it detects)."""
    from wearable_gaze.pipeline.report import page as report

    state = out / ".steps.json"
    steps = json.loads(state.read_text())
    steps.pop("report", None)
    state.write_text(json.dumps(steps))
    write = report.write_overlays
    report.write_overlays = lambda o, inp, *a, **k: write(o, dataclasses.replace(inp, detections=detections), *a, **k)
    try:
        c = time.process_time()
        res = process_session(root, out)
        assert "report" not in res.skipped and not res.problems, res.problems
        return time.process_time() - c
    finally:
        report.write_overlays = write


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds (default 20, the demo's)")
    ap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ap.add_argument("--targets", type=int, default=12, help="targets of the many-target session (default 12)")
    ap.add_argument("--only", default="demo,many,g2,aria", help="which sessions (default all four)")
    ap.add_argument("--detections", action="store_true", help="also the report with tracking's detections handed in")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, root in sessions(args, Path(tmp)):
            out = Path(tmp) / (root.name + "_out")
            rest_w, rest_c, res = timed(lambda root=root, out=out: process_session(root, out, report=False))
            rep_w, rep_c, res2 = timed(lambda root=root, out=out: process_session(root, out))
            assert "report" not in res2.skipped and not res2.problems, res2.problems
            dets = tracking_detections(out) if args.detections else None
            again = (report_with(root, out, None), report_with(root, out, dets)) if dets is not None else None
            rows.append((name, len(res.targets), rest_w, rep_w, rest_c, rep_c, again))
    print(f"process, one core (load {os.getloadavg()[0]:.1f} at the end); report share = report / (rest + report)")
    print(f"{'session':<26} {'found':>7} {'rest wall s':>11} {'report wall s':>13} {'share':>6} "
          f"{'rest CPU s':>10} {'report CPU s':>12} {'share':>6}"
          + ("   report again, CPU s (share): detecting / tracking's detections" if args.detections else ""))
    for name, n, rw, pw, rc, pc, again in rows:
        print(f"{name:<26} {n:>7} {rw:>11.1f} {pw:>13.1f} {pw / (rw + pw):>6.0%} {rc:>10.1f} {pc:>12.1f} "
              f"{pc / (rc + pc):>6.0%}"
              + ("   " + " / ".join(f"{a:.1f} ({a / (rc + a):.0%})" for a in again) if again else ""))
    worst = max((pc / (rc + pc) for *_, rc, pc, _ in rows), default=0.0)
    print(f"largest CPU share {worst:.0%}; target <= 25 %: {'PASS' if worst <= 0.25 else 'FAIL'}")


if __name__ == "__main__":
    main()
