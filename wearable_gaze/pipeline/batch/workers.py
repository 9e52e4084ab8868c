"""Where the sessions of ``wearable-gaze batch`` run (docs/batch.md): the worker's function
``run_session`` (one session, as ``process`` would, its status written before and after), and the
two runners that call it, ``LocalRunner`` (worker processes on this machine, no extra needed) and
``DaskRunner`` (an existing Dask cluster; the optional extra ``wearable-gaze[dask]``).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import socket
import sys
import time
import traceback
import uuid
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...errors import UserError, one_line
from ...formats.batch_status import (
    LOCK_FILE,
    STATUS_FILE,
    is_alive,
    read_status,
    release_lock,
    take_lock,
    this_process,
    write_status,
)

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

    from .run import BatchSettings

log = logging.getLogger(__name__)

MAX_ATTEMPTS = 3
"""A session whose worker process dies this many times (a crash, the out-of-memory killer) fails."""
DASK_EXTRA = "pip install 'wearable-gaze[dask]'"
RECYCLES_WORKERS = sys.version_info >= (3, 11)
"""Whether a local pool replaces each worker after one session itself (``max_tasks_per_child``,
Python 3.11); without it (3.10) ``LocalRunner`` replaces the pool after one session per worker."""


@dataclass(frozen=True)
class SessionTask:
    """One session to process: what a worker receives (picklable, paths as strings)."""

    name: str
    session: str
    out: str
    settings: BatchSettings
    fingerprint: str
    attempt: int = 1


# --- one session, in a worker ----------------------------------------------------------------

def _memory_mb() -> tuple[float | None, float | None]:
    """(resident, peak resident) memory of this process, MB (Linux /proc; else the peak from
    ``resource``)."""
    try:
        fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
        return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024
    except (OSError, KeyError, ValueError):
        try:
            import resource

            return None, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        except ImportError:
            return None, None


REASON_CHARS = 500
"""A status's ``reason``, cut to this many characters (``one_line``)."""


def run_session(task: SessionTask) -> dict:
    """Process one session into ``task.out`` as ``process`` would (in a worker process, local or
    Dask); write its status there before (``running``) and after (``done``; ``partial`` with the
    reason: targets, but a step failed, as ``process`` exits 3; or ``failed`` with the reason:
    the session unreadable, or no target estimated, as ``process`` exits 2, or an internal error,
    its traceback kept in the status as ``traceback``); return the final status. Never raises for
    a bad session; Ctrl-C and a killed worker leave the status ``running``."""
    from ..process.session import process_session  # the worker's heavy import, once

    out = Path(task.out)
    out.mkdir(parents=True, exist_ok=True)
    owner = take_lock(out)
    if owner is not None:                   # its status file is the owner's: left alone
        return {"version": 1, "name": task.name, "session": task.session, "fingerprint": task.fingerprint,
                "state": "failed", "attempt": task.attempt,
                "reason": f"being processed by another worker ({owner}, {out / LOCK_FILE}): not done twice; run the "
                          "batch again once that one has finished"}
    try:
        return _run_locked(task, out, process_session)
    finally:
        release_lock(out)


def _run_locked(task: SessionTask, out: Path, process_session) -> dict:
    """``run_session`` once this worker holds the session's lock."""
    status = {"version": 1, "name": task.name, "session": task.session, "fingerprint": task.fingerprint,
              "state": "running", "reason": None, "attempt": task.attempt, "worker": f"{socket.gethostname()}:"
              f"{os.getpid()}", "started": time.time()}
    write_status(out, status)
    t0 = time.perf_counter()
    try:
        res = process_session(task.session, out, **task.settings.process_kwargs())
    except UserError as exc:
        status.update(state="failed", reason=one_line(exc, REASON_CHARS))
    except Exception as exc:  # a bug on one session must not stop the others
        log.exception("session %s: internal error", task.session)
        status.update(state="failed", reason=one_line(f"internal error ({type(exc).__name__}: {exc}); this is a "
                                                      f"bug: its traceback is in {STATUS_FILE}", REASON_CHARS),
                      traceback=traceback.format_exc())
    else:
        state = {"ok": "done", "partial": "partial"}.get(res.outcome, "failed")
        status.update(state=state, reason=None if state == "done" else one_line("; ".join(res.problems), REASON_CHARS),
                      n_targets=sum(t.fixated for t in res.found), problems=res.problems, failed_steps=res.failed,
                      steps_skipped=res.skipped)
    status["duration_s"] = round(time.perf_counter() - t0, 3)
    status["finished"] = time.time()
    gc.collect()
    status["rss_mb"], status["peak_rss_mb"] = _memory_mb()
    write_status(out, status)
    return status


