"""Areas of interest against the simulator's truth (issue 28): simulated walking sessions
(lab-walkabout, 20 s, 640x360, four targets at 1.2-3.6 m) processed by ``batch --aois`` with a
300 mm box around each true static target and one area nobody looks at; per area, its dwell
time against the truth's (the time the simulator's per-sample target is that target in a
fixation) and its time to first fixation against the truth's first fixation sample.

    python benchmarks/bench_aoi.py [--sessions 3] [--seed 1] [--work DIR]

``--work``: simulate and process into DIR and keep it (default: a temporary folder, removed).

Targets (issue 28): each area's dwell within 10 % or 0.2 s of the truth's, time to first fixation
within 0.2 s, the empty area 0 s; the batch's sessions x areas table holds every session.
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
from pathlib import Path

import numpy as np

from wearable_gaze.formats.aoi_tables import read_aoi_metrics
from wearable_gaze.formats.truth import read_truth_targets
from wearable_gaze.pipeline.batch import BatchSettings, run_batch
from wearable_gaze.sim.simulate import simulate_scenario

SCENARIO = {"base": "lab-walkabout", "duration_s": 20.0, "camera": {"resolution": [640, 360]},
            "targets": {"points_mm": [[-600.0, 100.0, 1200.0], [500.0, -200.0, 2000.0], [-300.0, 300.0, 2800.0],
                                      [900.0, 0.0, 3500.0]], "random_count": 0}}
"""Every session's targets at the same points (one AOI file for the batch), each seed its own walk,
eyes and noise."""
BOX_MM = 300.0
NOBODY = {"name": "nobody", "sphere": {"center_mm": [0.0, -3000.0, 0.0], "radius_mm": 200.0}}


def truth_measures(session: Path) -> dict:
    """{target index: (dwell s, first fixation s)} from truth/gaze.csv's per-sample target."""
    with open(session / "truth" / "gaze.csv", newline="") as fh:
        rows = [(float(r["t"]), int(r["target"]), r["phase"]) for r in csv.DictReader(fh)]
    t = np.array([r[0] for r in rows])
    dt = float(np.median(np.diff(t)))
    out = {}
    for k in {r[1] for r in rows if r[1] >= 0}:
        on = np.array([r[1] == k and r[2] == "fixation" for r in rows])
        if on.any():
            out[k] = (float(on.sum() * dt), float(t[on][0] - t[0]))
    return out


def aois_of(session: Path) -> dict:
    areas = [{"name": f"target {t['index']}", "box": {"center_mm": t["position_mm"], "size_mm": [BOX_MM] * 3}}
             for t in read_truth_targets(session / "truth" / "targets.json") if not t["moving"]]
    return {"aois": [*areas, NOBODY]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=3, help="simulated sessions (default 3)")
    ap.add_argument("--seed", type=int, default=1, help="random seed of the first session (default 1)")
    ap.add_argument("--work", type=Path, default=None, help="a folder to work in, kept (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.work or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        root = Path(tmp) / "study"
        sessions = [root / f"s{i}" for i in range(args.sessions)]
        for i, s in enumerate(sessions):
            simulate_scenario(SCENARIO, s, seed=args.seed + i)
        aois = [aois_of(s) for s in sessions]
        assert all(a == aois[0] for a in aois), "the sessions' targets differ: one AOI file cannot hold them"
        (Path(tmp) / "aois.json").write_text(json.dumps(aois[0]))
        res = run_batch([root], Path(tmp) / "out", BatchSettings(overlay=False, aois=str(Path(tmp) / "aois.json")))
        assert not res.failed, res.failed
        fails = 0
        print(f"{'session':<8} {'area':<10} {'truth dwell':>11} {'ours':>6} {'truth 1st':>9} {'ours':>6}  ok")
        for s in sessions:
            m = read_aoi_metrics(Path(tmp) / "out" / s.name / "aoi_metrics.csv")
            truth = truth_measures(s)
            for j, name in enumerate(m["aoi"]):
                k = int(name.split()[-1]) if name.startswith("target") else None
                dwell, first = truth.get(k, (0.0, np.nan))
                ok_dwell = abs(m["dwell_s"][j] - dwell) <= max(0.1 * dwell, 0.2)
                ok_first = (np.isnan(first) and np.isnan(m["first_fixation_s"][j])) or \
                    abs(m["first_fixation_s"][j] - first) <= 0.2
                fails += not (ok_dwell and ok_first)
                print(f"{s.name:<8} {name:<10} {dwell:>11.2f} {m['dwell_s'][j]:>6.2f} {first:>9.2f} "
                      f"{m['first_fixation_s'][j]:>6.2f}  {'yes' if ok_dwell and ok_first else 'NO'}")
        table = (Path(tmp) / "out" / "batch_aoi_metrics.csv").read_text().splitlines()
        print(f"batch_aoi_metrics.csv: {len(table) - 1} rows ({args.sessions} sessions x {len(aois[0]['aois'])} areas)")
        print(f"{fails} area(s) outside the targets")


if __name__ == "__main__":
    main()
