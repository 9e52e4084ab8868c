"""Pupil Neon import: time and peak Python memory (tracemalloc) importing the real demo recording
(if present) and synthetic Neon native recordings of 1 minute and N minutes (default 60) at 200 Hz
(12,000 eye states a minute, 720,000 an hour: eye_state 58 MB, gaze 5.8 MB), written by the
module's writer from a generated session: fixations of 0.2-0.8 s on targets 0.4-3 m away, a
kappa of (5, 1) / (-5, 1) deg planted, 1 % of the eyes closed. Method (b) (Neon's 2D gaze) fits
the kappa, as on a recording without targets.

    python benchmarks/bench_import_neon.py [--minutes 60]

The import memory-maps the large streams (eye_state, gaze, worn and their .time files) and reads
them in chunks of ``neon.CHUNK`` records; the kappa fit uses at most ``neon.MAX_FIT_SAMPLES``
samples. So the peak should not grow with the length: the last line prints the ratio of the two
peaks. (Pupil Labs' reader, which loads each stream whole, gave 16.6 MiB for 1 minute and 192 MiB
for 60 minutes.)
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import cv2
import numpy as np
from _args import size_and_seed

from calibration.camera import CameraCalibration
from calibration.kappa import apply_kappa
from estimator.lines import BinocularSamples
from wearable_gaze.formats.devices import neon
from wearable_gaze.formats.devices.common import ImportOptions, SessionImport, SimulatedRecording

RATE_HZ = 200.0
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "pupil_labs_neon_demo_recording"
K = np.array([[888.4, 0.0, 805.1], [0.0, 888.4, 618.6], [0.0, 0.0, 1.0]])


def tiny_video(path: Path, n: int = 10) -> np.ndarray:
    """A 10-frame grey 160x120 mp4 (the importer copies the scene video; its length does not matter)."""
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (160, 120))
    for _ in range(n):
        w.write(np.full((120, 160, 3), 128, np.uint8))
    w.release()
    return np.arange(n) / 30.0


def generated(root: Path, minutes: float, seed: int) -> SimulatedRecording:
    """A still-head session of ``minutes`` at 200 Hz (visual axes toward the fixated targets)."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    n_fix = int(minutes * 60 / 0.2) + 2
    starts = np.cumsum(rng.uniform(0.2, 0.8, n_fix))
    targets = np.column_stack([rng.uniform(-0.5, 0.5, (n_fix, 2)) * rng.uniform(400, 3000, (n_fix, 1)),
                               rng.uniform(400, 3000, n_fix)])
    gaze = targets[np.searchsorted(starts, t)]
    arrays, valid = [], []
    for x in (-31.5, 31.5):
        c = np.array([x, 14.0, -36.0]) + rng.normal(0, 0.2, (n, 3))
        d = gaze - c
        d = apply_kappa(d / np.linalg.norm(d, axis=1, keepdims=True), rng.normal(0, 0.5, 2))
        arrays += [c, d]
        valid.append(rng.random(n) > 0.01)
    rays = BinocularSamples.from_arrays(t, arrays[0], arrays[1], arrays[2], arrays[3], valid[0], valid[1],
                                        frame="head")
    video = root / f"video{minutes:g}.mp4"
    ft = tiny_video(video)
    cam = CameraCalibration(K, np.array([-0.13, 0.11, 0.0, 0.0, 0.0]), (1600, 1200))
    return SimulatedRecording(t, rays, np.tile(np.eye(4), (1, 1, 1)), gaze, cam, video, ft, None, (1600, 1200),
                              RATE_HZ, 30.0)


def measure(src: Path, out: Path) -> tuple[float, float, int, dict]:
    """(peak traced MiB, seconds, eye samples written, drops) of importing ``src``: timed in one
    run, memory traced in a second (tracemalloc slows the allocations it traces)."""
    result = []
    for traced in (False, True):
        if traced:
            tracemalloc.start()
        t0 = time.perf_counter()
        with SessionImport(out / str(traced), "pupil-neon", src) as imp:
            neon.read_recording(src, imp, ImportOptions())
        result.append(time.perf_counter() - t0)
        if traced:
            result.append(tracemalloc.get_traced_memory()[1] / 2**20)
            tracemalloc.stop()
    return result[2], result[0], imp.n_rays, dict(imp.dropped)


RSS_SCRIPT = """
import sys
from pathlib import Path
import cv2, pupil_labs.neon_recording.utils
from wearable_gaze.formats.devices import neon
from wearable_gaze.formats.devices.common import ImportOptions, SessionImport
def hwm():   # this process's peak resident set, kB (ru_maxrss would carry the parent's over fork and exec)
    return next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM:"))
before = hwm()
with SessionImport(Path(sys.argv[2]), "pupil-neon", Path(sys.argv[1])) as imp:
    neon.read_recording(Path(sys.argv[1]), imp, ImportOptions())
print((hwm() - before) / 1024)
"""


def rss_growth(src: Path, out: Path) -> float:
    """MiB the peak resident set (VmHWM, Linux) grows by over one import in a fresh process (it
    also counts the memory-mapped file pages, which tracemalloc does not see); NaN elsewhere."""
    if not Path("/proc/self/status").is_file():
        return float("nan")
    res = subprocess.run([sys.executable, "-c", RSS_SCRIPT, str(src), str(out)], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).parent)
    return float(res.stdout.split()[-1])


def main():
    args = size_and_seed(__doc__, "--minutes", float, 60.0, 0, "minutes of the long recording")
    print(f"Pupil Neon native import, {RATE_HZ:g} Hz, tracemalloc peak (Python allocations incl. numpy)")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if REAL.is_dir():
            peak, dt, n, dropped = measure(REAL, root / "real")
            print(f"  real demo recording (8.96 s): {n:8d} eye samples kept, peak {peak:6.2f} MiB, {dt:6.2f} s")
        peaks = []
        for m in (1.0, args.minutes):
            sim = generated(root, m, args.seed)
            rec = root / f"neon{m:g}"
            neon.write_recording(sim, rec, kappa_deg={"left": (5.0, 1.0), "right": (-5.0, 1.0)}, targets=False)
            del sim
            peak, dt, n, dropped = measure(rec, root / f"out{m:g}")
            size = sum(p.stat().st_size for p in rec.iterdir()) / 2**20
            print(f"  {m:5g} min ({size:6.1f} MB on disk): {n:8d} eye samples kept, peak {peak:7.2f} MiB "
                  f"({peak * 2**20 / max(n, 1):5.0f} B/sample), {dt:6.1f} s ({n / dt / 1e3:5.0f} k samples/s), "
                  f"dropped {sum(dropped.values())}")
            peaks.append(peak)
            print(f"        peak resident set grows by {rss_growth(rec, root / f'rss{m:g}'):6.1f} MiB over the import "
                  "(a fresh process; includes memory-mapped pages)")
        print(f"  peak at {args.minutes:g} min / peak at 1 min: {peaks[1] / peaks[0]:.2f} (flat memory: close to 1)")


if __name__ == "__main__":
    main()
