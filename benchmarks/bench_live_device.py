"""``bench_live.py --device pupil-core|neon``: issue 29's figures for Pupil Core or Neon on loopback.

The emulator (``wearable-gaze emulate --as pupil-core|neon``) runs in a process of its own, on the
other core when there is one; the live session runs in this process on one core, recorded.

- latency from the device's sample time to the published estimate, p50 / p95 (target p95 <= 25
  ms), with the machine's load (``os.getloadavg``) before and after, and the CPU-time figures
  that do not depend on it: the loop thread's CPU time per published estimate, and this
  process's CPU time over the run;
- intact samples missing from the recording (every stream sample from the first received on);
- the same with a TCP subscriber that never reads (``--subscriber stalled``; ``both``: one run
  without a subscriber, then one with the stalled one);
- ``process`` on the recording: each live target's distance to the nearest offline one (target
  within 1 mm);
- ``--reconnect``: the emulator killed (SIGKILL) a third into the run and started again on the
  same port: the time from the device answering again to the first sample recorded after, and
  the samples missing from the recording before and after.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import _onecore
import numpy as np
import zmq

from wearable_gaze.formats.eye_rays import read_eye_rays
from wearable_gaze.live.device_app import open_device_session
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.sim.pupil_core_emu import device_stream


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def load() -> str:
    """The machine's load averages (1, 5, 15 min), as ``uptime`` says them."""
    return "load " + " ".join(f"{x:.2f}" for x in os.getloadavg())


DESCRIBED = {"pupil-core": "BGR frames at 30 fps and 200 Hz binocular gaze",
             "neon": "H.264 frames at 30 fps and 200 Hz gaze with eye states"}


def start_emulator(root: Path, port: int, device: str) -> subprocess.Popen:
    """``emulate ROOT --as DEVICE --listen 127.0.0.1:PORT`` on the cores this process does
    not use (all when it uses them all); returns once it answers (Pupil Remote's ``t``, the
    Companion API's status)."""
    others = sorted(set(range(os.cpu_count() or 1)) - os.sched_getaffinity(0)) or sorted(os.sched_getaffinity(0))
    emu = subprocess.Popen([sys.executable, "-m", "wearable_gaze", "emulate", str(root), "--as", device,
                            "--listen", f"127.0.0.1:{port}"], stderr=subprocess.DEVNULL,
                           preexec_fn=lambda: os.sched_setaffinity(0, set(others)))
    if not (wait_answering if device == "pupil-core" else wait_http)(port, 30.0):
        emu.kill()
        raise RuntimeError("the emulator did not start")
    return emu


def wait_answering(port: int, timeout_s: float) -> bool:
    """Wait until Pupil Remote on ``port`` answers a ``t`` request; False after ``timeout_s``."""
    ctx = zmq.Context()
    end = time.monotonic() + timeout_s
    try:
        while time.monotonic() < end:
            req = ctx.socket(zmq.REQ)
            req.setsockopt(zmq.LINGER, 0)
            req.connect(f"tcp://127.0.0.1:{port}")
            req.send(b"t")
            ok = req.poll(50)
            req.close()
            if ok:
                return True
        return False
    finally:
        ctx.destroy(linger=0)


def wait_http(port: int, timeout_s: float) -> bool:
    """Wait until the Companion API's ``/api/status`` on ``port`` answers; False after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status", timeout=1.0):
                return True
        except OSError:
            time.sleep(0.1)
    return False


def stream_rows(stream) -> np.ndarray:
    """(N, 12) both eyes' lines of the stream's samples with an eye valid (NaN: an eye not)."""
    nan = np.full(6, np.nan)
    return np.array([np.concatenate([stream.left[k] if stream.left_valid[k] else nan,
                                     stream.right[k] if stream.right_valid[k] else nan])
                     for k in range(len(stream.t)) if stream.left_valid[k] or stream.right_valid[k]])


def missing_from_run(sent: np.ndarray, rows: np.ndarray) -> tuple[int, int]:
    """(stream samples from the one matching ``rows[0]`` to the one matching ``rows[-1]``, of
    them not in ``rows``): ``rows`` (M, 12) must be the stream's ``sent`` (N, 12), in order."""
    if not len(rows):
        return 0, 0
    close = np.all(np.isclose(sent, rows[0], atol=2e-4, equal_nan=True), axis=1)
    j = int(np.flatnonzero(close)[0])
    matched = 0
    first = j
    for row in rows:                           # each recorded row is the next stream sample found
        while j < len(sent) and not np.allclose(sent[j], row, atol=2e-4, equal_nan=True):
            j += 1
        matched += j < len(sent)
        j += 1
    return j - first, j - first - matched


