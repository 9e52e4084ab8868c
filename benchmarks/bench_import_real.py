"""Real recordings end to end on one core: ``import`` then ``process`` (no report) on each
real sample in ../shared/data/real, timed apart, against the recording's own length (the
baseline: real time) and against the issue's target for Aria.

    python benchmarks/bench_import_real.py [--repeats 1]

Target (issue 14): import of the Aria sample plus process under 30 s on one core.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
from _args import size_and_seed

from wearable_gaze.pipeline.importer import import_recording
from wearable_gaze.pipeline.process.session import process_session

REAL = Path(os.environ.get("WEARABLE_GAZE_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
SAMPLES = [("aria-mps", "aria_mps_sample_gen1", 30.0),
           ("tobii-g2", "glassesvalidator_tobii_g2_example/recording", None),
           ("pupil-neon", "pupil_labs_neon_demo_recording", None), ("pupil-core", "tufts_gaze_depth/test.csv", None)]


def main():
    args = size_and_seed(__doc__, "--repeats", int, 1, 0, "runs per sample (the fastest is shown)")
    if not REAL.is_dir():
        raise SystemExit(f"real data not found at {REAL} (set WEARABLE_GAZE_REAL_DATA)")
    print(f"import + process (no report), one core, each real sample ({REAL})")
    print(f"{'format':<11} {'length s':>9} {'import s':>9} {'process s':>10} {'total s':>8} {'x real time':>12} "
          f"{'targets':>8}  target")
    for fmt, rel, target_s in SAMPLES:
        best = None
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                man, _ = import_recording(REAL / rel, Path(tmp) / "s", fmt)
                t1 = time.perf_counter()
                res = process_session(Path(tmp) / "s", Path(tmp) / "out", report=False, overlay=False)
                t2 = time.perf_counter()
                rays = (Path(tmp) / "s" / "eye_rays.csv").read_text().splitlines()
                length = float(rays[-1].split(",")[0]) - float(rays[1].split(",")[0])
            run = (t1 - t0, t2 - t1, length, len(res.targets))
            best = run if best is None or sum(run[:2]) < sum(best[:2]) else best
        imp, proc, length, n = best
        total = imp + proc
        verdict = "" if target_s is None else f"< {target_s:g} s: {'met' if total < target_s else 'MISSED'}" \
                                                f" ({total / target_s:.2f} of it)"
        print(f"{fmt:<11} {length:>9.1f} {imp:>9.2f} {proc:>10.2f} {total:>8.2f} {length / total:>12.1f} {n:>8}  "
              f"{verdict}")
    print(json.dumps({"cores": len(os.sched_getaffinity(0))}))


if __name__ == "__main__":
    main()
