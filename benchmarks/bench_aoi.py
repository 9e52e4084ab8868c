"""Areas of interest against the simulator's truth (issue 28): simulated walking sessions
(lab-walkabout, 20 s, 640x360, four targets at 1.2-3.6 m) processed by ``batch --aois`` with a
300 mm box around each true static target and one area nobody looks at; per area, its dwell
time against the truth's (the time the simulator's per-sample target is that target in a
fixation) and its time to first fixation against the truth's first fixation sample.

    python benchmarks/bench_aoi.py [--sessions 3] [--seed 1] [--work DIR]

``--work``: simulate and process into DIR and keep it (default: a temporary folder, removed); run
again with the same DIR, it reuses the sessions and the steps that did not change.

Targets (issue 28): each area's dwell within 10 % or 0.2 s of the truth's, time to first fixation
within 0.2 s, the empty area 0 s, "the same through ``batch`` for three sessions": the measures are
read from the batch's own sessions x areas table (``batch_aoi_metrics.csv``), which must hold every
session and area, each row equal to that session's ``aoi_metrics.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
from pathlib import Path

import numpy as np

from wearable_gaze.formats.aoi_tables import read_aoi_fixations, read_aoi_metrics
from wearable_gaze.formats.truth import read_truth_targets
from wearable_gaze.pipeline.batch.run import BatchSettings, run_batch
from wearable_gaze.sim.simulate import simulate_scenario

SCENARIO = {"base": "lab-walkabout", "duration_s": 20.0, "camera": {"resolution": [640, 360]},
            "targets": {"points_mm": [[-600.0, 100.0, 1200.0], [500.0, -200.0, 2000.0], [-300.0, 300.0, 2800.0],
                                      [900.0, 0.0, 3500.0]], "random_count": 0}}
"""Every session's targets at the same points (one AOI file for the batch), each seed its own walk,
eyes and noise."""
BOX_MM = 300.0
NOBODY = {"name": "nobody", "sphere": {"center_mm": [0.0, -3000.0, 0.0], "radius_mm": 200.0}}


def truth_runs(session: Path) -> tuple[list, float]:
    """([(target, start s, end s)] of each run of samples the simulator has in a fixation of a
    target (truth/gaze.csv's per-sample ``target`` and ``phase``; blinks and saccades are not in
    one), each run ending one sample interval after its last sample; that interval, s)."""
    with open(session / "truth" / "gaze.csv", newline="") as fh:
        rows = [(float(r["t"]), int(r["target"]), r["phase"]) for r in csv.DictReader(fh)]
    dt = float(np.median(np.diff([r[0] for r in rows])))
    runs, prev = [], None
    for t, k, phase in rows:
        key = (k, phase) if k >= 0 and phase == "fixation" else None
        if key is not None and key == prev:
            runs[-1][2] = t - rows[0][0] + dt
        elif key is not None:
            runs.append([k, t - rows[0][0], t - rows[0][0] + dt])
        prev = key
    return [tuple(r) for r in runs], dt


def truth_measures(session: Path) -> dict:
    """{target index: (dwell s, first fixation s)} from truth/gaze.csv's per-sample target: the
    time its samples are in a fixation of it (sample count x interval), and the first one's time."""
    runs, _ = truth_runs(session)
    return {k: (sum(b - a for j, a, b in runs if j == k), min(a for j, a, _ in runs if j == k))
            for k in {r[0] for r in runs}}


def why(session: Path, fx: dict, name: str, k: int, lost: dict) -> str:
    """Where an area's dwell differs from the truth's (``fx``: aoi_fixations.csv): per assigned
    fixation, its start after the first true fixation of target ``k`` it overlaps and its end
    (its last sample's time plus one sample interval, as the truth's runs end) before the last
    one's (mean, s), the blinks between those true fixations it spans (which
    neither the truth nor its duration counts); the true fixations no assigned one overlaps; the
    assigned time over no true fixation; the least assignment probability. Adds to ``lost``
    the time the fixations' late starts and early ends lose (``edges``) and the missed true
    fixations' (``missed``), s."""
    every, dt = truth_runs(session)
    runs = [(a, b) for j, a, b in every if j == k]
    mine = [(a, b, p) for a, b, area, p in zip(fx["start_s"], fx["end_s"], fx["aoi"], fx[f"p_{name}"], strict=True)
            if area == name]
    lag, early, bridged, extra = [], [], 0.0, 0.0
    for s, e, _ in mine:
        over = [(a, b) for a, b in runs if s < b and e > a]
        if not over:
            extra += e - s
            continue
        lag.append(s - over[0][0])
        early.append(over[-1][1] - (e + dt))
        bridged += sum(a2 - b1 for (_, b1), (a2, _) in zip(over, over[1:], strict=False))
    missed = [b - a for a, b in runs if not any(s < b and e > a for s, e, _ in mine)]
    lost["edges"] = lost.get("edges", 0.0) + sum(lag) + sum(early)
    lost["missed"] = lost.get("missed", 0.0) + sum(missed)
    parts = [f"starts {np.mean(lag):+.2f} s, ends {-np.mean(early):+.2f} s" if lag else "",
             f"spans blinks {bridged:.2f} s (not counted)" if bridged else "",
             f"true fixations missed {', '.join(f'{m:.2f}' for m in missed)} s" if missed else "",
             f"assigned outside any true fixation {extra:.2f} s" if extra else "",
             f"least p {min(p for *_, p in mine):.2f}" if mine else ""]
    return "; ".join(x for x in parts if x)


