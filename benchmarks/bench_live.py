"""Live session on one core: end-to-end latency from an eye sample's arrival to its published
estimate, at 30 fps 1280x720 video and 60 Hz eye data, and memory over a long stream.

A simulated lab-walkabout session plays the hardware: its serial byte stream is served over TCP
at its own pace (looped, counters and clock running on), and its scene video is the camera
(looped at its own frame rate). With --record the session is also recorded, as a user would;
the video encoding then shares the core.

    python benchmarks/bench_live.py [--minutes 2] [--record]

Targets (issue 7): p95 latency <= 50 ms; memory flat over the run (one hour: --minutes 60);
no sample that arrived intact is lost.
"""

from __future__ import annotations

import argparse  # noqa: E402
import ctypes  # noqa: E402
import io  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np  # noqa: E402

from wearable_gaze.live.app import LiveSession  # noqa: E402
from wearable_gaze.process import process_session  # noqa: E402
from wearable_gaze.session import load_session, read_eye_csv  # noqa: E402
from wearable_gaze.sim.emulate import RecorderEmulator  # noqa: E402
from wearable_gaze.sim.simulate import simulate_scenario  # noqa: E402


class _MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                 "fsmblks", "uordblks", "fordblks", "keepcost")]


def malloc_in_use_mb() -> float:
    """Bytes the C allocator has handed out and not had back (glibc ``mallinfo2``), MB; NaN
    elsewhere. RSS minus this is the allocator's free-but-kept memory."""
    try:
        f = ctypes.CDLL(None).mallinfo2
    except (OSError, AttributeError):
        return float("nan")
    f.restype = _MallInfo2
    mi = f()
    return (mi.uordblks + mi.hblkhd) / 2 ** 20


def rss_mb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--record", action="store_true", help="also record the session (video encoding shares the core)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "s"
        simulate_scenario({"base": "lab-walkabout", "duration_s": 20.0}, root, args.seed)
        cal = Path(tmp) / "cal"
        process_session(root, cal, report=False)
        emu = RecorderEmulator((root / "eye_serial.bin").read_bytes(), loop=True, duration_s=args.minutes * 60)
        url = emu.listen_tcp()
        live = LiveSession(url, str(root / "scene.mp4"), cal / "camera.json",
                           cal / "eyes.json", root / "markers.json", record=Path(tmp) / "rec" if args.record else None, stdout=False,
                           stream=io.StringIO())
        live.frames.loop = True
        mem = []
        stop = threading.Event()

        frame_mb = live.frames.size[0] * live.frames.size[1] / 2 ** 20       # a grey frame
        queues = []

        def sample_memory():
            while not stop.is_set():
                # what the bounded queues hold at this moment: frames waiting for the video encoder
                # and for tracking (grey and colour), eye records waiting for the loop, samples waiting for a pose
                vq = live.recorder.video_q.qsize() if live.recorder else 0
                cq, rq, pend = live.frames.queue.qsize(), live.reader.queue.qsize(), len(live.pending)
                queues.append((vq, cq, rq, pend, len(live.targets)))
                mem.append((time.monotonic(), rss_mb(), rss_mb() - (vq + 4 * cq) * frame_mb, malloc_in_use_mb()))
                time.sleep(5.0)
        threading.Thread(target=sample_memory, daemon=True).start()
        st = live.run(duration_s=args.minutes * 60 + 1.0)
        stop.set()
        n_rec = len(read_eye_csv(Path(tmp) / "rec" / "eye.csv")[0]) if args.record else live.stats.samples
        n_frames_rec = len(load_session(Path(tmp) / "rec").frame_times()) if args.record else None
        lat = np.array(st.latencies_ms)
        m = np.array(mem)
        half = len(m) // 2
        print(f"live session, {_onecore.CORES} core(s), {args.minutes:g} min of 30 fps 1280x720 video and 60 Hz eye data"
              f"{', recorded' if args.record else ''}")
        h = st.latency_all
        print(f"  latency arrival -> published estimate, whole run ({h.n} estimates): median {h.percentile(50):.1f} ms, "
              f"p95 {h.percentile(95):.1f} ms, p99 {h.percentile(99):.1f} ms, max {h.percentile(100):.1f} ms")
        print(f"  last {len(lat)} estimates: median {np.median(lat):.1f} ms, p95 {np.percentile(lat, 95):.1f} ms")
        print(f"  eye samples sent {emu.sent}, received intact {live.reader.stats.records}, {'recorded' if args.record else 'processed'} {n_rec}, "
              f"corrupt {live.reader.stats.corrupt}, dropped by the reader {live.reader.stats.dropped}")
        print(f"  frames {live.frames.stats.frames}, dropped by a full camera queue {live.frames.stats.dropped}, "
              f"skipped by tracking for a newer one {st.frames_skipped}"
              + (f", recorded {n_frames_rec}" if args.record else ""))
        if len(m) >= 4:
            print(f"  memory (RSS): first half mean {m[:half, 1].mean():.0f} MB, second half {m[half:, 1].mean():.0f} MB, "
                  f"max {m[:, 1].max():.0f} MB")
            tm = (m[:, 0] - m[0, 0]) / 60.0
            late = tm >= min(5.0, tm[-1] / 2)           # past the warm-up (caches, allocator pools)
            slope = np.polyfit(tm[late], m[late, 1], 1)[0] * 60.0 if late.sum() >= 3 else float("nan")
            edges = np.linspace(0.0, tm[-1] + 1e-9, 7)
            slices = [f"{m[(tm >= a) & (tm < b), 1].mean():.0f}" for a, b in zip(edges[:-1], edges[1:], strict=True)
                      if ((tm >= a) & (tm < b)).any()]
            print(f"  memory by sixths of the run: {' / '.join(slices)} MB; trend after warm-up {slope:+.1f} MB/hour")
            slices = [f"{m[(tm >= a) & (tm < b), 2].mean():.0f}" for a, b in zip(edges[:-1], edges[1:], strict=True)
                      if ((tm >= a) & (tm < b)).any()]
            slope = np.polyfit(tm[late], m[late, 2], 1)[0] * 60.0 if late.sum() >= 3 else float("nan")
            q = np.array(queues)
            print(f"  less the frames queued at that moment: {' / '.join(slices)} MB; trend {slope:+.1f} MB/hour")
            slices = [f"{m[(tm >= a) & (tm < b), 3].mean():.0f}" for a, b in zip(edges[:-1], edges[1:], strict=True)
                      if ((tm >= a) & (tm < b)).any()]
            print(f"  C allocator in use (malloc, queued frames included): {' / '.join(slices)} MB")
            print(f"  queues, most seen: video encoder {q[:, 0].max()} frames (bound "
                  f"{live.recorder.video_q.maxsize if live.recorder else 0}), tracking {q[:, 1].max()}, eye records "
                  f"{q[:, 2].max()}, samples waiting for a pose {q[:, 3].max()}; target ids {q[-1, 4]}")
        ok = (h.percentile(95) <= 50 and n_rec == live.reader.stats.records
              and (not args.record or n_frames_rec == live.frames.stats.frames))
        print(f"  target p95 <= 50 ms and nothing intact lost: {'PASS' if ok else 'FAIL'}")


if __name__ == "__main__":
    main()
