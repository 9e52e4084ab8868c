"""Pupil Core import streams: peak Python memory (tracemalloc) importing 1 minute and N minutes
(default 60) of a synthetic Player export, gaze_positions.csv at 200 Hz (12,000 rows a minute,
720,000 an hour, ~290 MB), written as Pupil Player's Raw Data Exporter does: binocular rows with
1 % monocular rows, 1 % below the confidence threshold, neighbouring rows swapped now and then
and a repeated timestamp every ~1,000 rows (binocular matching). The import must never hold the
file whole: the peak must not grow with its length. Also prints the import's rate.

    python benchmarks/bench_import_pupil_core.py [--minutes 60]

Target (issue 14): memory flat in the recording's length.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np
from _args import size_and_seed
from _traced import traced_import

from wearable_gaze.formats.devices import pupil_core

RATE_HZ = 200.0
T0 = 86_400.0          # Pupil time of the first row, s


def write_gaze_positions(export: Path, minutes: float, seed: int) -> int:
    """Write ``export/gaze_positions.csv`` a minute at a time; returns the row count."""
    rng = np.random.default_rng(seed)
    export.mkdir(parents=True, exist_ok=True)
    n_min = int(RATE_HZ * 60)
    with open(export / pupil_core.GAZE_FILE, "w", encoding="utf-8") as fh:
        fh.write(",".join(pupil_core.GAZE_COLUMNS) + "\n")
        for m in range(int(minutes)):
            t = T0 + (m * n_min + np.arange(n_min)) / RATE_HZ
            swap = np.flatnonzero(rng.random(n_min - 1) < 0.01)
            t[swap], t[swap + 1] = t[swap + 1].copy(), t[swap].copy()          # rows slightly out of order
            rep = np.flatnonzero(rng.random(n_min - 1) < 0.001)
            t[rep + 1] = t[rep]                                               # a repeated timestamp
            target = rng.normal([0.0, 0.0, 1500.0], [300.0, 200.0, 400.0], (n_min, 3))
            eyes = []
            for x in (31.0, -31.0):                                           # eye0 right (+x), eye1 left
                c = np.array([x, 15.0, -22.0]) + rng.normal(0, 0.5, (n_min, 3))
                d = target - c + rng.normal(0, 10.0, (n_min, 3))
                eyes += [c, d / np.linalg.norm(d, axis=1, keepdims=True)]
            conf = np.where(rng.random(n_min) < 0.01, 0.3, 0.95)
            mono = rng.random(n_min) < 0.01
            rows = np.column_stack([t, np.arange(n_min) // 7, conf, np.full((n_min, 2), 0.5), target, *eyes])
            lines = [",".join(f"{v:.6f}" for v in r[:5]) + ",base," + ",".join(f"{v:.4f}" for v in r[5:])
                     for r in rows]
            lines = [ln.rsplit(",", 6)[0] + ",,,,,," if mo else ln for ln, mo in zip(lines, mono, strict=True)]
            fh.write("\n".join(lines) + "\n")
    return int(minutes) * n_min


def measure(root: Path, minutes: float, seed: int) -> tuple[int, float, float, int, dict]:
    """(rows, peak traced MiB, seconds, eye samples written, drops) of importing ``minutes``."""
    export = root / f"rec{minutes:g}"
    n_rows = write_gaze_positions(export, minutes, seed)
    dt, peak, imp = traced_import(pupil_core, export, root / f"out{minutes:g}")
    return n_rows, peak / 2**20, dt, imp.n_rays, dict(imp.dropped)


def main():
    args = size_and_seed(__doc__, "--minutes", float, 60.0, 0, "minutes of the long recording")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [measure(Path(tmp), m, args.seed) for m in (1.0, args.minutes)]
    print(f"Pupil Core gaze_positions.csv import, {RATE_HZ:g} Hz, tracemalloc peak (Python allocations)")
    for m, (n_rows, peak, dt, n, dropped) in zip((1.0, args.minutes), rows, strict=True):
        print(f"  {m:5g} min: {n_rows:8d} rows, {n:8d} eye samples kept, peak {peak:6.2f} MiB, {dt:6.1f} s "
              f"({n_rows / dt / 1e3:.0f} k rows/s, tracemalloc on)")
        print("           dropped: " + ", ".join(f"{k} {v}" for k, v in dropped.items()))
    ratio = rows[1][1] / rows[0][1]
    print(f"  peak ratio {args.minutes:g} min / 1 min: {ratio:.2f} (flat: about 1; loading whole would be "
          f"~{args.minutes:g})")


if __name__ == "__main__":
    main()