def batch_table(out: Path, sessions: list, n_areas: int) -> dict:
    """{session name: its rows of the batch's ``batch_aoi_metrics.csv`` as aoi_metrics.csv's
    columns}, checked: every session with ``n_areas`` rows, each equal to the session's own
    aoi_metrics.csv (the measures are taken from the batch's table)."""
    with open(out / "batch_aoi_metrics.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    table = {}
    for s in sessions:
        mine = [r for r in rows if r["session"] == s.name]
        own = read_aoi_metrics(out / s.name / "aoi_metrics.csv")
        assert len(mine) == n_areas == len(own["aoi"]), (s.name, len(mine), n_areas)
        text = ("aoi", "group")
        cols = {k: np.array([r[k] if k in text else float(r[k] or "nan") for r in mine], object if k in text else float)
                for k in own}
        for k, v in own.items():
            same = [str(a or "") for a in v] == [str(a or "") for a in cols[k]] if k in text else \
                np.allclose(v, cols[k], atol=1e-4, equal_nan=True)
            assert same, (s.name, k, v, cols[k])
        table[s.name] = cols
    assert len(rows) == len(sessions) * n_areas, (len(rows), len(sessions), n_areas)
    return table


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
            if not (s / "session.json").is_file():         # --work again: its sessions and steps reused
                simulate_scenario(SCENARIO, s, seed=args.seed + i)
        aois = [aois_of(s) for s in sessions]
        assert all(a == aois[0] for a in aois), "the sessions' targets differ: one AOI file cannot hold them"
        (Path(tmp) / "aois.json").write_text(json.dumps(aois[0]))
        res = run_batch([root], Path(tmp) / "out", BatchSettings(overlay=False, aois=str(Path(tmp) / "aois.json")))
        assert not res.failed, res.failed
        fails, lost, short = 0, {}, 0.0
        table = batch_table(Path(tmp) / "out", sessions, len(aois[0]["aois"]))
        print(f"{'session':<8} {'area':<10} {'truth dwell':>11} {'ours':>6} {'truth 1st':>9} {'ours':>6}  ok   why")
        for s in sessions:
            m = table[s.name]
            fx = read_aoi_fixations(Path(tmp) / "out" / s.name / "aoi_fixations.csv")
            truth = truth_measures(s)
            for j, name in enumerate(m["aoi"]):
                k = int(name.split()[-1]) if name.startswith("target") else None
                dwell, first = truth.get(k, (0.0, np.nan))
                ok_dwell = abs(m["dwell_s"][j] - dwell) <= max(0.1 * dwell, 0.2)
                ok_first = (np.isnan(first) and np.isnan(m["first_fixation_s"][j])) or \
                    abs(m["first_fixation_s"][j] - first) <= 0.2
                fails += not (ok_dwell and ok_first)
                short += dwell - m["dwell_s"][j]
                print(f"{s.name:<8} {name:<10} {dwell:>11.2f} {m['dwell_s'][j]:>6.2f} {first:>9.2f} "
                      f"{m['first_fixation_s'][j]:>6.2f}  {'yes' if ok_dwell and ok_first else 'NO '}  "
                      + (why(s, fx, name, k, lost) if k is not None else ""))
        print(f"batch_aoi_metrics.csv: {sum(len(m['aoi']) for m in table.values())} rows ({args.sessions} sessions x "
              f"{len(aois[0]['aois'])} areas), each equal to its session's aoi_metrics.csv")
        print(f"dwell short of the truth's by {short:.2f} s in all: the fixations' late starts and early ends "
              f"{lost.get('edges', 0.0):.2f} s, true fixations no fixation found {lost.get('missed', 0.0):.2f} s, "
              f"the rest {short - lost.get('edges', 0.0) - lost.get('missed', 0.0):+.2f} s")
        print(f"{fails} area(s) outside the targets: {'PASS' if not fails else 'FAIL'} "
              f"({len(sessions) * len(aois[0]['aois']) - fails} of {len(sessions) * len(aois[0]['aois'])} within)")


if __name__ == "__main__":
    main()
