"""Every fixation answered (issue 27): simulated sessions whose targets are far (3-8 m) and whose
eyes carry a small diverging vergence bias (each eye 0.2-0.4 deg outward, a different size per
session, within the 0.5 deg accuracy of a calibrated tracker), so that the two eyes' rays of a far
fixation meet behind the head or not at all (they diverge where twice the bias exceeds the
vergence, 64 mm over the distance: beyond 4.6-9.2 m for these biases; counted as "diverging"); the
head sways (its parallax may still fix a point) or stands still (vergence alone: it cannot).
Each session is simulated, then processed by ``process`` (its own scene video tracked in its
own markers); each true fixation is paired with the process fixation overlapping it most.

    python benchmarks/bench_direction_only.py [--sessions 6] [--seed 300]

Counted per true fixation of a fixed target:
- found: the segmenter found a fixation overlapping at least half of it (fixation detection is
  not this benchmark's; a fixation not found is listed, not counted below);
- answered: that fixation belongs to a target with a direction (every static target has one:
  ``ok``, ``unresolved`` and ``direction-only`` alike; ``estimator.direction``);
- in cone: the true target's direction, seen from where the target's lines were seen (the
  mean of their cyclopean origins), lies inside its 95 % cone. The cone is the data's: the
  angular spread of the samples' cyclopean directions (the mean of the two eyes' unit
  directions) about their mean, divided by their number (times the lag-one time-correlation
  factor), plus the error model's per-eye bias (process's: the calibration's leave-one-out
  residual and the slippage the session's lines show, ``pipeline.steps.errorbudget``) seen through the
  cyclopean mean and the pose offset of a tracked head, at 95 % along the covariance's longest
  axis (chi-square, 2 dof; Student's when the slippage, sized from few combinations of the eyes'
  angles, counts: ``ErrorModel.slip_dof``).

Target (issue 27): every found fixation answered, the true direction inside the 95 % cone in at
least 90 % of them.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
from _args import size_and_seed

from estimator.direction import GazeDirection
from wearable_gaze.formats.fixations_table import read_fixations_csv
from wearable_gaze.formats.targets import read_targets
from wearable_gaze.formats.truth import read_truth_targets
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.report.truth_match import TruthFrame
from wearable_gaze.sim.simulate import simulate_scenario


def scenario(rng, still: bool) -> tuple[dict, float]:
    """A far-target scenario and its per-eye outward bias, degrees."""
    b = float(rng.uniform(0.2, 0.4))
    return ({"base": "lab-walkabout", "duration_s": 18.0, "camera": {"resolution": [640, 360]},
             "eyes": {"bias_deg": [[-b, 0.0], [b, 0.0]]},
             "targets": {"random_count": 5, "random_depth_mm": [3000.0, 8000.0]},
             "head": {"motion": "fixed"} if still else {"sway_deg": 8.0, "sway_mm": 120.0},
             "calibration": {"camera_views": 6}}, b)


def session_rows(out: Path, session: Path, bias_deg: float) -> list[dict]:
    """One row per true fixation of a fixed target: found, answered, status, in cone, the cone,
    the angle between the true and the reported direction (degrees), and whether its biased rays
    diverge (``bias_deg`` outward per eye against the vergence at its distance from the head's
    start)."""
    summary = json.loads((out / "summary.json").read_text())
    frame = TruthFrame.from_record(summary.get("truth_frame"))
    truth = read_truth_targets(session / "truth" / "targets.json")
    truth = frame.targets(truth) if frame is not None and frame.T_map_from_truth is not None else truth
    fx = read_fixations_csv(out / "fixations.csv") if (out / "fixations.csv").is_file() else None
    records = {r["target"]: r for r in read_targets(out / "targets.json")} if (out / "targets.json").is_file() else {}
    rows = []
    for tt in truth:
        if "position_mm" not in tt:
            continue
        X = np.asarray(tt["position_mm"], float)
        for a, b in tt["fixations_s"]:
            vergence_deg = float(np.degrees(64.0 / np.linalg.norm(X)))
            row = {"found": False, "answered": False, "status": "not found", "in_cone": False,
                   "cone_deg": np.nan, "angle_deg": np.nan, "diverging": 2 * bias_deg > vergence_deg}
            rows.append(row)
            if fx is None or not len(fx["fixation_id"]):
                continue
            overlap = np.clip(np.minimum(fx["end_s"], b) - np.maximum(fx["start_s"], a), 0, None)
            k = int(np.argmax(overlap))
            if overlap[k] < 0.5 * (b - a):
                continue
            row["found"] = True
            rec = records.get(int(fx["target_id"][k]))
            g = GazeDirection.from_dict(rec.get("direction")) if rec is not None else None
            row["status"] = rec["status"] if rec is not None else str(fx["status"][k])
            if g is None:
                continue
            v = X - g.origin_mm
            angle = float(np.degrees(np.arccos(np.clip(v @ g.unit / np.linalg.norm(v), -1, 1))))
            row.update(answered=True, in_cone=g.contains(X), cone_deg=g.cone95_deg, angle_deg=angle)
    return rows


def main():
    args = size_and_seed(__doc__, "--sessions", int, 6, 300, "simulated sessions (alternately swaying and still)")
    rng = np.random.default_rng(args.seed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.sessions):
            still = i % 2 == 1
            scn, b = scenario(rng, still)
            s, out = Path(tmp) / f"s{i}", Path(tmp) / f"out{i}"
            simulate_scenario(scn, s, seed=args.seed + i)
            process_session(s, out, overlay=False, report=False)
            got = session_rows(out, s, b)
            rows += got
            found = [r for r in got if r["found"]]
            print(f"session {i} ({'still' if still else 'sway'} head, bias {b:.2f} deg outward per eye): "
                  f"{len(got)} true fixations ({sum(r['diverging'] for r in got)} with diverging rays), "
                  f"{len(found)} found, {sum(r['answered'] for r in found)} answered, "
                  f"{sum(r['in_cone'] for r in found)} with the truth in the cone; statuses "
                  f"{sorted(r['status'] for r in got)}", flush=True)
    found = [r for r in rows if r["found"]]
    answered = [r for r in found if r["answered"]]
    inside = sum(r["in_cone"] for r in answered)
    by_status = {}
    for r in found:
        by_status[r["status"]] = by_status.get(r["status"], 0) + 1
    div = [r for r in answered if r["diverging"]]
    print(f"\n{len(rows)} true fixations of fixed targets at 3-8 m; {len(found)} found by the segmenter; "
          f"{len(answered)} of them answered with a direction ({100 * len(answered) / max(len(found), 1):.0f} %); "
          f"statuses {by_status}")
    print(f"true direction inside the 95 % cone: {inside} of {len(answered)} "
          f"({100 * inside / max(len(answered), 1):.1f} %); cone half-angle median "
          f"{np.nanmedian([r['cone_deg'] for r in answered]):.2f} deg, angle to the truth median "
          f"{np.nanmedian([r['angle_deg'] for r in answered]):.2f} deg, p95 "
          f"{np.nanpercentile([r['angle_deg'] for r in answered], 95):.2f} deg")
    print(f"of them with diverging rays: {len(div)} answered, {sum(r['in_cone'] for r in div)} with the truth in "
          f"the cone; statuses {sorted(set(r['status'] for r in div))}")
    ok = len(answered) == len(found) and inside >= 0.9 * len(answered)
    print("target (every found fixation answered, >= 90 % in the cone):", "met" if ok else "NOT met")


if __name__ == "__main__":
    main()