def _init_local_worker(coordinator: str) -> None:
    """A local worker: Ctrl-C is the coordinator's to handle (it stops the workers); the worker
    ends when its ``coordinator`` (``HOST:PID:START``) does, killed or not (``_watch``); one
    thread for OpenCV (the batch runs one worker per core)."""
    import signal
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch, args=(coordinator,), name="coordinator-watch", daemon=True).start()
    with contextlib.suppress(ImportError):
        import cv2

        cv2.setNumThreads(1)


def _watch(coordinator: str) -> None:
    """End this worker process at once when the ``coordinator`` process is gone (a coordinator
    killed outright cannot stop its workers: they would go on writing into OUT, and a restarted
    batch would find the sessions they hold). Its session stays ``running``, its lock stale: the
    next batch does it again."""
    while is_alive(coordinator):
        time.sleep(POLL_S)
    os._exit(1)


# --- the runners: local processes or a Dask cluster ------------------------------------------------

class WorkerLost(Exception):
    """A session's worker process died (crash, killed) too often for it to be retried."""


@contextlib.contextmanager
def _single_threaded_children():
    """Numerical libraries in the worker processes started meanwhile use one thread each."""
    names = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    before = {k: os.environ.get(k) for k in names}
    for k in names:
        os.environ.setdefault(k, "1")
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


POLL_S = 0.2
"""How often the coordinator looks up from waiting: a signal (Ctrl-C) that the system handed to
another of its threads is acted on only when the main thread wakes (a blocking wait would hold
it until the next session ends)."""


def _as_completed(futures):
    """``concurrent.futures.as_completed``, waking every ``POLL_S`` s (see there)."""
    from concurrent.futures import FIRST_COMPLETED, wait

    pending = set(futures)
    while pending:
        done, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
        yield from done


def _context():
    """The start method of local workers: forked from a server that has imported the pipeline
    (with one-thread numerical libraries: it starts inside ``_single_threaded_children``)."""
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["wearable_gaze.pipeline.batch.workers", "wearable_gaze.pipeline.process.session"])
    return ctx


def _pool(size: int) -> ProcessPoolExecutor:
    """A pool of ``size`` local workers (``_context``, ``_init_local_worker``), each replaced after
    one session where Python can (``RECYCLES_WORKERS``)."""
    from concurrent.futures import ProcessPoolExecutor

    # a keyword Python 3.10 lacks (its stubs too): passed only where there
    recycle: dict[str, Any] = {"max_tasks_per_child": 1} if RECYCLES_WORKERS else {}
    return ProcessPoolExecutor(size, _context(), initializer=_init_local_worker, initargs=(this_process(),),
                               **recycle)


class LocalRunner:
    """Worker processes on this machine (``concurrent.futures``), each running one session and
    replaced by a fresh one for the next (``max_tasks_per_child=1``), so no worker's memory can
    grow across sessions. Python 3.10 has no ``max_tasks_per_child``: there each pool is given one
    session per worker and replaced once they are done (``RECYCLES_WORKERS`` False; a worker that
    finishes before another has started may take that one's session too). They are forked from a
    server process that has imported the pipeline once (start method ``forkserver``; ``spawn``
    where there is none), so a fresh worker costs no import. A worker that dies (a crash, the
    out-of-memory killer) breaks the pool: its sessions are submitted again to a new one, at most
    ``MAX_ATTEMPTS`` times in all.

    (One worker for several sessions, ``max_tasks_per_child`` > 1, deadlocks the pool on
    Python 3.11-3.14 when sessions are queued: CPython issue gh-115634.)"""

    def __init__(self, workers: int):
        self.workers = max(1, int(workers))
        self.pool: ProcessPoolExecutor | None = None

    def describe(self) -> str:
        return f"{self.workers} local worker process(es)"

    def run(self, tasks):
        """Yield (task, status dict or exception) as sessions finish."""
        from concurrent.futures.process import BrokenProcessPool

        todo = list(tasks)
        with _single_threaded_children():               # the workers are started on demand, and replaced
            while todo:
                size = min(self.workers, len(todo))
                wave, todo = (todo, []) if RECYCLES_WORKERS else (todo[:size], todo[size:])
                self.pool = pool = _pool(size)
                futures = {pool.submit(run_session, t): t for t in wave}
                for fut in _as_completed(futures):
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        result = self._again(futures[fut], todo)
                    if result is not None:
                        yield futures[fut], result
                pool.shutdown(wait=True)
                self.pool = None

    @staticmethod
    def _again(task: SessionTask, todo: list):
        """A session whose pool broke (a worker died): queued again (None), or, started and lost
        ``MAX_ATTEMPTS`` times, a ``WorkerLost``."""
        st = read_status(Path(task.out))
        started = st is not None and st["state"] == "running" and st.get("attempt") == task.attempt
        again = replace(task, attempt=task.attempt + int(started))
        if again.attempt > MAX_ATTEMPTS:
            return WorkerLost(f"its worker process died {MAX_ATTEMPTS} times (a crash, or killed: out of memory?)")
        todo.append(again)
        return None

    def stop(self, timeout_s: float = 30.0) -> None:
        """Stop every worker now (Ctrl-C): the sessions they were processing stay ``running``.
        The pool may be starting a worker meanwhile, so its workers are stopped until its
        manager thread ends (the pool's own ``shutdown`` would wait for their sessions; the
        standard library has no public way to stop workers before Python 3.14, and that one
        misses a worker being started). ``shutdown(wait=False)`` lets go of the workers while
        the manager thread may meet one's exit and count them (``len(None)``): the thread then
        ends, as it should, and ``_quiet_end`` keeps its traceback off the terminal."""
        pool, self.pool = self.pool, None
        if pool is None:
            return
        processes = getattr(pool, "_processes", None) or {}
        manager = getattr(pool, "_executor_manager_thread", None)
        with _quiet_end(pool, manager):
            pool.shutdown(wait=False, cancel_futures=True)
            t0 = time.monotonic()
            while True:
                for p in list(processes.values()):
                    with contextlib.suppress(Exception):
                        p.terminate()
                if manager is None or not manager.is_alive() or time.monotonic() - t0 > timeout_s:
                    break
                manager.join(0.05)


