"""Fixation detection in the world frame against the simulator's truth (issue 27): simulated
walking and swaying sessions at several eye rates, every error source on, segmented as
``process`` segments them (``pipeline.steps.segmentation.segment_view_lines`` with the rate's
``segment_config``); recall and precision of the fixations against the truth's fixation
intervals (``fixations_s`` of truth/targets.json: the runs of samples the simulator's plan puts
on one target).

    python benchmarks/bench_fixations.py [--sessions 60] [--seed 100] [--work DIR]

The sessions are simulated at the level of view lines, with the simulator's own pieces
(``sim.eyes``: gaze plan, saccades, blinks, one-eye dropouts, per-eye noise and bias;
``sim.motion``: the walk or sway; ``sim.simulate.make_targets``), without rendering a video:
the head poses are the true ones with a tracking error per video frame (30 fps) at the figure
docs/tracking.md measures for marker tracking (rotation 0.016 deg, translation 1.0 mm median),
taken here as 0.03 deg and 1.5 mm sd per axis. Session i: eye rate 30/60/120/200 Hz in turn;
motion: a walk past the targets (0.6-4 m ahead of the world origin; lateral across it, diagonal or
forward up to it, 300-900 mm/s) or a standing
sway (100-250 mm, 5-15 deg); dwell per target 0.4-1.2, 0.8-2, 1.5-3 or 2.5-4 s; noise 0.7-1.3 deg per
eye; per-eye bias up to 0.5 deg; 20 s each.

Scoring: a found fixation is right when one true fixation overlaps it by half its length or
more (precision); a true fixation is found when one found fixation overlaps it by half the true
one's length (recall). True fixations shorter than the segmentation's minimum (0.3 s) or with
fewer than half their samples valid (the target behind the head) are not counted for recall.
``--work DIR`` keeps each session's view lines (viewlines.csv) and truth (targets.json) there
and reuses them.
"""

from __future__ import annotations

import argparse
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from estimator.lines import BinocularSamples
from wearable_gaze.formats.jsonio import read_json_text, write_json
from wearable_gaze.formats.viewlines import read_viewlines_csv, write_viewlines_csv
from wearable_gaze.pipeline.steps.segmentation import segment_config, segment_view_lines
from wearable_gaze.sim.eyes import EyeModel, gaze_points, plan_gaze
from wearable_gaze.sim.motion import make_motion
from wearable_gaze.sim.scenario import resolve
from wearable_gaze.sim.simulate import make_targets

RATES = (30.0, 60.0, 120.0, 200.0)
DWELLS = ((0.4, 1.2), (0.8, 2.0), (1.5, 3.0), (2.5, 4.0))
POSE_FPS, POSE_DEG, POSE_MM = 30.0, 0.03, 1.5