def recorded_rows(rec: Path):
    r = read_eye_rays(rec / "eye_rays.csv")
    return r.t_s, np.hstack([r.left_origin_mm, r.left_direction, r.right_origin_mm, r.right_direction])


def live_targets(rec: Path) -> dict:
    """The last message of each target id the session published (live.jsonl)."""
    out = {}
    for line in (rec / "live.jsonl").read_text().splitlines():
        m = json.loads(line)
        if m.get("type") == "target":
            out[m["target"]] = m
    return out


def process_distance(rec: Path, out: Path) -> list[float]:
    """Each live target's distance to the nearest target ``process`` finds in the recording, mm."""
    res = process_session(rec, out, report=False)
    return [min((float(np.linalg.norm(np.subtract(m["position_mm"], t["position_mm"]))) for t in res.targets),
                default=float("inf")) for m in live_targets(rec).values()]


def _cpu_s(stat_path: str) -> float | None:
    """utime + stime, s, of a /proc stat file (None: gone)."""
    try:
        rest = Path(stat_path).read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(rest[11]) + int(rest[12])) / os.sysconf("SC_CLK_TCK")


class CpuWatch(threading.Thread):
    """Each thread's CPU time in this process (by name) and the tracking process's, read from
    /proc every 0.25 s until ``stop`` (the session's threads end inside ``run``: the last reading
    of each is kept)."""

    def __init__(self, live):
        super().__init__(daemon=True)
        self.live, self.cpu, self.done = live, {}, threading.Event()
        self.start_cpu = self._threads()            # the threads already running (the loop's): from now on

    def _threads(self) -> dict:
        return {th.name: c for th in threading.enumerate()
                if th.native_id and (c := _cpu_s(f"/proc/self/task/{th.native_id}/stat")) is not None}

    def run(self):
        while not self.done.wait(0.25):
            for th in threading.enumerate():
                c = _cpu_s(f"/proc/self/task/{th.native_id}/stat") if th.native_id and th is not self else None
                if c is not None:
                    self.cpu[th.name] = c
            remote = getattr(self.live.tracker, "remote", None)
            if remote is not None and (c := _cpu_s(f"/proc/{remote.proc.pid}/stat")) is not None:
                self.cpu["tracking process"] = c

    def stop(self) -> dict:
        """CPU time, s, of each thread (by name) and of the tracking process since ``__init__``."""
        self.done.set()
        self.join()
        return {k: v - self.start_cpu.get(k, 0.0) for k, v in self.cpu.items()}


