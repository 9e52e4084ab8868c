"""Tobii Pro Glasses 2 import streams: peak Python memory (tracemalloc) importing 1 minute and N
minutes (default 60) of synthetic livedata.json.gz at 50 Hz, with IMU lines interleaved (ac 100 Hz,
gy 95 Hz) and a video sync line every 0.64 s, as the device writes them (about 1.3 million lines
per hour of eye samples, 2.4 million with the IMU). The import must never hold the recording
whole: the peak must not grow with its length. Also prints the import's rate.

    python benchmarks/bench_import_tobii.py [--minutes 60]

Target (issue 14): memory flat in the recording's length (an hour of livedata never loaded whole).
"""

from __future__ import annotations

import gzip
import tempfile
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np
from _args import size_and_seed
from _traced import traced_import

from wearable_gaze.formats.devices import tobii_g2

RATE_HZ = 50.0
TS0_US = 84_000_000


def write_livedata(seg: Path, minutes: float, seed: int) -> int:
    """Write ``seg/livedata.json.gz`` (streamed, a second at a time); returns the line count."""
    rng = np.random.default_rng(seed)
    seg.mkdir(parents=True, exist_ok=True)
    n_lines = 0
    with gzip.open(seg / "livedata.json.gz", "wt", encoding="utf-8", compresslevel=1) as fh:
        for sec in range(int(minutes * 60)):
            t0 = TS0_US + sec * 1_000_000
            out = []
            target = rng.normal([0.0, 0.0, 700.0], [150.0, 100.0, 80.0])
            for k in range(int(RATE_HZ)):
                ts, gidx = t0 + k * 20_000, sec * int(RATE_HZ) + k
                s = 16 if rng.random() < 0.01 else 0
                for side, x in (("left", 32.0), ("right", -32.0)):
                    pc = np.array([x, -23.0, -28.0]) + rng.normal(0, 0.3, 3)
                    gd = target - pc + rng.normal(0, 5.0, 3)
                    gd /= np.linalg.norm(gd)
                    out += [f'{{"ts":{ts},"s":{s},"gidx":{gidx},"pc":[{pc[0]:.2f},{pc[1]:.2f},{pc[2]:.2f}],'
                            f'"eye":"{side}"}}', f'{{"ts":{ts},"s":{s},"gidx":{gidx},"pd":3.40,"eye":"{side}"}}',
                            f'{{"ts":{ts},"s":{s},"gidx":{gidx},"gd":[{gd[0]:.4f},{gd[1]:.4f},{gd[2]:.4f}],'
                            f'"eye":"{side}"}}']
                out += [f'{{"ts":{ts},"s":0,"gidx":{gidx},"l":20000,"gp":[0.5000,0.5000]}}',
                        f'{{"ts":{ts},"s":0,"gidx":{gidx},"gp3":[{target[0]:.2f},{target[1]:.2f},{target[2]:.2f}]}}']
            out += [f'{{"ts":{t0 + k * 10_000},"s":0,"ac":[0.2,-9.9,-0.4]}}' for k in range(100)]
            out += [f'{{"ts":{t0 + k * 10_526},"s":0,"gy":[0.5,-1.2,0.3]}}' for k in range(95)]
            out += [f'{{"ts":{v},"s":0,"vts":{v - TS0_US}}}' for v in range(t0 + (-t0) % 640_000, t0 + 1_000_000,
                                                                          640_000)]
            fh.write("\n".join(out) + "\n")
            n_lines += len(out)
    return n_lines


def measure(root: Path, minutes: float, seed: int) -> tuple[int, float, float, int]:
    """(lines, peak traced MiB, seconds, eye samples written) of importing ``minutes`` of livedata."""
    rec = root / f"rec{minutes:g}"
    n_lines = write_livedata(rec / "segments" / "1", minutes, seed)
    dt, peak, imp = traced_import(tobii_g2, rec, root / f"out{minutes:g}")
    return n_lines, peak / 2**20, dt, imp.n_rays


def main():
    args = size_and_seed(__doc__, "--minutes", float, 60.0, 0, "minutes of the long recording")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [measure(Path(tmp), m, args.seed) for m in (1.0, args.minutes)]
    print(f"Tobii G2 livedata import, {RATE_HZ:g} Hz eye samples, tracemalloc peak (Python allocations)")
    for m, (lines, peak, dt, n) in zip((1.0, args.minutes), rows, strict=True):
        print(f"  {m:5g} min: {lines:9d} lines, {n:7d} eye samples kept, peak {peak:6.2f} MiB, {dt:6.1f} s "
              f"({lines / dt / 1e3:.0f} k lines/s, tracemalloc on)")
    ratio = rows[1][1] / rows[0][1]
    print(f"  peak ratio {args.minutes:g} min / 1 min: {ratio:.2f} (flat: about 1; loading whole would be "
          f"~{args.minutes:g})")


if __name__ == "__main__":
    main()
