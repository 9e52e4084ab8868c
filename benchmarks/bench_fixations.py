"""Fixation detection on simulated walking sessions with every error source on, old rule against
new (issue 27): recall and precision of the fixations found against the truth's fixation
intervals.

    BENCH_CORES=2 python benchmarks/bench_fixations.py [--sessions 60] [--seed 2700] [--work DIR]

Each session (15 s) is simulated and processed once into ``--work`` (kept: a second run only
segments the view lines ``process`` wrote again): a head walking 0.5-1.0 m/s toward targets
1-4.5 m beyond where it stops, turning partly toward each target and swaying (so the eyes
counter-rotate in the head: the vestibulo-ocular reflex), eye samples at 10, 30, 60 or 120 Hz
(in turn), fixations of 0.5-2 s, 1 deg eye noise, a per-eye bias after calibration (sd 0.3 deg
per axis), blinks and dropouts, eye calibration from the simulated walls, head poses tracked
in the 640x360 scene video.

Scoring: a found fixation (a run of equal labels, ``segment_view_lines``) and a true one (a span
of ``truth/targets.json``'s ``fixations_s``) are a pair when their overlap in time is at least
half the length of each (one-to-one, the largest overlaps first); recall is the pairs over the
true fixations, precision the pairs over the found ones. The true fixations shorter than the
segmentation's minimum (0.3 s) are left out of recall.

Target (issue 27): recall and precision at least 95 % each with the new rule, over >= 60 sessions.

Measured (60 sessions, seed 2700, 726 true fixations; worldfix branch, 2026-12-03):

| rule | 10 Hz | 30 Hz | 60 Hz | 120 Hz | all |
|---|---|---|---|---|---|
| old (eye-in-head rule on the world lines), recall | 47.0 % | 76.7 % | 74.0 % | 90.1 % | 71.9 % |
| old, precision | 74.1 % | 92.0 % | 88.2 % | 94.8 % | 88.3 % |
| new (world rule), recall | 95.1 % | 88.3 % | 91.2 % | 94.5 % | **92.3 %** |
| new, precision | 97.2 % | 95.8 % | 95.4 % | 96.6 % | **96.3 %** |

Precision meets the target, recall does not (92.3 %; 95.1 % at 10 Hz). What the misses are,
from the sessions looked at: the scene-video tracking losing or misplacing the head for a few frames (a pose 13 deg
and 2.4 m off marked ok: the rays jump, the fixation is cut), and saccades of 2-4 deg between
targets that lie in nearly one direction at different depths, which the course score at 30 Hz
(threshold 5.5 deg there for 1 deg of noise per eye) does not see and which the chain splitter,
kept to rates up to 26 Hz, does not split.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import _onecore  # noqa: F401  (first: pins the cores before numpy and OpenCV load)
import numpy as np

from estimator.segments import SegmentConfig
from wearable_gaze.formats.viewlines import read_viewlines_csv
from wearable_gaze.pipeline.process import process_session
from wearable_gaze.pipeline.segmentation import segment_view_lines
from wearable_gaze.sim.simulate import simulate_scenario

RATES_HZ = (10.0, 30.0, 60.0, 120.0)


def scenario(rng, k: int) -> dict:
    """Session ``k``: a walk of 0.5-1.0 m/s for 4-6 m, then standing; 4-6 static targets 1-4.5 m
    beyond the walk's end, up to 2 m to either side; eye rate ``RATES_HZ[k % 4]``."""
    walk = float(rng.uniform(4000, 6000))
    n = int(rng.integers(4, 7))
    pts = np.column_stack([rng.uniform(-2000, 2000, n), rng.uniform(-800, 300, n), walk + rng.uniform(1000, 4500, n)])
    return {"base": "lab-walkabout", "duration_s": 15.0, "camera": {"resolution": [640, 360]},
            "room": {"size_mm": [6000.0, 2700.0, 13000.0], "markers_per_wall": 8},
            "eyes": {"rate_hz": RATES_HZ[k % len(RATES_HZ)], "fixation_s": [0.5, 2.0], "order": "random",
                     "bias_deg": rng.normal(0.0, 0.3, size=(2, 2)).round(3).tolist()},
            "targets": {"points_mm": pts.round(1).tolist(), "random_count": 0},
            "head": {"motion": "walk", "start_mm": [0.0, 0.0, 0.0], "walk_to_mm": [float(rng.uniform(-500, 500)), 0.0,
                                                                                  walk],
                     "speed_mm_s": float(rng.uniform(500, 1000)), "sway_deg": float(rng.uniform(4, 10)),
                     "sway_mm": float(rng.uniform(50, 120))}}


