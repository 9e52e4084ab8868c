"""Finished fixations made into targets in a process of their own (a device session, docs/live.md,
The loop): the motion test or path and the merge test (``GazeEstimation.finish_ended``, 60-200
ms of CPU time a fixation, much of it in numpy calls that hold the interpreter's lock for
milliseconds at a time) share no interpreter lock with the eye samples' thread. In a thread of
the session they took the lock from the loop at each fixation's end for 0.2-0.6 s: the samples
that came meanwhile waited 30-100 ms (docs/live.md, Latency).

``RemoteTargets.finish(done)`` thins the fixation's lines in the calling thread (the loop's target
worker), sends them (a few kB) and waits for the target. The process keeps the merge state (the
target ids), so fixations are made in the order they are sent, as ``process`` re-runs them
(``pipeline.steps.live_replay``).
"""

from __future__ import annotations

from ..pipeline.steps.live_estimation import GazeEstimation, RayEyes, thin_fixation
from . import served

NICE = 10
"""The target process's niceness above the session's: on a core the loop and the tracking
process keep busy, the eye samples go first; a target comes a little later (it is published when
made, in fixation order). At 5 it still had a quarter of the core against a loop with samples
waiting: the two longest backlogs of a 30 s Pupil Core run at load 1.5 (97.7 and 73.3 ms) were
fixations' ends, the loop's thread at 47-49 % of the core."""


def _serve(conn, method: str, nice: int) -> None:
    """The target process: ``EndedFixation`` in; (target or None, ids given so far) or
    ("error", message) out, until a None."""
    served.renice(nice)
    est = GazeEstimation([RayEyes(), RayEyes()], method)
    conn.send("ready")
    while (done := conn.recv()) is not None:
        try:
            conn.send((est.finish_ended(done), len(est.targets)))
        except Exception as exc:  # the session's target worker raises it (the session ends)
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


class RemoteTargets:
    """A target process for the streaming estimator ``method`` (started here, a fresh
    interpreter; ``ready`` waits for it).

    ``n_ids``: the target ids given so far (``TargetIds``' length in the process).
    """

    def __init__(self, method: str, nice: int = NICE):
        self.proc, self.conn = served.start(_serve, (method, nice), "wearable-gaze-targets")
        self.n_ids = 0

    def ready(self) -> None:
        """Wait for the process to start.

        Raises:
            RuntimeError: it did not within ``served.START_TIMEOUT_S``.
        """
        if not served.ready(self.conn):
            self.close()
            raise RuntimeError(served.NOT_STARTED.format("target"))

    def finish(self, done):
        """The target (``pipeline.types.Target``) of a finished fixation (``FinishedFixation``),
        or None (``GazeEstimation.finish``).

        Raises:
            RuntimeError: the process failed on it, or has ended.
        """
        self.conn.send(thin_fixation(done))
        try:
            answer = self.conn.recv()
        except EOFError:
            raise RuntimeError("the target process ended") from None
        if isinstance(answer[0], str):
            raise RuntimeError(answer[1])
        target, self.n_ids = answer
        return target

    def close(self) -> None:
        """End the process at once: it holds nothing to keep (the session has had every target it
        asked for), and its interpreter's own teardown takes 0.15 s or more, which the session's
        end would wait for."""
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.proc.join(0.02)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(1.0)
        if self.proc.is_alive():               # pragma: no cover (SIGTERM is not caught there)
            self.proc.kill()
            self.proc.join(1.0)
        self.conn.close()