def scenario(i: int, rng: np.random.Generator) -> dict:
    """Session ``i``'s scenario (resolved): its rate, motion, dwell, noise and bias."""
    kind = ("walk", "walk", "sway")[i % 3]
    head = {"motion": kind, "sway_mm": float(rng.uniform(100, 250)), "sway_deg": float(rng.uniform(5, 15))}
    if kind == "walk":
        way = rng.choice(["lateral", "diagonal", "forward"])
        side = float(rng.choice([-1.0, 1.0]))
        start = {"lateral": [-2500 * side, 0, 0], "diagonal": [-2000 * side, 0, -2000], "forward": [0, 0, -6000]}[way]
        goal = {"lateral": [2500 * side, 0, 0], "diagonal": [2000 * side, 0, 0], "forward": [0, 0, 0]}[way]
        head.update(start_mm=start, walk_to_mm=goal, speed_mm_s=float(rng.uniform(300, 900)))
    spec = {"duration_s": 20.0,
            "eyes": {"rate_hz": RATES[i % len(RATES)], "sigma_deg": float(rng.uniform(0.7, 1.3)),
                     "bias_deg": rng.uniform(-0.5, 0.5, (2, 2)).tolist(), "fixation_s": list(DWELLS[(i // 4) % 4]),
                     "order": "random"},
            "targets": {"random_count": 6, "random_depth_mm": [600.0, 4000.0]}, "head": head}
    return resolve(spec)


def pose_error(t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3, 3) rotations and (N, 3) offsets, mm: a tracking error per video frame, held over it."""
    frame = np.floor(t * POSE_FPS).astype(int)
    n = frame.max() + 1
    R = Rotation.from_rotvec(rng.normal(0, np.deg2rad(POSE_DEG), (n, 3))).as_matrix()
    return R[frame], rng.normal(0, POSE_MM, (n, 3))[frame]


def simulate_lines(scn: dict, seed: int) -> tuple[BinocularSamples, list]:
    """World view lines (as the view-line step would give them) and the true fixations [(start,
    end, valid fraction)], s, of one session."""
    rng_t, rng_m, rng_e, rng_g, rng_n, rng_p = (np.random.default_rng(s) for s in
                                                 np.random.SeedSequence(seed).spawn(6))
    es = scn["eyes"]
    targets = make_targets(scn, rng_t)          # ahead of the world origin, which the walks pass or near
    t = np.arange(int(scn["duration_s"] * es["rate_hz"])) / es["rate_hz"]
    plan = plan_gaze(t, len(targets), [False] * len(targets), rng_g, es["fixation_s"], es["blink_rate_hz"],
                     es["dropout_rate"], es["order"])
    gaze_w = gaze_points(t, plan, targets)
    motion = make_motion(scn["head"], scn["duration_s"], rng_m,
                         lambda tt: np.column_stack([np.interp(tt, t, gaze_w[:, i]) for i in range(3)]))
    T = motion.poses(t)
    eyes = EyeModel.make(rng_e, es["ipd_mm"], es["centre_offset_mm"], es["sigma_deg"], es["bias_deg"])
    gaze_c = np.einsum("nji,nj->ni", T[:, :3, :3], gaze_w - T[:, :3, 3])
    _, _, noisy = eyes.measure(gaze_c, rng_n, with_bias=True)
    valid = plan.valid & (gaze_c[:, 2] > 0)[:, None]
    dR, dt = pose_error(t, rng_p)
    R = np.einsum("nij,njk->nik", T[:, :3, :3], dR)
    o = np.einsum("nij,ej->nei", R, eyes.centers) + (T[:, :3, 3] + dt)[:, None]
    d = np.einsum("nij,nej->nei", R, noisy)
    nan = np.full((len(t), 3), np.nan)
    samples = BinocularSamples.from_arrays(t, o[:, 0], np.where(valid[:, :1], d[:, 0], nan),
                                           o[:, 1], np.where(valid[:, 1:], d[:, 1], nan))
    truth = []
    for k in range(len(targets)):
        sel = np.flatnonzero(plan.target == k)
        for run in np.split(sel, np.flatnonzero(np.diff(sel) > 1) + 1) if len(sel) else []:
            truth.append((float(t[run[0]]), float(t[run[-1]]), float(valid[run].any(axis=1).mean())))
    return samples, sorted(truth)


def found_fixations(samples: BinocularSamples, labels: np.ndarray) -> list[tuple[float, float]]:
    """[(first, last sample time)] of each labelled fixation, s."""
    return [(float(samples.t_s[labels == k].min()), float(samples.t_s[labels == k].max()))
            for k in range(int(labels.max()) + 1)]


def overlap(a: tuple, b: tuple) -> float:
    return max(0.0, min(a[1], b[1]) - max(a[0], b[0]))


def score(found: list, truth: list, min_s: float) -> tuple[int, int, int, int]:
    """(true fixations found, true fixations counted, found fixations right, found fixations)."""
    counted = [tr for tr in truth if tr[1] - tr[0] >= min_s and tr[2] >= 0.5]
    hit = sum(any(overlap(f, tr) >= 0.5 * (tr[1] - tr[0]) for f in found) for tr in counted)
    right = sum(any(overlap(f, tr) >= 0.5 * (f[1] - f[0]) for tr in truth) for f in found)
    return hit, len(counted), right, len(found)


def session(work: Path, i: int, seed: int) -> tuple[dict, BinocularSamples, list]:
    """Session i's scenario, view lines and truth, simulated or read back from ``work``."""
    rng = np.random.default_rng([seed, i])
    scn = scenario(i, rng)
    folder = work / f"s{i}"
    if not (folder / "targets.json").is_file():
        samples, truth = simulate_lines(scn, seed * 1000 + i)
        folder.mkdir(parents=True, exist_ok=True)
        keep = np.flatnonzero(samples.left_valid | samples.right_valid)     # as the view-line step writes
        write_viewlines_csv(folder / "viewlines.csv", samples.select(keep))
        write_json(folder / "targets.json", {"fixations_s": truth})
    samples = read_viewlines_csv(folder / "viewlines.csv")[0].samples
    truth = [tuple(x) for x in read_json_text(folder / "targets.json", "truth")["fixations_s"]]
    return scn, samples, truth


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=60, help="simulated sessions (default 60)")
    ap.add_argument("--seed", type=int, default=100, help="random seed (default 100)")
    ap.add_argument("--work", type=Path, default=None, help="a folder to work in, kept (default: a temporary one)")
    args = ap.parse_args()
    groups: dict = defaultdict(lambda: np.zeros(4, int))
    with tempfile.TemporaryDirectory() as scratch:
        work = (args.work or Path(scratch)) / f"seed{args.seed}"
        for i in range(args.sessions):
            scn, samples, truth = session(work, i, args.seed)
            rate = scn["eyes"]["rate_hz"]
            cfg = segment_config(rate)
            r = np.array(score(found_fixations(samples, segment_view_lines(samples, cfg)), truth, cfg.min_fixation_s))
            dwell = "dwell {:g}-{:g} s".format(*scn["eyes"]["fixation_s"])
            for key in ("all", f"{rate:g} Hz", scn["head"]["motion"], dwell):
                groups[key] += r
    print(f"fixations against the truth, {args.sessions} sessions, seed {args.seed}")
    print(f"{'group':<16} {'recall':>18} {'precision':>18}")
    for key, (hit, n_true, right, n_found) in groups.items():
        print(f"{key:<16} {100 * hit / max(n_true, 1):6.1f} % ({hit:3d}/{n_true:3d}) "
              f"{100 * right / max(n_found, 1):6.1f} % ({right:3d}/{n_found:3d})")


if __name__ == "__main__":
    main()
