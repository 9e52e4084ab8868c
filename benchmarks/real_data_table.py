"""The README's real-data table: on each real recording in ../shared/data/real, our 3D
estimates beside the device's own 3D gaze, and how both were measured.

    python benchmarks/real_data_table.py

- Aria gen1 MPS (head moves): ``import`` + ``process``; per fixation, the distance from the head
  (CPF, median over the fixation) to our ``ml`` and ``voxel`` estimates and to the device's gaze
  (median ``depth_m``), against a reference: the first surface of MPS's semi-dense points
  (dist_std <= 20 mm) along the device's gaze direction (``tracking.surface.first_surface``),
  median over the fixation. Then every 0.5 s window (5 consecutive samples, sliding) with >= 300
  mm of head travel (first to last sample), ``ml`` on its 10 lines against ``depth_m``: median
  absolute depth error of each and their ratio, the same reference.
- Tobii Pro Glasses 2 (head still, arm's length): the nine published fixation intervals; per
  interval the ``ml`` point (sigma 0.5 deg, mixture loss) of the imported rays, and the device's
  median ``gp3``: distance from the eyes' midpoint. The poster stood at a nominal 600 mm.
- Pupil Neon demo (head still, no targets): ``process`` after the kappa correction.
"""

from __future__ import annotations

import csv
import os
import tempfile
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np

from estimator import MLConfig, estimate, ml_point
from tracking.timeline import nearest_in_time
from wearable_gaze.formats.devices import aria
from wearable_gaze.formats.eye_rays import read_device_gaze, read_eye_rays
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.viewlines import read_viewlines_csv
from wearable_gaze.pipeline.importer import import_recording
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.steps.device import surface_reference
from wearable_gaze.pipeline.types import Poses

