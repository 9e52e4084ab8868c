"""Estimator speed, on one core, against a naive full-grid numpy update measured in the same run.

    python benchmarks/bench_estimator.py [--samples 4000] [--depth 2000] [--tufts PATH]

Targets (issue 2): voxel >= 2,000 binocular samples/s; ML on 400 lines < 20 ms; speed-up of the
voxel update over the naive full-grid update >= 20x.

Issue 12: lines that never fix a point must not make the voxel update grow with the stream. The
per-update cost at samples 100, 650 and 2000 of a still head looking at 5 m with the eyes
diverging by 1 degree (median of the 20 updates before each), and the total over 1,036 real
samples (Tufts Gaze Depth, the first 1,036 rows in file order, each a binocular sample in the
tracker's frame), are printed against a baseline measured in the same run: the same estimator
on a fixation at 2 m whose lines do fix the point (paper protocol), at the same sample counts.

The naive baseline is what one writes first: one fixed, axis-aligned cube of 64^3 voxels around
the seed (voxel = 1/8 of the final depth std, so the cube spans +-4 std in depth), and for every
sample the angle of each voxel to each of its two lines computed directly (difference vectors,
norms, arccos) and the Gaussian log-cone added. Its accuracy on the same data is printed too:
the speed-up is not bought with precision.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np

from estimator import (
    BinocularSample,
    BinocularSamples,
    MLConfig,
    PaperVoxelEstimator,
    VoxelEstimator,
    cramer_rao_bound,
    ml_point,
)
from estimator._open3d import import_open3d
from wearable_gaze.sim.protocol import Protocol, simulate_lines, still_head_samples


class NaiveGrid:
    """The baseline: a dense fixed cube, every voxel updated per sample with direct maths."""

    def __init__(self, center, voxel_mm, n=64, sigma_deg=1.0):
        ax = (np.arange(n) - (n - 1) / 2) * voxel_mm
        g = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
        self.pts = g + center
        self.logp = np.zeros(len(self.pts))
        self.k = -0.5 / np.deg2rad(sigma_deg) ** 2

    def update(self, o, d):
        for e, u in zip(o, d, strict=True):
            v = self.pts - e
            cos = (v @ u) / np.linalg.norm(v, axis=1)
            ang = np.arccos(np.clip(cos, -1, 1))
            self.logp += self.k * ang**2
        return self.pts[np.argmax(self.logp)]


def streamed(samples: BinocularSamples):
    return [samples.sample(i) for i in range(len(samples))]


def bench_stream(make, stream, repeat=1):
    best = np.inf
    for _ in range(repeat):
        est = make()
        t0 = time.perf_counter()
        for s in stream:
            r = est.update(s)
        best = min(best, time.perf_counter() - t0)
    return best, r


def tufts_stream(path, n=1036):
    """The first ``n`` rows of the Tufts Gaze Depth test split as binocular samples (eye centres,
    mm, and gaze normals, in the tracker's world-camera frame), or None if the file is absent."""
    if not path.exists():
        return None
    a = np.loadtxt(path, delimiter=",", skiprows=1)[:n]
    return [BinocularSample(i / 120, r[1:4], r[4:7], r[7:10], r[10:13]) for i, r in enumerate(a)]


def update_times(stream):
    """Seconds taken by each ``update`` of a new VoxelEstimator over the stream, and the estimator."""
    est = VoxelEstimator()
    out = np.empty(len(stream))
    for i, s in enumerate(stream):
        t0 = time.perf_counter()
        est.update(s)
        out[i] = time.perf_counter() - t0
    return out, est


def bench_lines_that_fix_no_point(tufts_path):
    at, win = (100, 650, 2000), 20
    regular = streamed(simulate_lines(np.array([0.0, 0, 2000]), np.random.default_rng(2),
                                      Protocol(n_samples=max(at), step_mm=200.0 / max(at))))
    t_reg, _ = update_times(regular)
    t_div, est = update_times(still_head_samples(max(at), np.random.default_rng(3)))
    print("\nvoxel per-update cost (median of the 20 updates before each count), lines that fix no point:")
    print(f"  {'sample':>6}  {'diverging 1 deg, 5 m':>21}  {'baseline: fixation at 2 m':>26}  {'ratio':>6}")
    for k in at:
        d, r = np.median(t_div[k - win:k]) * 1e3, np.median(t_reg[k - win:k]) * 1e3
        print(f"  {k:>6}  {d:>18.3f} ms  {r:>23.3f} ms  {d / r:>6.2f}")
    growth = np.median(t_div[max(at) - win:max(at)]) / np.median(t_div[at[0] - win:at[0]])
    print(f"  diverging, cost at {max(at)} / cost at {at[0]}: x{growth:.2f}; worst single update "
          f"{t_div.max() * 1e3:.1f} ms; work over the kept lines {getattr(est, 'work', 'n/a')}")
    tufts = tufts_stream(tufts_path)
    if tufts is None:
        print(f"\nTufts: {tufts_path} not found (set --tufts): skipped")
        return
    t_tufts, est = update_times(tufts)
    base = t_reg[:len(tufts)].sum()
    print(f"\nTufts Gaze Depth, {len(tufts)} real samples: total {t_tufts.sum():.2f} s "
          f"(baseline, {len(tufts)} samples of the fixation at 2 m: {base:.2f} s; ratio {t_tufts.sum() / base:.1f}); "
          f"worst single update {t_tufts.max() * 1e3:.1f} ms; last status {est.estimate().status.value}; "
          f"{getattr(est, 'work', 'n/a')}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=4000)
    ap.add_argument("--depth", type=float, default=2000.0)
    ap.add_argument("--tufts", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
                    / "tufts_gaze_depth" / "test.csv")
    ap.add_argument("--only-no-point", action="store_true", help="run only the issue 12 part")
    args = ap.parse_args()
    import_open3d()
    if args.only_no_point:
        bench_lines_that_fix_no_point(args.tufts)
        return
    rng = np.random.default_rng(0)
    X = np.array([0.0, 0.0, args.depth])
    prot = Protocol(n_samples=args.samples, step_mm=200.0 / args.samples)
    samples = simulate_lines(X, rng, prot)
    stream = streamed(samples)
    crb = cramer_rao_bound(samples.lines().origins_mm, X, 1.0)
    std_z = np.sqrt(crb[2, 2])
    print(f"one core; {args.samples} binocular samples, target at {args.depth:.0f} mm, head moving 200 mm; "
          f"CRB sqrt(trace) {np.sqrt(np.trace(crb)):.2f} mm")

    # baseline: naive full-grid update, timed on a slice of the stream (it is slow)
    n_naive = min(200, len(stream))
    naive = NaiveGrid(X + [0, 0, 0], voxel_mm=std_z / 8)
    t0 = time.perf_counter()
    for s in stream[:n_naive]:
        p_naive = naive.update(np.vstack([s.left_origin_mm, s.right_origin_mm]),
                               np.vstack([s.left_direction, s.right_direction]))
    t_naive = (time.perf_counter() - t0) / n_naive
    naive_rate = 1.0 / t_naive
    print(f"\nbaseline  naive full-grid update (64^3 voxels): {naive_rate:9.1f} samples/s "
          f"({t_naive * 1e3:.2f} ms per sample)")

    t_vox, r_vox = bench_stream(VoxelEstimator, stream, repeat=2)
    vox_rate = len(stream) / t_vox
    print(f"voxel     Bayesian grid (12^3 adaptive)       : {vox_rate:9.1f} samples/s   "
          f"x{vox_rate / naive_rate:6.1f} vs baseline   target >= 2000/s: {'PASS' if vox_rate >= 2000 else 'FAIL'}")
    print(f"          error {np.linalg.norm(r_vox.position_mm - X):.2f} mm after {len(stream)} samples "
          f"(ML: {np.linalg.norm(ml_point(samples.lines()).position_mm - X):.2f} mm); "
          f"relayouts {r_vox.info['relayouts']}")

    n_paper = min(1000, len(stream))
    t_pap, _ = bench_stream(PaperVoxelEstimator, stream[:n_paper])
    pap_rate = n_paper / t_pap
    print(f"paper     stochastic voxel (32^3, 10 mm)      : {pap_rate:9.1f} samples/s   "
          f"x{pap_rate / naive_rate:6.1f} vs baseline")

    # ML on 400 lines (the paper's protocol) vs the naive full-grid maximum of the same likelihood
    s400 = simulate_lines(X, np.random.default_rng(1))
    lines = s400.lines()
    ml_point(lines)
    times = []
    for _ in range(20):
        t0 = time.perf_counter()
        r_ml = ml_point(lines, MLConfig())
        times.append(time.perf_counter() - t0)
    t_ml = float(np.median(times))
    crb400 = cramer_rao_bound(lines.origins_mm, X, 1.0)
    grid = NaiveGrid(X, voxel_mm=np.sqrt(crb400[2, 2]) / 8)
    t0 = time.perf_counter()
    p_grid = grid.update(lines.origins_mm, lines.directions)
    t_grid = time.perf_counter() - t0
    print(f"\nML        400 lines: {t_ml * 1e3:7.2f} ms ({r_ml.info['iterations']} iterations)   target < 20 ms: "
          f"{'PASS' if t_ml < 0.02 else 'FAIL'}")
    print(f"baseline  naive full-grid maximum of the same likelihood (64^3): {t_grid * 1e3:7.1f} ms   "
          f"ML x{t_grid / t_ml:6.1f} faster; grid error {np.linalg.norm(p_grid - X):.1f} mm vs ML "
          f"{np.linalg.norm(r_ml.position_mm - X):.1f} mm")
    print(f"\nspeed-up of the voxel update over the naive full-grid update: x{vox_rate / naive_rate:.1f} "
          f"(aim >= 20x): {'PASS' if vox_rate / naive_rate >= 20 else 'FAIL'}")
    _ = p_naive
    bench_lines_that_fix_no_point(args.tufts)


if __name__ == "__main__":
    main()