def run_device(root: Path, tmp: Path, args, subscriber: str, listener_cls) -> dict:
    """One live run against the emulator; prints its figures and returns them."""
    port = free_port()
    emu = start_emulator(root, port, args.device)
    listener = listener_cls(False) if subscriber == "stalled" else None
    rec = tmp / f"rec-device-{subscriber}"
    live, link = open_device_session(f"{args.device}://127.0.0.1:{port}", root / "truth" / "camera.json",
                                     root / "markers.json", record=rec, stdout=False,
                                     publish=listener.url if listener else None)
    load0, cpu0, wall0 = load(), resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    watch = CpuWatch(live)
    watch.start()
    try:
        st = live.run(duration_s=args.seconds + 1.5)
    finally:
        cpu1, wall1, load1 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic(), load()
        threads = watch.stop()
        link.close()
        emu.terminate()
        emu.wait(10)
        if listener is not None:
            listener.close()
    t, rows = recorded_rows(rec)
    expected, missing = missing_from_run(stream_rows(device_stream(root)), rows)
    h, c = st.latency_all, st.sample_cpu
    cpu_s = cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime
    print(f"live --device {args.device} [{subscriber}], {_onecore.CORES} core(s), {args.seconds:g} s of "
          f"{args.resolution} {DESCRIBED[args.device]}, recorded"
          + (", TCP subscriber that never reads" if listener else "") + f"; {load0} before, {load1} after")
    print(f"  latency device sample time -> published estimate ({h.n} estimates): p50 {h.percentile(50):.1f} ms, "
          f"p95 {h.percentile(95):.1f} ms, p99 {h.percentile(99):.1f} ms, max {h.percentile(100):.1f} ms")
    tr = live.reader.transport
    print(f"  of which device sample time -> received by the gaze reader (the emulator's lateness and the "
          f"network): p50 {tr.percentile(50):.1f} ms, p95 {tr.percentile(95):.1f} ms, max {tr.percentile(100):.1f} ms")
    tk = st.taken
    print(f"  device sample time -> taken by the loop (transport and the wait for the loop): p50 "
          f"{tk.percentile(50):.1f} ms, p95 {tk.percentile(95):.1f} ms, p99 {tk.percentile(99):.1f} ms")
    print("  CPU time over the run, s: " + ", ".join(f"{k} {v:.1f}" for k, v in sorted(threads.items(),
                                                                                     key=lambda kv: -kv[1])))
    print(f"  CPU time per published estimate in the loop's thread (pose, estimate, publish): p50 "
          f"{c.percentile(50):.2f} ms, p95 {c.percentile(95):.2f} ms, p99 {c.percentile(99):.2f} ms; this process: "
          f"{cpu_s:.1f} s CPU over {wall1 - wall0:.1f} s ({100 * cpu_s / (wall1 - wall0):.0f} % of its core)")
    print(f"  gaze samples received {st.eye_records} (corrupt {st.corrupt}, reconnects {st.reconnects}, no pose "
          f"{st.no_pose}, too late to estimate {st.shed}), recorded {len(rows)}; stream samples from the first "
          f"received on {expected}, missing from the recording {missing}")
    print(f"  frames {st.frames}, tracked {live.tracker.tracked} (skipped for a newer one {st.frames_skipped}, "
          f"missed {st.frames_missed}); messages {st.published}, dropped by publishing {st.publish_dropped}"
          + (f"; disconnected: {', '.join(live.publisher.disconnected)}" if live.publisher.disconnected else ""))
    ok = h.percentile(95) <= 25 and missing == 0 and st.eye_records == len(rows)
    print(f"  target p95 <= 25 ms and nothing received missing: {'PASS' if ok else 'FAIL'}")
    dist = process_distance(rec, tmp / f"processed-{subscriber}")
    print(f"  process on the recording: each of the {len(dist)} live targets to the nearest offline one: "
          f"{', '.join(f'{d:.3f}' for d in dist)} mm; within 1 mm: {'PASS' if dist and max(dist) <= 1.0 else 'FAIL'}")
    return {"p50": h.percentile(50), "p95": h.percentile(95), "missing": missing, "dist": dist}


def run_reconnect(root: Path, tmp: Path, args) -> dict:
    """The emulator killed a third into the run and started again on the same port."""
    port = free_port()
    emu = start_emulator(root, port, args.device)
    rec = tmp / "rec-device-reconnect"
    live, link = open_device_session(f"{args.device}://127.0.0.1:{port}", root / "truth" / "camera.json",
                                     root / "markers.json", record=rec, stdout=False)
    done = {}
    th = threading.Thread(target=lambda: done.update(stats=live.run(duration_s=args.seconds)))
    th.start()
    time.sleep(args.seconds / 3)
    emu.send_signal(signal.SIGKILL)                            # the device goes away ...
    emu.wait(10)
    killed = time.monotonic()
    emu = start_emulator(root, port, args.device)              # ... and comes back on the same address
    back = time.monotonic()
    th.join()
    link.close()
    emu.terminate()
    emu.wait(10)
    st = done["stats"]
    t, rows = recorded_rows(rec)
    local = t + link.t0
    before, after = rows[local < killed], rows[local > back]
    sent = stream_rows(device_stream(root))
    mb, ma = missing_from_run(sent, before)[1], missing_from_run(sent, after)[1]
    gap = float(local[local > back][0] - back) if len(after) else float("inf")
    print(f"live --device {args.device}, the emulator killed {args.seconds / 3:.0f} s into a {args.seconds:g} s "
          f"run and started again on the same port {back - killed:.1f} s later ({load()})")
    print(f"  reconnects {st.reconnects}; first sample recorded {gap:.2f} s after the device answered again "
          f"(target <= 2 s); recorded {len(before)} before, {len(after)} after, {len(rows) - len(before) - len(after)} "
          f"in between; received {st.eye_records}; missing from the recording: {mb} before, {ma} after: "
          f"{'PASS' if gap <= 2.0 and mb == ma == 0 and st.eye_records == len(rows) else 'FAIL'}")
    return {"gap": gap, "missing": mb + ma}
