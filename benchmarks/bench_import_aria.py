"""Aria MPS import on one core: time and peak traced memory (tracemalloc) of importing the real
gen1 sample, and of a 1-minute and a long (default 60-minute) synthetic recording, each with a
1 kHz closed_loop_trajectory.csv and 10 Hz per-eye gaze written by ``aria.write_recording`` from a
generated walk. Memory must stay flat in the recording's length (the trajectory is streamed).

    python benchmarks/bench_import_aria.py [--minutes 60]
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy loads)
import numpy as np
from _args import size_and_seed
from _traced import traced_import

from estimator.lines import BinocularSamples
from wearable_gaze.formats.devices import aria
from wearable_gaze.formats.devices.common import SimulatedRecording

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "aria_mps_sample_gen1"


def walk(minutes: float, rng, rate_hz: float = 10.0) -> SimulatedRecording:
    """A wearer walking a 2 m circle (0.5 m/s, head bobbing and turning) and fixating a new
    point 2-5 m ahead every 2 s: head-frame rays at ``rate_hz`` with 1 deg noise."""
    t = np.arange(int(minutes * 60 * rate_hz)) / rate_hz
    a = t * 0.25                                                   # rad: 0.5 m/s on a 2 m radius
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, 0, 3], T[:, 1, 3], T[:, 2, 3] = 2000 * np.sin(a), -1600 + 30 * np.sin(2 * np.pi * 1.8 * t), 2000 * np.cos(a)
    yaw = a + np.pi / 2 + 0.3 * np.sin(0.4 * t)
    T[:, 0, 0], T[:, 0, 2], T[:, 2, 0], T[:, 2, 2] = np.cos(yaw), np.sin(yaw), -np.sin(yaw), np.cos(yaw)
    seg = (t // 2).astype(int)                                     # a new point ahead every 2 s
    first = np.flatnonzero(np.diff(seg, prepend=-1))
    ahead = rng.uniform([-800, -300, 2000], [800, 600, 5000], size=(len(first), 3))
    targets = np.einsum("nij,nj->ni", T[first, :3, :3], ahead) + T[first, :3, 3]
    gaze_w = targets[seg]
    gaze_h = np.einsum("nji,nj->ni", T[:, :3, :3], gaze_w - T[:, :3, 3])
    eyes = [np.tile([-32.0, 0.0, 0.0], (len(t), 1)), np.tile([32.0, 0.0, 0.0], (len(t), 1))]
    dirs = [gaze_h - o + rng.normal(scale=np.linalg.norm(gaze_h - o, axis=1, keepdims=True) * np.deg2rad(1.0),
                                    size=o.shape) for o in eyes]
    rays = BinocularSamples.from_arrays(t, eyes[0], dirs[0], eyes[1], dirs[1], frame="head")
    return SimulatedRecording(t, rays, T, gaze_h, None, None, np.zeros(0), None, (0, 0), rate_hz, 0.0)


def timed_import(src: Path, out: Path) -> tuple[float, float, dict]:
    """(seconds, peak traced MB, report counts) of importing ``src`` into ``out``."""
    dt, peak, imp = traced_import(aria, src, out)
    return dt, peak / 1e6, {"kept": imp.n_rays, "poses read": imp.read["trajectory rows"]}


def main():
    args = size_and_seed(__doc__, "--minutes", float, 60.0, 5, "length of the long synthetic recording, minutes")
    rng = np.random.default_rng(args.seed)
    print("Aria MPS import, one core (time; peak memory traced by tracemalloc during the import only)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if REAL.is_dir():
            dt, peak, n = timed_import(REAL, tmp / "real")
            print(f"  real gen1 sample (123 gaze rows, 11,517 poses, 3.6 MB): {dt:6.2f} s, peak {peak:6.1f} MB, {n}")
        else:
            print(f"  real sample not found at {REAL}: skipped")
        for minutes in sorted({1.0, args.minutes}):
            src = tmp / f"mps{minutes:g}"
            t0 = time.perf_counter()
            aria.write_recording(walk(minutes, rng), src)
            wrote = time.perf_counter() - t0
            size = sum(p.stat().st_size for p in src.rglob("*.csv")) / 1e6
            dt, peak, n = timed_import(src, tmp / f"s{minutes:g}")
            print(f"  synthetic {minutes:4g} min ({size:7.1f} MB of CSV, written in {wrote:6.1f} s): import "
                  f"{dt:6.1f} s = {minutes * 60 / dt:5.0f}x real time, peak {peak:6.1f} MB, {n}")


if __name__ == "__main__":
    main()
