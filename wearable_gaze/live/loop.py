"""The live loop (docs/live.md, The loop): frames to head tracking, eye samples with their head
pose to estimation, what comes out published and recorded. The parts are built and wired by
``app.open_session``; each is tested alone, the loop with fakes of them."""

from __future__ import annotations

import gc
import logging
import queue
import sys
import threading
import time
from collections import deque

import numpy as np

from ..errors import UserError
from .allocator import bound_heap, release_free_memory
from .head import TrackingThread
from .messages import estimate_message, target_message
from .sched import GAZE_SLICE_S, set_thread_slice, thread_slice_s
from .stats import LiveStats

log = logging.getLogger(__name__)

QUIET_END_S = 0.5       # after the camera file ends, the session ends once eye data have been quiet this long
SHED_AFTER_S = 0.1
"""With frames tracked off the loop (a device session): a sample this late (from its device time)
when the loop takes it is not estimated (``LiveStats.shed``, still recorded; no pose in
``live_poses.csv``, so ``process`` skips it too): on a core too busy for 200 Hz the backlog, and
with it the latency, stays bounded instead of growing (seconds, on the 2-core machine at load 20)."""
SWITCH_INTERVAL_S = 0.0005
"""The interpreter's thread switch interval during a session (Python's default is 5 ms): a thread
that wants the interpreter's lock while another computes (the target worker's motion and merge
tests, the frame reader, the recorder) waits up to this long for it, and the loop's thread waits
for it several times a sample (each queue, lock and socket call releases it). At 5 ms the samples
that came while another thread computed waited up to 10-50 ms (docs/live.md, Latency)."""


class TargetWorker(threading.Thread):
    """The end-of-fixation work off the loop's thread (docs/live.md, The loop): finished
    fixations are taken from a queue one at a time, in the order they ended (so target ids are
    given deterministically), each turned into its target (``finish``: the motion test or path,
    the merge test, 0.05-1 s) and published (``publish``) while the loop goes on with the next
    eye samples. ``drain`` returns once every fixation queued before it is done.

    An error in ``finish`` or ``publish`` is kept in ``failure`` (the loop ends the session on
    it); the fixations after it are dropped.
    """

    def __init__(self, finish, publish):
        super().__init__(name="targets", daemon=True)
        self.finish, self.publish = finish, publish
        self.queue: queue.Queue = queue.Queue()      # unbounded: one item per fixation, a few a second at most
        self.failure: str | None = None

    def put(self, done) -> None:
        """Queue a finished fixation (``estimation.FinishedFixation``)."""
        self.queue.put(done)

    def run(self) -> None:
        while (done := self.queue.get()) is not None:
            if self.failure is not None:
                continue
            try:
                target = self.finish(done)
                if target is not None:
                    self.publish(target)
            except Exception as exc:  # the loop raises it: the session ends, the recording kept
                log.debug("the target worker failed", exc_info=True)
                self.failure = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__

    def drain(self) -> None:
        """Wait until every fixation queued so far is done, then end the thread (a worker never
        started ends at once)."""
        if self.is_alive():
            self.queue.put(None)
            self.join()


