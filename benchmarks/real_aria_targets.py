"""The real Aria gen1 MPS sample (a 12 s walk, 10 Hz gaze; ../shared/data/real/aria_mps_sample_gen1)
through ``import`` and ``process`` (issue 27): the targets answered, each with its direction, and
for each one whose head travels 0.3 m or more over a fixation its depth error against the
reference beside Aria's own ``depth_m``'s.

    python benchmarks/real_aria_targets.py [--work DIR]

Reference: the first surface of MPS's semi-dense SLAM points (dist_std <= 20 mm) along the
device's own gaze direction (``pipeline.device.surface_reference``, ``tracking.surface``), median
over the target's samples; depths from the median head position over them. Done when (issue 27):
6 or more targets, every one with a direction, and every one with 0.3 m of head travel nearer the
reference than ``depth_m``.

Then what the walk holds (``eye_in_head_places``): the dispersion rule on the eye-in-head
direction that the issue counted "about 9 fixations" with, and where on the SLAM surface each of
those fixations looked: on this sample all of them lie within 0.3 m of one place, one object the
wearer walks around, so they are one world target seen from many places, not nine.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from wearable_gaze.formats.devices import aria
from wearable_gaze.formats.eye_rays import read_device_gaze, read_eye_rays
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.viewlines import read_viewlines_csv
from wearable_gaze.pipeline.importer import import_recording
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.steps.device import surface_reference
from wearable_gaze.pipeline.types import Poses

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "aria_mps_sample_gen1"
TRAVEL_MM = 300.0


def target_rows(session: Path, out: Path, found: list) -> list[dict]:
    """Per target: {index, status, direction, samples, travel (mm, the most over one of its
    fixations), ours, ref, device (depths, mm, from the median head position; NaN: none)}."""
    segments = {s.key: s.samples for s in read_viewlines_csv(out / "viewlines.csv") if s.key >= 0}
    poses = Poses(*read_poses_csv(out / "poses.csv"))
    cloud = aria.read_point_cloud(REAL)
    t_g, p_g = read_device_gaze(session / "device_gaze.csv")
    rows = []
    for tg in found:
        parts = [segments[k] for k in tg.fixations if k in segments]
        t = np.concatenate([p.t_s for p in parts]) if parts else np.zeros(0)
        ref, head = surface_reference(cloud, session / "device_gaze.csv", poses, t)
        travel, start = 0.0, 0
        for p in parts:
            h = head[start:start + len(p.t_s)]
            travel = max(travel, float(np.linalg.norm(h[-1] - h[0])))
            start += len(p.t_s)
        o = np.nanmedian(head, axis=0) if len(t) else np.full(3, np.nan)
        dev = p_g[np.isin(np.round(t_g, 4), np.round(t, 4))]
        rows.append({"index": tg.index, "fixations": tg.fixations, "status": tg.status,
                     "direction": tg.direction is not None, "samples": len(t), "travel": travel,
                     "ours": float(np.linalg.norm(np.asarray(tg.position_mm) - o)),
                     "ref": float(np.linalg.norm(np.nanmedian(ref, axis=0) - o)) if len(t) else np.nan,
                     "device": float(np.median(np.linalg.norm(dev, axis=1))) if len(dev) else np.nan})
    return rows


IDT_DEG, IDT_MIN, PLACE_MM = 2.0, 5, 300.0


def eye_in_head_places(session: Path, out: Path) -> tuple[list, list]:
    """What the walk holds, by the rule issue 27 counted "about 9 fixations" with: a dispersion
    rule (I-DT) on the eye-in-head cyclopean direction, ``IDT_DEG`` and ``IDT_MIN`` samples, each
    run's median SLAM surface point along the device's gaze (``surface_reference``); then the
    places: those points greedily grouped within ``PLACE_MM`` of a group's first. Returns
    ([(t0, t1, n, point (3,) mm)], [[run indices] per place])."""
    rays = read_eye_rays(session / "eye_rays.csv")
    d = rays.left_direction + rays.right_direction
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rays.t_s
    poses = Poses(*read_poses_csv(out / "poses.csv"))
    ref, _ = surface_reference(aria.read_point_cloud(REAL), session / "device_gaze.csv", poses, t)

    def spread(i, j):
        m = d[i:j].mean(axis=0)
        return float(np.degrees(np.arccos(np.clip(d[i:j] @ (m / np.linalg.norm(m)), -1, 1))).max())

    runs, i = [], 0
    while i + IDT_MIN <= len(t):
        if spread(i, i + IDT_MIN) > IDT_DEG:
            i += 1
            continue
        j = i + IDT_MIN
        while j < len(t) and spread(i, j + 1) <= IDT_DEG:
            j += 1
        runs.append((float(t[i]), float(t[j - 1]), j - i, np.nanmedian(ref[i:j], axis=0)))
        i = j
    places: list[list[int]] = []
    for k, r in enumerate(runs):
        home = next((p for p in places if np.linalg.norm(runs[p[0]][3] - r[3]) < PLACE_MM), None)
        home.append(k) if home is not None else places.append([k])
    return runs, places


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=None, help="a folder to work in, kept (default: a temporary one)")
    args = ap.parse_args()
    if not REAL.is_dir():
        print(f"Aria sample not found at {REAL}: nothing to measure")
        return
    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.work or Path(scratch)
        session, out = Path(tmp) / "session", Path(tmp) / "out"
        if not (session / "session.json").is_file():
            import_recording(REAL, session)
        res = process_session(session, out, overlay=False, report=False)
        rows = target_rows(session, out, res.found)
        n_fix = len([s for s in read_viewlines_csv(out / "viewlines.csv") if s.key >= 0])
        runs, places = eye_in_head_places(session, out)
    print(f"{n_fix} fixations, {len(rows)} targets")
    print(f"{'target':>6} {'fixations':<9} {'status':<15} {'dir':>3} {'lines':>5} {'travel mm':>9} {'ours mm':>8} "
          f"{'ref mm':>7} {'depth_m':>7} {'err ours':>8} {'err dev':>7}")
    moved = nearer = 0
    for r in rows:
        e_ours, e_dev = abs(r["ours"] - r["ref"]), abs(r["device"] - r["ref"])
        if r["travel"] >= TRAVEL_MM:
            moved += 1
            nearer += bool(e_ours < e_dev)
        print(f"{r['index']:>6} {','.join(map(str, r['fixations'])):<9} {r['status']:<15} "
              f"{'yes' if r['direction'] else 'NO':>3} {r['samples']:>5} "
              f"{r['travel']:>9.0f} {r['ours']:>8.0f} {r['ref']:>7.0f} {r['device']:>7.0f} {e_ours:>8.0f} "
              f"{e_dev:>7.0f}")
    print(f"{len(rows)} targets, {sum(r['direction'] for r in rows)} with a direction; {moved} with >= "
          f"{TRAVEL_MM / 1000:g} m of head travel over a fixation, {nearer} of them nearer the SLAM surface than "
          f"depth_m")
    print(f"\nthe eye-in-head rule ({IDT_DEG:g} deg, >= {IDT_MIN} samples): {len(runs)} fixations; their SLAM "
          f"surface points (median over each) fall in {len(places)} place(s) at least {PLACE_MM / 1000:g} m apart "
          f"(world frame, m):")
    for k, (t0, t1, n, p) in enumerate(runs):
        place = next(i for i, pl in enumerate(places) if k in pl)
        print(f"  {t0:5.1f}-{t1:5.1f} s {n:>3} samples, surface point {np.round(p / 10) / 100} m, place {place}")


if __name__ == "__main__":
    main()
