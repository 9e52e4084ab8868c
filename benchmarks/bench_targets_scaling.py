"""The targets step's time against the session's length (issue 27), and the whole ``process`` of a
long session against real time, on one core: simulated lab-walkabout sessions (four targets
revisited in turn, a swaying head, 640x360 video at 30 fps, 60 Hz eye data) of 1, 5 and 20
minutes, each processed without the report.

    python benchmarks/bench_targets_scaling.py [--minutes 1,5,20] [--keep DIR] [--repeat-from M]

``--keep DIR`` simulates each session into DIR once and reuses it on the next run (a 20-minute
session takes about as long to simulate as to process). ``--repeat-from M`` makes each session
longer than M minutes from the M-minute one played back to back (its video copied frame by frame,
its eye samples and frame times shifted; the same room, targets and calibration; the head jumps
back to its start at each seam): no rendering, and the targets are revisited all session long.
Targets (issue 27): the targets step's seconds per minute of session within 1.5x of each other;
the longest session processed at 4x real time or faster (its whole ``process``: tracking, view
lines, targets, exports).

Times are CPU seconds of the one pinned core (``time.process_time``: the steps' own timings are
taken with it here), which a machine shared with other work does not inflate as it does the
wall-clock times (printed beside them).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)

from wearable_gaze.pipeline.process import stepcache as steps
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.sim.simulate import simulate_scenario

RESOLUTION = [640, 360]


class _CpuClock:
    """Stands in for the ``time`` module in ``wearable_gaze.pipeline.process.stepcache``: its step timings in
    CPU seconds."""

    perf_counter = staticmethod(time.process_time)


def session(folder: Path, minutes: float, seed: int) -> tuple[Path, float]:
    """The simulated session of ``minutes`` in ``folder`` (made unless there), and the seconds it
    took to simulate (0 when reused)."""
    root = folder / f"lab-walkabout-{minutes:g}min-{RESOLUTION[0]}x{RESOLUTION[1]}-seed{seed}"
    if root.exists():
        return root, 0.0
    t0 = time.perf_counter()
    simulate_scenario({"base": "lab-walkabout", "duration_s": 60.0 * minutes, "camera": {"resolution": RESOLUTION}},
                      root, seed)
    return root, time.perf_counter() - t0


def repeated(src: Path, dst: Path, times: int) -> Path:
    """The session ``src`` played ``times`` times back to back, written to ``dst``: eye.csv and
    scene_timestamps.csv shifted by the session's duration per repeat (the recorder's counter
    carried on), scene.mp4 copied frame by frame; its calibration and marker map as they are; no
    truth (the head jumps at each seam)."""
    import cv2

    manifest = json.loads((src / "session.json").read_text())
    duration = float(manifest["scenario"]["duration_s"])
    tmp = dst.with_name(dst.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    shutil.copytree(src / "calibration", tmp / "calibration")
    shutil.copy(src / "markers.json", tmp / "markers.json")
    for name, shift in (("eye.csv", ("t", "counter")), ("scene_timestamps.csv", ("t", "frame"))):
        rows = list(csv.DictReader((src / name).open()))
        step = {"t": duration, "counter": len(rows), "frame": len(rows)}
        with (tmp / name).open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            for k in range(times):
                for r in rows:
                    out = dict(r)
                    for col in shift:
                        out[col] = (f"{float(r[col]) + k * step[col]:.6f}" if col == "t"
                                    else str(int(r[col]) + k * step[col]))
                    w.writerow(out)
    cap = cv2.VideoCapture(str(src / "scene.mp4"))
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    writer = cv2.VideoWriter(str(tmp / "scene.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), float(manifest["fps"]), size)
    for _ in range(times):
        cap = cv2.VideoCapture(str(src / "scene.mp4"))
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            writer.write(frame)
        cap.release()
    writer.release()
    files = {k: v for k, v in manifest["files"].items() if not k.startswith("truth") and k != "eye_serial"}
    manifest.update(files=files, n_frames=manifest["n_frames"] * times, n_eye_samples=manifest["n_eye_samples"] * times)
    manifest["scenario"]["duration_s"] = duration * times
    (tmp / "session.json").write_text(json.dumps(manifest, indent=1))
    tmp.rename(dst)
    return dst


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", default="1,5,20", help="session lengths, minutes (default 1,5,20)")
    ap.add_argument("--seed", type=int, default=11, help="random seed (default 11)")
    ap.add_argument("--keep", type=Path, default=None, help="simulate the sessions into this folder once, reuse them")
    ap.add_argument("--repeat-from", type=float, default=None, metavar="M",
                    help="make each session longer than M minutes from the M-minute one played back to back")
    args = ap.parse_args()
    minutes = [float(m) for m in args.minutes.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        rows = []
        for m in minutes:
            if args.repeat_from and m > args.repeat_from and (m / args.repeat_from).is_integer():
                src, _ = session(folder, args.repeat_from, args.seed)
                root, sim_s = src.with_name(f"{src.name}-x{int(m / args.repeat_from)}"), 0.0
                if not root.exists():
                    repeated(src, root, int(m / args.repeat_from))
            else:
                root, sim_s = session(folder, m, args.seed)
            steps.time = _CpuClock                     # the steps' timings in CPU seconds
            t0, w0 = time.process_time(), time.perf_counter()
            r = process_session(root, Path(tmp) / f"out-{m:g}", report=False, overlay=False)
            total, wall = time.process_time() - t0, time.perf_counter() - w0
            steps.time = time
            rows.append((m, sim_s, total, wall, r.timings, len(r.targets)))
    print(f"process on one core, simulated lab-walkabout sessions ({RESOLUTION[0]}x{RESOLUTION[1]} at 30 fps, "
          f"60 Hz eye data, seed {args.seed}), no report; CPU seconds of the one core")
    for m, sim_s, total, wall, tm, n in rows:
        print(f"  {m:5.1f} min: targets step {tm['targets']:7.1f} s CPU = {tm['targets'] / m:5.2f} s per minute; "
              f"tracking {tm['tracking']:6.1f} s; whole process {total:7.1f} s CPU = {60 * m / total:5.2f}x real time "
              f"(wall {wall:.0f} s); {n} targets{f'; simulated in {sim_s:.0f} s' if sim_s else ''}")
    per_min = [tm["targets"] / m for m, _, _, _, tm, _ in rows]
    spread = max(per_min) / min(per_min)
    m, _, total, _, _, _ = rows[-1]
    rate = 60 * m / total
    print(f"  targets step, seconds per minute: largest / smallest {spread:.2f} (target <= 1.5: "
          f"{'PASS' if spread <= 1.5 else 'FAIL'}); {m:g}-minute session at {rate:.2f}x real time (target >= 4: "
          f"{'PASS' if rate >= 4 else 'FAIL'})")


if __name__ == "__main__":
    main()