class LiveSession:
    """Runs until the camera file ends, ``duration_s`` passes, or ``stop()`` (Ctrl-C, SIGTERM).

    Readers (serial, camera) run in threads; the recorder takes every intact eye record and
    every frame from them directly, so nothing the loop or the subscribers do can keep a
    sample out of the recording. The loop tracks, estimates and publishes; publishing never
    blocks it (``publish.Publisher``). A finished fixation's target is made and published by
    one worker thread (``TargetWorker``), so that the motion and merge tests do not hold up the
    next eye samples; the session waits for it before the recording is closed. Any error inside
    the loop or the worker ends the session: the recording is kept, marked incomplete, and
    ``run`` raises a ``UserError`` saying so.

    Args:
        reader: the eye reader (``serial_in.EyeReader``): a thread whose queue holds
            ``(arrival_s, t_s, EyeRecord)``.
        frames: the camera (``camera_in.FrameSource``): a thread whose queue holds
            ``(t_monotonic_s, index, grey, colour)``.
        head: ``head.HeadTracker``; estimation: ``estimation.GazeEstimation``.
        publisher: ``publish.Publisher``; recorder: ``record.Recorder`` or None.
        status_stream: where the one-line status goes every 0.5 s (None: nowhere).
        viewer: ``viewer.RerunViewer`` or None: fed every message, each tracked frame's head pose
            and each target with its fixation's lines.
        tracker: a ``head.TrackingThread`` feeding ``head`` (a device session): no eye sample
            waits for a frame, each takes the newest pose there is (``HeadTracker.pose_at``),
            and the recording keeps the pose each sample took (``Recorder.sample_pose``:
            ``process`` re-runs with them). None: the loop tracks the newest frame between eye
            samples, which wait for a frame at most ``head.MAX_WAIT_S``.
        targets: a ``target_process.RemoteTargets`` (a device session; closed with the
            session): the target worker has it make each finished fixation's target, so that the
            motion and merge tests share no interpreter lock with the loop. None: the worker
            makes them itself (``estimation.finish``).
    """

    def __init__(self, reader, frames, head, estimation, publisher, recorder=None, status_stream=None, viewer=None,
                 tracker: TrackingThread | None = None, targets=None):
        self.reader, self.frames = reader, frames
        self.head, self.estimation = head, estimation
        self.tracker = tracker
        self.publisher, self.recorder = publisher, recorder
        self.status_stream = status_stream
        self.stats = LiveStats()
        self.tracking_skipped = 0        # waiting frames passed over for a newer one (the camera counts its own drops)
        self.stop_event = threading.Event()
        self.pending: deque = deque()                # (arrival, t_s, record) waiting for a pose
        self.last_arrival: float | None = None       # monotonic time the newest eye record arrived
        self.camera_ended_at: float | None = None
        self.publish_lock = threading.Lock()         # the loop and the target worker both publish
        self.viewer = viewer
        self.targets = targets
        self.make_target = estimation.finish if targets is None else targets.finish
        self.worker = TargetWorker(self._finish if viewer is not None else self.make_target, self._publish_target)

    def stop(self, *_):
        self.stop_event.set()

    def _publish(self, msg: dict) -> None:
        """Send ``msg`` and record it: from the loop or the target worker, one at a time, so that
        the recording has the messages in the order subscribers get them."""
        with self.publish_lock:
            line = self.publisher.send(msg)
            if self.viewer is not None:
                self.viewer.message(msg)
            if self.recorder is not None:
                self.recorder.message(line)
            self.stats.published += 1

    def _finish(self, done):
        """A finished fixation's target (in the target worker), shown in the viewer with its lines."""
        target = self.make_target(done)
        if target is not None:
            self.viewer.target(target, done.lines)
        return target

    def _publish_target(self, target) -> None:
        """A finished fixation's target (in the target worker)."""
        self._publish(target_message(target))
        with self.publish_lock:
            self.stats.targets += 1

    def update_stats(self) -> LiveStats:
        """Copy the readers' and the publisher's counters into ``stats``."""
        s, r, c = self.stats, self.reader.stats, self.frames.stats
        s.frames, s.frames_missed, s.camera_stalls = c.frames, c.missed, c.stalls
        s.frames_skipped = self.tracking_skipped + c.skipped + (self.tracker.skipped if self.tracker else 0)
        s.eye_records, s.corrupt, s.lost, s.reader_dropped, s.reconnects = (r.records, r.corrupt, r.lost, r.dropped,
                                                                            r.reconnects)
        s.publish_dropped = self.publisher.dropped
        s.distinct_targets = len(self.estimation.targets) if self.targets is None else self.targets.n_ids
        return s

    def run(self, duration_s: float | None = None) -> LiveStats:
        """Run the session; returns its counters.

        Raises:
            UserError: the serial port will not open, or an error inside the session (the
                recording is kept and marked incomplete).
        """
        bound_heap()                                 # sessions one after another stay flat (allocator.py)
        release_free_memory()
        # the objects of before the session are frozen (kept, scanned again once it ends): a full
        # collection scans every object the process holds (the libraries, the setup) holding the
        # interpreter's lock, 0.1-0.25 s of every thread's time once or twice a minute at 200 Hz
        gc.freeze()
        switch, slice_s = sys.getswitchinterval(), thread_slice_s()
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        set_thread_slice(GAZE_SLICE_S)               # this thread runs the loop (sched.py)
        try:
            return self._run(duration_s)
        finally:
            sys.setswitchinterval(switch)
            set_thread_slice(slice_s)
            gc.unfreeze()

    def _run(self, duration_s: float | None) -> LiveStats:
        self.reader.start()
        self.reader.connected.wait(5.0)
        if self.reader.error and self.reader.error.startswith("cannot open"):
            self._close(complete=False)
            raise UserError(f"--serial: {self.reader.error}")
        self.frames.start()
        if self.tracker is not None:
            self.tracker.start()
        self.worker.start()
        failure = None
        try:
            self._loop(duration_s)
            self._ended(self.estimation.end_fixation())
            self.worker.drain()                      # every target published and recorded
            if self.worker.failure:
                raise RuntimeError(f"the target worker failed: {self.worker.failure}")
        except Exception as exc:  # one line to the user; the recording kept, not complete
            log.debug("live session failed", exc_info=True)
            failure = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        finally:
            self._close(complete=failure is None)
        self.update_stats()
        if failure is not None:
            kept = f"; the recording in {self.recorder.root} is kept, marked incomplete" if self.recorder else ""
            raise UserError(f"the session stopped on an error ({failure}){kept}")
        return self.stats

    def _loop(self, duration_s: float | None) -> None:
        t_start = time.monotonic()
        last_status = 0.0
        while not self.stop_event.is_set():
            for th, what in ((self.reader, "the eye reader"), (self.frames, "the camera"),
                             (self.worker, "the target worker"), (self.tracker, "head tracking")):
                if th is not None and th.failure:
                    raise RuntimeError(f"{what} failed: {th.failure}")
            if self.tracker is None:
                busy = self._drain_frames()
                busy |= self._drain_eye()
            else:
                busy = self._take_eye()
            now = time.monotonic()
            if duration_s is not None and now - t_start >= duration_s:
                self.stats.end_reason = f"{duration_s:g} s passed"
                return
            if self._camera_over(now):
                return
            if self.status_stream is not None and now - last_status > 0.5:
                self._status()
                last_status = now
            if not busy:
                time.sleep(0.002)
        self.stats.end_reason = "stopped"

    def _camera_over(self, now: float) -> bool:
        """The camera file has ended and its frames are done; the session ends once the eye
        data have been quiet for ``QUIET_END_S`` (at once if none ever came)."""
        if not (self.frames.finished.is_set() and self.frames.queue.empty()) or (self.tracker and self.tracker.busy):
            return False
        if self.camera_ended_at is None:
            self.camera_ended_at = now
        if not (self.reader.queue.empty() and not self.pending):
            return False
        since = now - max(self.camera_ended_at, self.last_arrival or 0.0)
        if since <= QUIET_END_S:
            return False
        if self.last_arrival is None:
            self.stats.end_reason = (f"the camera ended and no eye data ever arrived from {self.reader.port} "
                                     f"(check --serial and --baud, and that the recorder is sending)")
        else:
            self.stats.end_reason = "the camera ended"
        return True

    def _drain_frames(self) -> bool:
        """Track the newest waiting frame; older waiting frames are skipped (counted): under
        load, a fresh pose serves the waiting eye samples better than a backlog of old ones
        (every frame is still recorded)."""
        items = []
        while True:
            try:
                items.append(self.frames.queue.get_nowait())
            except queue.Empty:
                break
        if not items:
            return False
        self.tracking_skipped += len(items) - 1
        t, _, gray, _ = items[-1]
        if self.head.track(t - self.frames.t0, gray) and self.viewer is not None:
            self.viewer.head(*self.head.poses[-1])
        return True

    def _drain_eye(self) -> bool:
        """Take the waiting eye records; each is processed once the head pose at its time is
        known (or it has waited long enough: ``HeadTracker.must_wait``)."""
        busy = False
        while True:
            try:
                item = self.reader.queue.get_nowait()
            except queue.Empty:
                break
            busy = True
            self.last_arrival = item[0]
            self.pending.append(item)
        while self.pending:
            arrival, t_s, rec = self.pending[0]
            if self.head.must_wait(t_s, time.monotonic() - arrival):
                break                                        # wait for the next frame (bounded)
            self.pending.popleft()
            self._sample(arrival, t_s, rec)
        return busy

    def _take_eye(self) -> bool:
        """With frames tracked in their own thread: wait (at most 50 ms) for eye records and
        process each at once with the newest pose there is (it never waits for a frame)."""
        try:
            item = self.reader.queue.get(timeout=0.05)
        except queue.Empty:
            return False
        while item is not None:
            self.last_arrival = item[0]
            late = time.monotonic() - item[0]
            self.stats.taken.add(late * 1000)
            if late > SHED_AFTER_S:
                self.stats.samples += 1
                self.stats.shed += 1
                if self.recorder is not None:
                    self.recorder.sample_pose(item[1], None)
            else:
                self._sample(*item)
            try:
                item = self.reader.queue.get_nowait()
            except queue.Empty:
                item = None
        return True

    def _sample(self, arrival: float, t_s: float, rec) -> None:
        cpu0 = time.thread_time()
        self.stats.samples += 1
        if not (rec.left_valid or rec.right_valid):
            return
        T = self.head.pose_at(t_s)
        if T is None:
            self.stats.no_pose += 1
        else:
            ended, est = self.estimation.add(t_s, rec, T)
            lat = (time.monotonic() - arrival) * 1000
            self._ended(ended)
            if est is not None:
                self.stats.add_latency(lat)
                self._publish(estimate_message(est, lat))
                self.stats.sample_cpu.add((time.thread_time() - cpu0) * 1000)
        if self.tracker is not None and self.recorder is not None:
            self.recorder.sample_pose(t_s, T)            # the pose it took, for process to re-run with

    def _ended(self, done) -> None:
        """Hand a finished fixation to the target worker (None: the fixation gave none)."""
        if done is not None:
            self.worker.put(done)

    def _status(self) -> None:
        s = self.update_stats()
        lat = np.percentile(list(s.latencies_ms), 95) if s.latencies_ms else float("nan")
        x = self.estimation.current_mm
        cur = "-" if x is None else "(" + ", ".join(f"{v:.0f}" for v in x) + ")"
        self.status_stream.write(f"\r{s.counters()}  markers {self.head.markers_in_view}  p95 latency {lat:.1f} ms  "
                                 f"target {cur} mm   ")
        self.status_stream.flush()

    def _close(self, complete: bool = True) -> None:
        self.reader.stop()
        self.frames.stop()
        if self.tracker is not None:
            self.tracker.stop()
        for th in (self.reader, self.frames, self.tracker):
            if th is not None and th.is_alive():
                th.join(2.0)
        if self.tracker is not None:
            self.tracker.close()
        self.worker.drain()                          # after an error too: the targets found are kept
        if self.targets is not None:
            self.targets.close()
        self.publisher.close()
        if self.viewer is not None:
            self.viewer.close(5.0)
            if self.viewer.dropped:
                log.warning("rerun: %d of its items were dropped (the viewer fell behind)", self.viewer.dropped)
        if self.recorder is not None:
            self.recorder.close(complete=complete)
        self.update_stats()
        release_free_memory()
