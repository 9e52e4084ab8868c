"""Offline processing speed on one core: ``process`` on a simulated lab-walkabout session
(30 fps 1280x720 video, 60 Hz eye data), against the session's own duration, and against
tracking every frame measured in the same run. The calibration steps (once per session) and
the report (plots and overlay) are timed separately.

    python benchmarks/bench_process.py [--duration 30]

Target (issue 6): >= 2x real time.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
from _args import size_and_seed

from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.sim.simulate import simulate_scenario


def main():
    args = size_and_seed(__doc__, "--duration", float, 30.0, 11, "simulated seconds")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "s"
        simulate_scenario({"base": "lab-walkabout", "duration_s": args.duration}, root, args.seed)
        rows = []
        for every, report in ((2, False), (1, False), (2, True)):
            out = Path(tmp) / f"p{every}{report}"
            t0 = time.perf_counter()
            r = process_session(root, out, track_every=every, report=report, overlay=report)
            total = time.perf_counter() - t0
            rows.append((every, report, total, r.timings, len(r.targets)))
    print(f"process, one core, {args.duration:.0f} s lab-walkabout session (30 fps 1280x720, 60 Hz eye data)")
    for every, report, total, tm, n in rows:
        per_session = sum(tm.get(k, 0) for k in ("tracking", "viewlines", "targets"))
        fixed = sum(tm.get(k, 0) for k in ("camera", "eyes"))
        print(f"  track every {every}{' + report' if report else '':<9}: total {total:5.1f} s; tracking + view lines + "
              f"targets {per_session:5.1f} s = {args.duration / per_session:4.2f}x real time; calibration "
              f"{fixed:4.1f} s; report {tm.get('report', 0):4.1f} s; {n} targets")
    per_session = ("tracking", "viewlines", "targets")
    main_rate = args.duration / sum(rows[0][3].get(k, 0) for k in per_session)
    every_frame_rate = args.duration / sum(rows[1][3].get(k, 0) for k in per_session)
    print(f"  tracking every frame: {every_frame_rate:.2f}x real time; target >= 2x real time (default, every 2nd "
          f"frame): {'PASS' if main_rate >= 2 else 'FAIL'}")


if __name__ == "__main__":
    main()
