"""The README's rows for the recordings added on 2026-12-03 (issue 26), each a recording the
importers were not written against: ``import`` (format detected) + ``process``, and what the data
show.

    python benchmarks/real_data_new.py

- Tobii Pro Glasses 2, gazeMapper example 2 (``data/lead/``, the project's parent folder given):
  the targets, and those inside the coded Validate episode (scene frames in coding.tsv at 25 fps,
  a poster at a nominal 60 cm) with their distance from the scene camera.
- Tobii Pro Glasses 3 data files only (EyeDentify3D; still head, no video): targets by status.
- Aria Gen2 MPS eye gaze (5 rows): the two eye lines' closest-point depth, general file.
- Pupil Cloud Timeseries export of a Pupil Invisible recording (2D gaze only): rows read and
  kept, the eye rate, and the targets by status (no video: a still head, so directions only).
"""

from __future__ import annotations

import csv
import statistics
import tempfile
from collections import Counter
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np
from real_data_table import REAL

from estimator.triangulation import closest_point_two_lines
from wearable_gaze.formats.eye_rays import read_eye_rays
from wearable_gaze.pipeline.importer import import_recording
from wearable_gaze.pipeline.process.session import process_session

FPS = 25.0


def _process(src: Path, tmp: Path, name: str):
    manifest, report = import_recording(src, tmp / name)
    res = process_session(tmp / name, tmp / f"{name}_out", overlay=False, report=False)
    return manifest, report, res.targets


def _statuses(targets) -> str:
    return ", ".join(f"{n} {s}" for s, n in sorted(Counter(t["status"] for t in targets).items())) or "none"


def g2_second(tmp: Path) -> None:
    root = REAL / "gazemapper_example2"
    _, rep, targets = _process(root / "data" / "lead", tmp, "g2b")
    with open(root / "coding" / "lead" / "coding.tsv", newline="") as fh:
        row = next(r for r in csv.reader(fh, delimiter="\t") if r and r[0] == "Validate")
    a, b = float(row[1]) / FPS, float(row[2]) / FPS
    inside = [t for t in targets if a <= t["t_start"] and t["t_end"] <= b]
    ok = [t["depth"]["distance_mm"] for t in inside if t["status"] == "ok"]
    print(f"Tobii G2, gazeMapper example 2 ({rep['device']}): {len(targets)} targets ({_statuses(targets)}); "
          f"Validate episode {a:.1f}-{b:.1f} s: {len(inside)} targets, {len(ok)} ok at "
          f"{min(ok, default=0):.0f}-{max(ok, default=0):.0f} mm, median {statistics.median(ok) if ok else 0:.0f}")


def g3_files_only(tmp: Path) -> None:
    _, rep, targets = _process(REAL / "eyedentify3d_tobii_g3", tmp, "g3")
    print(f"Tobii G3 data files only ({rep['device']}): {rep['eye_samples_written']} samples, "
          f"{len(targets)} targets ({_statuses(targets)})")


def gen2(tmp: Path) -> None:
    src = tmp / "gen2"
    src.mkdir()
    (src / "general_eye_gaze.csv").write_bytes((REAL / "aria_gen2_mps_eye_gaze" / "general_eye_gaze.csv").read_bytes())
    import_recording(src, tmp / "gen2_s")
    r = read_eye_rays(tmp / "gen2_s" / "eye_rays.csv")
    pair = closest_point_two_lines(r.left_origin_mm, r.left_direction, r.right_origin_mm, r.right_direction)
    depth = np.linalg.norm(pair.point_mm - 0.5 * (r.left_origin_mm + r.right_origin_mm), axis=1) / 1000
    print(f"Aria Gen2 MPS eye gaze, general: {len(depth)} rows, vergence {depth.min():.3f}-{depth.max():.3f} m")


def cloud(tmp: Path) -> None:
    src = REAL / "gazemapper_example2" / "data" / "follow"
    manifest, rep, targets = _process(src, tmp, "cloud")
    print(f"Pupil Cloud export ({rep['device']}, rays {rep.get('rays')}): "
          f"{rep['read']['gaze.csv rows']} gaze.csv rows read, "
          f"{rep['eye_samples_written']} kept at {manifest.get('eye_rate_hz', 0):.0f} Hz; "
          f"{len(targets)} targets ({_statuses(targets)})")


def main():
    if not REAL.is_dir():
        raise SystemExit(f"real data not found at {REAL} (set WEARABLE_GAZE_REAL_DATA)")
    with tempfile.TemporaryDirectory() as tmp:
        for fn in (g2_second, g3_files_only, gen2, cloud):
            fn(Path(tmp))


if __name__ == "__main__":
    main()