def session_lines(work: Path, rng, k: int, seed: int):
    """(view lines before segmentation, eye rate, the true fixation spans (M, 2) s) of session
    ``k``, simulated and processed into ``work`` once."""
    root, out = work / f"s{k:03d}", work / f"s{k:03d}-processed"
    scn = scenario(rng, k)                      # drawn every time: the sessions after k stay the same
    if not (root / "session.json").is_file():
        simulate_scenario(scn, root, seed=seed + k)
    if not (out / ".viewlines_unsegmented.csv").is_file():
        process_session(root, out, overlay=False, report=False)
    samples = read_viewlines_csv(out / ".viewlines_unsegmented.csv")[0].samples
    truth = json.loads((root / "truth" / "targets.json").read_text())["targets"]
    spans = np.array(sorted(s for t in truth if not t["moving"] for s in t["fixations_s"])).reshape(-1, 2)
    return samples, float(scn["eyes"]["rate_hz"]), spans


def found_spans(t_s: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(K, 2) first and last time, s, of each fixation label >= 0."""
    return np.array([[t_s[labels == k].min(), t_s[labels == k].max()]
                     for k in np.unique(labels[labels >= 0])]).reshape(-1, 2)


def score(found: np.ndarray, truth: np.ndarray, min_s: float) -> tuple[int, int, int]:
    """(pairs, found fixations, true fixations of at least ``min_s``): one-to-one pairs whose
    overlap is at least half of each one's length, largest overlaps first."""
    truth = truth[truth[:, 1] - truth[:, 0] >= min_s]
    cand = []
    for i, (a, b) in enumerate(found):
        for j, (c, d) in enumerate(truth):
            ov = min(b, d) - max(a, c)
            if ov > 0 and ov >= 0.5 * (b - a) and ov >= 0.5 * (d - c):
                cand.append((ov, i, j))
    used_f, used_t = set(), set()
    for _, i, j in sorted(cand, reverse=True):
        if i not in used_f and j not in used_t:
            used_f.add(i)
            used_t.add(j)
    return len(used_f), len(found), len(truth)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=60, help="simulated sessions (default 60)")
    ap.add_argument("--seed", type=int, default=2700, help="random seed (default 2700)")
    ap.add_argument("--work", type=Path, default=None, help="keep the sessions here (default: a temporary folder)")
    ap.add_argument("--simulate-only", action="store_true", help="simulate and process, do not score")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng(args.seed)
        totals = {rule: {} for rule in ("old", "new")}
        for k in range(args.sessions):
            samples, rate, truth = session_lines(work, rng, k, args.seed)
            if args.simulate_only:
                print(f"session {k}: {len(samples)} view lines at {rate:g} Hz, {len(truth)} true fixations", flush=True)
                continue
            cfg = SegmentConfig.for_rate(rate)
            line = []
            for rule, world in (("old", False), ("new", True)):
                labels = segment_view_lines(samples, cfg, world=world)
                p, nf, nt = score(found_spans(samples.t_s, labels), truth, cfg.min_fixation_s)
                acc = totals[rule].setdefault(rate, np.zeros(3, int))
                acc += (p, nf, nt)
                line.append(f"{rule} {p}/{nf} found, {p}/{nt} true")
            print(f"session {k} ({rate:g} Hz): " + "; ".join(line), flush=True)
        if args.simulate_only:
            return
        for rule, by_rate in totals.items():
            for rate, (p, nf, nt) in sorted(by_rate.items()):
                print(f"{rule} rule, {rate:g} Hz: recall {p / max(nt, 1):.1%} ({p}/{nt}), "
                      f"precision {p / max(nf, 1):.1%} ({p}/{nf})")
            p, nf, nt = np.sum(list(by_rate.values()), axis=0)
            print(f"{rule} rule, all {args.sessions} sessions: recall {p / max(nt, 1):.1%} ({p}/{nt}), "
                  f"precision {p / max(nf, 1):.1%} ({p}/{nf})")


if __name__ == "__main__":
    main()