REAL = Path(os.environ.get("WEARABLE_GAZE_REAL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))


def device_depths(gaze_csv: Path, t) -> np.ndarray:
    """The device's gaze depth (distance of its 3D gaze point from the head), mm, at times t."""
    return np.linalg.norm(nearest_in_time(*read_device_gaze(gaze_csv), t, 1e-4), axis=1)


def aria_rows(tmp: Path):
    src = REAL / "aria_mps_sample_gen1"
    import_recording(src, tmp / "aria", "aria-mps")
    process_session(tmp / "aria", tmp / "aria_out", overlay=False, report=False)
    poses = Poses(*read_poses_csv(tmp / "aria_out" / "poses.csv"))
    cloud = aria.read_point_cloud(src)
    gaze = tmp / "aria" / "device_gaze.csv"
    print("Aria gen1 MPS sample, per fixation found by process (distances from the head, mm):")
    print(f"{'t s':>11} {'n':>3} {'travel':>7} {'ref':>6} {'ml':>6} {'voxel':>6} {'depth_m':>8} {'|ml-ref|':>9} "
          f"{'|dev-ref|':>9}")
    for seg in read_viewlines_csv(tmp / "aria_out" / "viewlines.csv"):
        if seg.key < 0:
            continue
        s = seg.samples
        ref, head = surface_reference(cloud, gaze, poses, s.t_s)
        o = np.nanmedian(head, axis=0)
        r = np.linalg.norm(np.nanmedian(ref, axis=0) - o)
        d = {m: np.linalg.norm(estimate(s, m).position_mm - o) for m in ("ml", "voxel")}
        dev = float(np.nanmedian(device_depths(gaze, s.t_s)))
        print(f"{s.t_s[0]:5.1f}-{s.t_s[-1]:<5.1f} {len(s):>3} {np.linalg.norm(head[-1] - head[0]):>7.0f} {r:>6.0f} "
              f"{d['ml']:>6.0f} {d['voxel']:>6.0f} {dev:>8.0f} {abs(d['ml'] - r):>9.0f} {abs(dev - r):>9.0f}")
    all_lines = read_viewlines_csv(tmp / "aria_out" / ".viewlines_unsegmented.csv")[0].samples
    ref, head = surface_reference(cloud, gaze, poses, all_lines.t_s)
    dev = device_depths(gaze, all_lines.t_s)
    for travel_mm in (0, 100, 300):
        err_ml, err_dev = _window_errors(all_lines, ref, head, dev, travel_mm)
        m_ml, m_dev = np.median(err_ml), np.median(err_dev)
        print(f"0.5 s windows with >= {travel_mm:>3} mm head travel: {len(err_ml):>3}; median |depth error| ml "
              f"{m_ml:4.0f} mm, device depth_m {m_dev:4.0f} mm: ml {m_dev / m_ml:4.1f}x closer")


def _window_errors(lines, ref, head, dev, travel_mm: float):
    """|depth error| of ml and of the device over every 0.5 s window (5 consecutive samples)
    whose head travel (first to last sample) is at least ``travel_mm``."""
    err_ml, err_dev = [], []
    for i in range(len(lines) - 4):
        w = slice(i, i + 5)
        if np.linalg.norm(head[i + 4] - head[i]) < travel_mm or np.ptp(lines.t_s[w]) > 0.45:
            continue
        o = head[i + 2]
        r = np.linalg.norm(np.nanmedian(ref[w], axis=0) - o)
        e = estimate(lines.select(np.arange(i, i + 5)), "ml")
        if not (np.isfinite(r) and e.ok):
            continue
        err_ml.append(abs(np.linalg.norm(e.position_mm - o) - r))
        err_dev.append(abs(np.nanmedian(dev[w]) - r))
    return np.array(err_ml), np.array(err_dev)


def tobii_rows(tmp: Path):
    root = REAL / "glassesvalidator_tobii_g2_example"
    import_recording(root / "recording", tmp / "g2", "tobii-g2")
    rays = read_eye_rays(tmp / "g2" / "eye_rays.csv")
    tg, g3 = read_device_gaze(tmp / "g2" / "device_gaze.csv")
    with open(root / "recording" / "analysisInterval_from_3e0a114.tsv", newline="") as fh:
        rows = [(int(r["target"]), float(r["start_timestamp"]) / 1e3, float(r["end_timestamp"]) / 1e3)
                for r in csv.DictReader(fh, delimiter="\t")]
    print("\nTobii Pro Glasses 2 (glassesValidator), nine targets on a poster at a nominal 600 mm, head still:")
    print(f"{'target':>6} {'n':>4} {'ours mm':>8} {'gp3 mm':>7}")
    for k, a, b in rows:
        s = rays.select((rays.t_s >= a) & (rays.t_s <= b))
        e = ml_point(s.lines(), MLConfig(sigma_deg=0.5, loss="mixture"))
        view = np.nanmean(np.vstack([s.left_origin_mm, s.right_origin_mm]), axis=0)
        gp = np.nanmedian(g3[(tg >= a) & (tg <= b)], axis=0)
        print(f"{k:>6} {len(s):>4} {np.linalg.norm(e.position_mm - view):>8.0f} {np.linalg.norm(gp - view):>7.0f}")


def neon_rows(tmp: Path):
    import_recording(REAL / "pupil_labs_neon_demo_recording", tmp / "neon", "pupil-neon")
    res = process_session(tmp / "neon", tmp / "neon_out", overlay=False, report=False)
    print("\nPupil Neon demo (head still, kappa from the 2D gaze ray at 1 m; no 3D gaze from the device):")
    for t in res.targets:
        print(f"  target {t['target']}: {t['t_start']:.1f}-{t['t_end']:.1f} s, "
              f"{np.linalg.norm(t['position_mm']):.0f} mm from the scene camera")


def main():
    if not REAL.is_dir():
        raise SystemExit(f"real data not found at {REAL} (set WEARABLE_GAZE_REAL_DATA)")
    with tempfile.TemporaryDirectory() as tmp:
        aria_rows(Path(tmp))
        tobii_rows(Path(tmp))
        neon_rows(Path(tmp))


if __name__ == "__main__":
    main()
