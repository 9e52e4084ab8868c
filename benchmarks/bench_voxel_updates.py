"""The streaming voxel estimator's CPU time per update in the live session's estimation (issue 29:
the bursts that held the live loop's samples up), the default settings against other ones,
interleaved sample by sample in one process so that the machine's load falls on both alike.

A simulated lab-walkabout session at 200 Hz (``--seconds``, 60; the one ``bench_live.py --device``
serves): its measured rays with the true head poses go through the live estimation
(``GazeEstimation.add``: world lines, the online segmentation), and every sample its fixation's
estimator takes is given to two streaming ``VoxelEstimator`` s, a new pair at each fixation: one
with the default ``VoxelConfig``, one with ``--against`` (default: the settings of before, a box
re-laid over up to 1,024 lines in one update and the seed fits and error model over up to 2,048
samples), which goes first alternating. Timed: each ``update``, the thread's CPU time (the objects of
before the session frozen for the garbage collector, as the live session freezes them).

    python benchmarks/bench_voxel_updates.py [--seconds 60] [--against layout_chunk_lines=1024,update_fit_samples=2048]

Printed: each one's p50 / p95 / p99 / max per update and the updates over 3 and 5 ms, their
total CPU, and how far apart their estimates were (after each update, over the updates both
answered, in the new one's sd: the two give the same targets).
"""

from __future__ import annotations

import argparse
import gc
import os
import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np

from estimator.voxel import VoxelConfig, VoxelEstimator
from wearable_gaze.formats.devices.common import read_simulated_recording
from wearable_gaze.formats.devices.pupil_net import RaySample
from wearable_gaze.pipeline.steps.estimate import DEFAULT_ERROR_MODEL
from wearable_gaze.pipeline.steps.live_estimation import GazeEstimation, RayEyes, warm_up
from wearable_gaze.sim.simulate import simulate_scenario


def _records(root: Path):
    """(t, RaySample, T_world_from_head) of each sample of the simulated session with an eye valid."""
    rec = read_simulated_recording(root)
    r = rec.rays
    for k in range(len(r.t_s)):
        lv, rv = bool(r.left_valid[k]), bool(r.right_valid[k])
        if not (lv or rv):
            continue
        left = tuple(np.concatenate([r.left_origin_mm[k], r.left_direction[k]])) if lv else (np.nan,) * 6
        right = tuple(np.concatenate([r.right_origin_mm[k], r.right_direction[k]])) if rv else (np.nan,) * 6
        yield float(r.t_s[k]), RaySample(k, float(r.t_s[k]), left, right, lv, rv, 1.0), rec.T_world_from_head[k]


def _parse(text: str) -> dict:
    out = {}
    for item in filter(None, text.split(",")):
        key, value = item.split("=")
        out[key] = type(getattr(VoxelConfig(), key))(value)
    return out


def run(root: Path, against: dict) -> None:
    configs = {"default": VoxelConfig(error_model=DEFAULT_ERROR_MODEL),
               "against": VoxelConfig(error_model=DEFAULT_ERROR_MODEL, **against)}
    warm_up("voxel")
    gc.freeze()              # as ``LiveSession.run`` does: the collector scans only what the session makes
    est = GazeEstimation([RayEyes(), RayEyes()], "voxel")       # the segmentation (its own estimator untimed)
    cpu: dict = {k: [] for k in configs}
    nth: list = []                                               # each update's sample count in its fixation
    apart, fixation, pair, k = [], -1, {}, 0
    for t, rec, T in _records(root):
        est.add(t, rec, T)
        if est.fixation != fixation:
            fixation, pair = est.fixation, {name: VoxelEstimator(c) for name, c in configs.items()}
        if not est.lines or est.lines[-1].t_s != t:
            continue                                             # in a saccade: no fixation's estimator took it
        sample, out = est.lines[-1], {}
        for name in (list(configs) if k % 2 == 0 else list(configs)[::-1]):
            c0 = time.thread_time()
            out[name] = pair[name].update(sample)
            cpu[name].append(time.thread_time() - c0)
        k += 1
        nth.append(len(pair["default"]))
        a, b = out["default"], out["against"]
        if a.ok and b.ok:
            d = a.position_mm - b.position_mm
            apart.append(float(np.sqrt(d @ np.linalg.solve(a.covariance_mm2, d))))
    print(f"{k} updates, each given to both estimators in turn; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for name in configs:
        x = np.array(cpu[name]) * 1e3
        label = "default" if name == "default" else ", ".join(f"{key}={v}" for key, v in against.items())
        print(f"  {label}: CPU per update p50 {np.percentile(x, 50):.2f} ms, p95 {np.percentile(x, 95):.2f}, "
              f"p99 {np.percentile(x, 99):.2f}, max {x.max():.1f} ms; over 3 ms {int((x > 3).sum())}, over 5 ms "
              f"{int((x > 5).sum())}; total {x.sum() / 1e3:.2f} s (the max at update {int(np.argmax(x))}, "
              f"its fixation's sample {nth[int(np.argmax(x))]})")
    ap = np.array(apart)
    print(f"  estimates apart (both answered, {len(ap)} updates), in the default's sd: p50 "
          f"{np.percentile(ap, 50):.3f}, p95 {np.percentile(ap, 95):.3f}, max {ap.max():.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--against", default="layout_chunk_lines=1024,update_fit_samples=2048",
                    help="VoxelConfig fields (KEY=VALUE,...) of the estimator compared with the default one")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "s"
        simulate_scenario({"base": "lab-walkabout", "duration_s": args.seconds, "eyes": {"rate_hz": 200.0},
                           "camera": {"resolution": [640, 360]}, "calibration": {"camera_views": 0}}, root, args.seed)
        run(root, _parse(args.against))


if __name__ == "__main__":
    main()