@contextlib.contextmanager
def _quiet_end(pool, manager):
    """While a stopped pool's manager thread ends: its ``TypeError`` from counting the workers the
    pool has let go of (``_processes`` None) is that end, not an error, and is not printed (it
    was, as a traceback, when Ctrl-C met a worker's exit); any other exception is."""
    import threading

    previous = threading.excepthook

    def hook(args):
        if not (args.thread is manager and args.exc_type is TypeError and getattr(pool, "_processes", 1) is None):
            previous(args)
    threading.excepthook = hook
    try:
        yield
    finally:
        if manager is not None:
            manager.join(1.0)
        if threading.excepthook is hook:
            threading.excepthook = previous


class DaskRunner:
    """The sessions as tasks of an existing Dask cluster (its scheduler's address): one task per
    session (``pure=False``: a re-run computes again), reassigned by the scheduler when a worker
    dies while running it. The workers must have wearable-gaze installed and see the sessions and
    OUT at the same paths (a shared file system)."""

    def __init__(self, address: str, connect_timeout_s: float = 10.0):
        try:
            import distributed
        except ImportError:
            raise UserError(f"--scheduler needs Dask's distributed scheduler (an optional extra): {DASK_EXTRA}") \
                from None
        self._distributed = distributed
        self.address = address
        try:
            self.client = distributed.Client(address, timeout=connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise UserError(f"--scheduler {address}: cannot connect ({one_line(exc, 200)}); start the scheduler "
                            "('dask scheduler') or check the address") from None
        self.futures: dict[Any, SessionTask] = {}          # Dask futures (distributed.Future)

    def describe(self) -> str:
        n = len(self.client.scheduler_info().get("workers", {}))
        return f"the Dask cluster at {self.address} ({n} worker(s))"

    def run(self, tasks):
        """Yield (task, status dict or exception) as sessions finish."""
        d = self._distributed
        batch_id = uuid.uuid4().hex[:8]
        self.futures = {self.client.submit(run_session, t, key=f"wearable-gaze-{t.name}-{batch_id}", pure=False,
                                           retries=1): t for t in tasks}
        ac = d.as_completed(list(self.futures), loop=self.client.loop)
        while not ac.is_empty():                        # polled: see POLL_S
            ready = ac.next_batch(block=False) if ac.has_ready() else []
            if not ready:
                time.sleep(POLL_S)
            for fut in ready:
                try:
                    result = fut.result()
                except Exception as exc:  # KilledWorker, a lost scheduler: that session fails
                    result = exc
                task = self.futures.pop(fut)
                # released at once: a finished task whose worker dies later would otherwise be
                # computed again to restore its lost result, and write the session's status anew
                fut.release()
                yield task, result

    def stop(self) -> None:
        """Cancel the sessions not yet started (those running finish on their workers)."""
        with contextlib.suppress(Exception):
            self.client.cancel(list(self.futures))

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.close()
