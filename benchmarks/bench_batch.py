"""Batch speed-up and worker memory: ``run_batch`` over simulated sessions (lab-walkabout, 6 s,
640x360, the ``process`` defaults: plots, overlay, report) with one local worker and then with
two, each from an empty output folder, in the same run; the wall-time ratio, and the memory of
the workers: each local session's fresh worker's peak, and, on a local Dask cluster of two
long-lived workers (if Dask is installed), each worker's resident memory after each of its
sessions, which should stay flat.

    python benchmarks/bench_batch.py [--sessions 8] [--seed 3]

Target (issue 18): 8 sessions, 2 workers >= 1.7x faster than 1 worker on a 2-core machine; each
worker's memory flat across its sessions. A machine shared with other work gives lower ratios:
the load average is printed before and after.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from _args import size_and_seed

from wearable_gaze.pipeline.batch.run import BatchSettings, run_batch
from wearable_gaze.sim.simulate import simulate_scenario

SCENARIO = {"base": "lab-walkabout", "duration_s": 6.0, "camera": {"resolution": [640, 360]},
            "targets": {"random_count": 2, "random_depth_mm": [700.0, 3000.0]}, "calibration": {"camera_views": 6}}


def _load() -> str:
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg()) + " (1, 5, 15 min)"


def _batch(root: Path, out: Path, workers: int, scheduler=None):
    t0 = time.perf_counter()
    res = run_batch([root], out, BatchSettings(), workers=workers, scheduler=scheduler)
    wall = time.perf_counter() - t0
    assert not res.failed and len(res.done) == len(res.statuses), res.failed
    return wall, res


def _memory_lines(res) -> list[str]:
    """Per worker process: resident memory after each of its sessions (in the order they ended)
    and its peak, MB."""
    per = defaultdict(list)
    for st in sorted(res.statuses.values(), key=lambda s: s["finished"]):
        per[st["worker"]].append(st)
    if all(len(v) == 1 for v in per.values()):
        peaks = [v[0]["peak_rss_mb"] for v in per.values()]
        return [f"    one fresh worker process per session: peak resident {min(peaks):.0f}-{max(peaks):.0f} MB, in "
                "session order " + ", ".join(f"{p:.0f}" for p in peaks)]
    lines = []
    for w, sts in per.items():
        rss = [s["rss_mb"] for s in sts]
        lines.append(f"    worker {w}: {len(sts)} session(s), resident after each " + ", ".join(f"{r:.0f}" for r in rss)
                     + f" MB (growth {rss[-1] - rss[0]:+.0f} MB), peak {max(s['peak_rss_mb'] for s in sts):.0f} MB")
    return lines


def _dask(root: Path, out: Path):
    """The same on a local Dask cluster of two long-lived single-threaded workers, if Dask is
    installed: (wall s, result) or None."""
    try:
        from distributed import LocalCluster
    except ImportError:
        return None
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        return _batch(root, out, 0, cluster.scheduler_address)


def main():
    args = size_and_seed(__doc__, "--sessions", int, 8, 3, "simulated sessions")
    print(f"batch benchmark, {args.sessions} sessions, {os.cpu_count()} cores; before: {_load()}")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "study"
        t0 = time.perf_counter()
        for i in range(args.sessions):
            simulate_scenario(SCENARIO, root / f"s{i:02d}", seed=args.seed + i)
        print(f"  simulated in {time.perf_counter() - t0:.0f} s")
        rows = {}
        for workers in (1, 2):
            wall, res = _batch(root, Path(tmp) / f"out{workers}", workers)
            per = [s["duration_s"] for s in res.statuses.values()]
            rows[workers] = wall
            print(f"  {workers} worker(s): {wall:6.1f} s wall, {wall / args.sessions:5.1f} s a session; each "
                  f"session's processing {min(per):.1f}-{max(per):.1f} s")
            print("\n".join(_memory_lines(res)))
        dask = _dask(root, Path(tmp) / "outdask")
        if dask is not None:
            print(f"  Dask LocalCluster, 2 long-lived workers: {dask[0]:6.1f} s wall ({rows[1] / dask[0]:.2f}x against "
                  "1 local worker)")
            print("\n".join(_memory_lines(dask[1])))
    ratio = rows[1] / rows[2]
    print(f"  speed-up with 2 workers: {ratio:.2f}x; target >= 1.7x: {'PASS' if ratio >= 1.7 else 'FAIL'}")
    print(f"  after: {_load()}")


if __name__ == "__main__":
    main()
