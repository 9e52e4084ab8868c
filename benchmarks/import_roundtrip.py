"""The round trip of issue 14 for every device format: a simulated lab-walkabout session
(12 s, 3 targets at 0.7-3 m) exported in each format (``export-recording``), imported and
processed, against ``process`` on the native session (its own camera and eye calibration and
head tracking): RMS target error of each, and their ratio. The harness is tests/roundtrip.py.

    python benchmarks/import_roundtrip.py [--seed 321]

Target (issue 14): every format within 1.1x the native session's error.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
from _args import size_and_seed

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import roundtrip

from wearable_gaze.formats.devices import MODULES


def main():
    args = size_and_seed(__doc__, "--repeats", int, 1, roundtrip.SEED, "runs (one is enough: it is deterministic)")
    roundtrip.SEED = args.seed
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        _, native = roundtrip.native(str(base))
        print(f"native session (seed {args.seed}): target errors {native.round(1).tolist()} mm, "
              f"RMS {roundtrip.rms(native):.1f} mm")
        for fmt in MODULES:
            work = base / fmt
            work.mkdir()
            _, err, _ = roundtrip.roundtrip_errors(fmt, base, work)
            ratio = roundtrip.rms(err) / roundtrip.rms(native)
            print(f"{fmt:<11} errors {err.round(1).tolist()} mm, RMS {roundtrip.rms(err):6.1f} mm: "
                  f"{ratio:.2f}x native ({'within' if ratio <= 1.1 else 'BEYOND'} 1.1x)")


if __name__ == "__main__":
    main()
