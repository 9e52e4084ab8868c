"""``wearable-gaze batch``: many sessions, each processed exactly as ``process`` would, in
parallel: on this machine (a pool of worker processes, no extra needed) or on a Dask cluster
(``distributed``, the optional extra ``wearable-gaze[dask]``). docs/batch.md.

Each session gets its own output folder ``OUT/NAME`` (the session folder's name; sessions of the
same name in different folders get their parents' names too) and a status file there,
``OUT/NAME/batch_status.json``: ``pending``, ``running`` (written by the worker when it starts),
``done`` or ``failed`` (with the reason), and the fingerprint of the session's files and the
settings it ran with. A re-run skips a session that is done with the same fingerprint, retries
a failed one and redoes a changed one (``process`` itself then skips its unchanged steps); a
session left ``running`` by an interrupted batch is done again. ``OUT/batch.json`` is the index
of the batch: every session's status, rewritten after each change. Every file is written
atomically (``formats/atomic.py``): a batch killed at any point leaves no half-written file.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ...errors import UserError, one_line
from ...formats.atomic import remove_temporaries
from ...formats.batch_status import STATUS_FILE, earlier_statuses, lock_owner, read_status, write_index, write_status
from ...formats.session import MANIFEST
from ..process.stepcache import EXIT_PARTIAL, missing_output
from .summary import write_batch_report
from .workers import REASON_CHARS, DaskRunner, LocalRunner, SessionTask, WorkerLost

log = logging.getLogger(__name__)

_SKIP_DIRS = ("processed",)                    # process's default output folder inside a session


@dataclass(frozen=True)
class BatchSettings:
    """The ``process`` settings every session of a batch runs with (``process_session``'s
    arguments of the same names; ``camera``, ``eyes``: files used instead of calibrating each
    session; ``build_map``: (marker side mm, dictionary); ``markers``: a marker map every session is
    tracked in; ``aois``: an AOI file every session's AOI step reads)."""

    method: str = "voxel"
    camera: str | None = None
    eyes: str | None = None
    force: bool = False
    overlay: bool = True
    report: bool = True
    track_every: int = 2
    build_map: tuple | None = None
    markers: str | None = None
    aois: str | None = None

    def process_kwargs(self) -> dict:
        """The keyword arguments of ``process_session``."""
        return {"method": self.method, "camera": self.camera, "eyes": self.eyes, "force": self.force,
                "overlay": self.overlay, "report": self.report, "track_every": self.track_every,
                "build_map": self.build_map, "markers": self.markers, "aois": self.aois}

    def fingerprint_params(self) -> dict:
        """What decides a session's results (``force`` only says to redo them)."""
        d = asdict(self)
        d.pop("force")
        d["build_map"] = list(self.build_map) if self.build_map else None
        return d


@dataclass
class BatchResult:
    """What ``run_batch`` did.

    Attributes:
        out: the batch's output folder.
        statuses: {name: status dict (``STATUS_FILE``'s contents)}, in the sessions' order.
        skipped: names of the sessions done earlier and unchanged, not redone.
        interrupted: the batch was stopped (Ctrl-C) before every session finished.
        seconds: wall time.
    """

    out: Path
    statuses: dict = field(default_factory=dict)
    skipped: list = field(default_factory=list)
    interrupted: bool = False
    seconds: float = 0.0

    @property
    def failed(self) -> list:
        return [n for n, s in self.statuses.items() if s["state"] == "failed"]

    @property
    def done(self) -> list:
        return [n for n, s in self.statuses.items() if s["state"] == "done"]

    @property
    def partial(self) -> list:
        return [n for n, s in self.statuses.items() if s["state"] == "partial"]

    @property
    def exit_status(self) -> int:
        """0 when every session is done, 2 when any failed (as ``process`` on that session), else
        3 when any is partial (targets, but a step failed: ``process`` exits 3), 130 when
        interrupted."""
        return 130 if self.interrupted else 2 if self.failed else EXIT_PARTIAL if self.partial else 0


# --- the sessions and their output folders ------------------------------------------------------

def find_sessions(paths, exclude=None) -> list[Path]:
    """The session folders (with a ``session.json``: native, recorded or imported) among
    ``paths``: each a session folder, or a folder searched for them at any depth (not inside a
    session, not in hidden folders, not in ``exclude``). Returns resolved paths, sorted, each
    once.

    Raises:
        UserError: a path that is no folder, or holds no session.
    """
    exclude = Path(exclude).resolve() if exclude is not None else None
    found = []
    for p in paths:
        p = Path(p)
        if not p.is_dir():
            raise UserError(f"{p}: no such folder; give session folders or folders containing them")
        here = []
        for root, dirs, files in os.walk(p.resolve()):
            if MANIFEST in files:
                here.append(Path(root))
                dirs[:] = []
                continue
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and (exclude is None or Path(root, d) != exclude))
        if not here:
            raise UserError(f"{p}: no session folder in it (a folder with {MANIFEST}); give session folders or "
                            "folders containing them")
        found += here
    return sorted(set(found))


def _clean(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "session"


def output_names(sessions, known: dict | None = None) -> dict:
    """A distinct output folder name for each session (resolved paths): ``known`` ({path: name},
    from an earlier run) kept, else the folder's name, with as many parents' names as make it
    unique (``p01-rest``, ``p02-rest``), with a hash of the path when even that does not."""
    known = known or {}
    names = {s: known[s] for s in sessions if s in known}
    used = set(names.values())
    depth = {s: 1 for s in sessions if s not in names}
    while depth:
        cand = {s: "-".join(_clean(x) for x in s.parts[-d:]) for s, d in depth.items()}
        counts = Counter(cand.values())
        for s in list(depth):
            if counts[cand[s]] == 1 and cand[s] not in used:
                names[s] = cand[s]
                used.add(cand[s])
                del depth[s]
            elif depth[s] < len(s.parts) - 1:
                depth[s] += 1
            else:
                names[s] = f"{cand[s]}-{hashlib.sha1(str(s).encode()).hexdigest()[:8]}"
                used.add(names[s])
                del depth[s]
    return {s: names[s] for s in sessions}


def session_fingerprint(root: Path, settings: BatchSettings, exclude=None) -> str:
    """A hash of a session's files (relative path, size, modification time; not its
    ``processed`` folder, hidden files or ``exclude``), the calibration files given instead and
    the settings: a session whose fingerprint is unchanged has the same results."""
    h = hashlib.sha1()
    exclude = Path(exclude).resolve() if exclude is not None else None
    for dirpath, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not (Path(dirpath) == root and d in _SKIP_DIRS)
                         and (exclude is None or Path(dirpath, d) != exclude))
        for f in sorted(files):
            if not f.startswith("."):
                st = os.stat(os.path.join(dirpath, f))
                h.update(f"{os.path.relpath(os.path.join(dirpath, f), root)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    for p in (settings.camera, settings.eyes, settings.markers, settings.aois):
        if p is not None:
            p_stat = os.stat(p) if os.path.exists(p) else None
            size_time = p_stat and (p_stat.st_size, p_stat.st_mtime_ns)
            h.update(f"{Path(p).resolve()}:{size_time}\n".encode())
    h.update(json.dumps(settings.fingerprint_params(), sort_keys=True, default=str).encode())
    return h.hexdigest()


def check_out_folder(out: Path) -> None:
    """Refuse an output folder that is a session folder or inside one: the batch would write its
    outputs into that session (and skip it, as a session is not searched inside).

    Raises:
        UserError: ``out`` or a folder above it holds a session manifest.
    """
    for d in (out, *out.parents):
        if (d / MANIFEST).is_file():
            raise UserError(f"-o {out}: is {'a session folder' if d == out else f'inside the session folder {d}'} "
                            f"(it has {MANIFEST}); batch would write into that session: choose a folder outside "
                            "every session")


# --- the batch -------------------------------------------------------------------------------------

def _plan(paths, out: Path, settings: BatchSettings) -> tuple[dict, list, list]:
    """Each session's status and the tasks to run: a session done earlier with the same
    fingerprint (and its summary.json there) is skipped; every other one is marked pending."""
    sessions = find_sessions(paths, exclude=out)
    earlier = earlier_statuses(out)
    names = output_names(sessions, {s: st["name"] for s, st in earlier.items()})
    statuses, tasks, skipped = {}, [], []
    for s in sessions:
        name, st = names[s], earlier.get(s)
        owner = lock_owner(out / name)
        if owner is not None:                                   # a worker of another batch holds it: not twice
            log.warning("%s: being processed by %s (its lock file): left to it", name, owner)
            statuses[name] = dict(st or {}, name=name, session=str(s), state="running",
                                  reason=f"being processed by another batch's worker ({owner})")
            continue
        remove_temporaries(out / name, [STATUS_FILE])          # left by a worker killed while writing it
        fp = session_fingerprint(s, settings, out)
        same = st is not None and st["state"] == "done" and st.get("fingerprint") == fp
        lost = missing_output(out / name) if same else None
        if not settings.force and same and lost is None and st is not None:   # (same: st is set)
            log.info("%s: done earlier and unchanged: skipped", name)
            statuses[name] = st
            skipped.append(name)
            continue
        why = ("new" if st is None else "forced" if settings.force else f"done earlier, but {lost}" if same else
               "changed" if st["state"] == "done" else
               f"{st['state']} in the earlier run" + (f" ({st['reason']})" if st.get("reason") else ""))
        log.info("%s: %s: to do", name, why)
        statuses[name] = {"version": 1, "name": name, "session": str(s), "fingerprint": fp, "state": "pending",
                          "reason": None, "why": one_line(why, 300)}
        write_status(out / name, statuses[name])
        tasks.append(SessionTask(name, str(s), str(out / name), settings, fp))
    return statuses, tasks, skipped


def _lost(task: SessionTask, exc: BaseException) -> dict:
    """The failed status of a session whose worker never returned (written by the coordinator)."""
    kind = type(exc).__name__
    why = str(exc) if isinstance(exc, WorkerLost) else (
        f"its worker died while processing it too often (Dask {kind}: killed, or out of memory?)"
        if kind == "KilledWorker" else f"the cluster lost it ({kind}: {exc})")
    st = dict(read_status(Path(task.out)) or {}, version=1, name=task.name, session=task.session,
              fingerprint=task.fingerprint, state="failed", reason=one_line(why, REASON_CHARS), finished=time.time())
    write_status(Path(task.out), st)
    return st


def _interrupted(out: Path, statuses: dict, local: bool, ours) -> None:
    """After Ctrl-C: each session of this run (``ours``: names) as its file has it; a local
    session whose worker was stopped goes back to ``pending`` (a Dask worker finishes its session
    and writes it)."""
    for name in ours:
        st = read_status(out / name)
        if st is None:
            continue
        if local and st["state"] == "running":
            st.update(state="pending", reason="interrupted while running; the next run does it again")
            write_status(out / name, st)
        statuses[name] = st


def run_batch(paths, out, settings: BatchSettings = BatchSettings(), workers: int | None = None,
              scheduler: str | None = None, progress=None, on_status=None) -> BatchResult:
    """Process every session under ``paths`` (``find_sessions``) into ``out/NAME``, as
    ``process_session`` would with ``settings``, in parallel; then write the batch report
    (``batch_report.write_batch_report``).

    Args:
        workers: local worker processes (default: one per core); ignored with ``scheduler``.
        scheduler: a Dask scheduler's address (``tcp://HOST:PORT``): run there instead.
        progress: ``progress(done, total)`` over the sessions (those skipped count as done).
        on_status: called with each session's final status dict as it arrives.

    Returns:
        BatchResult; ``interrupted`` when Ctrl-C stopped it (the statuses on disk say where).

    Raises:
        UserError: no session found, ``out`` inside a session, a Dask scheduler unreachable or
            Dask not installed.
    """
    t0 = time.perf_counter()
    out = Path(out).resolve()                   # workers may run elsewhere: absolute paths
    check_out_folder(out)
    runner = DaskRunner(scheduler) if scheduler else LocalRunner(workers or os.cpu_count() or 1)
    try:
        out.mkdir(parents=True, exist_ok=True)
        statuses, tasks, skipped = _plan(paths, out, settings)
        res = BatchResult(out, statuses, skipped)
        write_index(out, statuses, settings.fingerprint_params())
        if tasks:
            log.info("%d session(s) to process on %s", len(tasks), runner.describe())
        n_done = len(skipped)
        if progress is not None:
            progress(n_done, len(statuses))
        try:
            for task, result in runner.run(tasks) if tasks else ():
                statuses[task.name] = result if isinstance(result, dict) else _lost(task, result)
                write_index(out, statuses, settings.fingerprint_params())
                n_done += 1
                if progress is not None:
                    progress(n_done, len(statuses))
                if on_status is not None:
                    on_status(statuses[task.name])
        except KeyboardInterrupt:
            runner.stop()
            res.interrupted = True
            _interrupted(out, statuses, isinstance(runner, LocalRunner), [t.name for t in tasks])
            write_index(out, statuses, settings.fingerprint_params())
        write_batch_report(out, statuses)
    finally:
        if isinstance(runner, DaskRunner):
            runner.close()
    res.seconds = time.perf_counter() - t0
    return res


def format_summary(res: BatchResult) -> str:
    """The line ``batch`` ends with: how many sessions were done, skipped, failed, not done."""
    counts = Counter(s["state"] for s in res.statuses.values())
    parts = [f"{counts.get('done', 0)} done" + (f" ({len(res.skipped)} unchanged, skipped)" if res.skipped else ""),
             f"{counts.get('failed', 0)} failed"]
    if counts.get("partial"):
        parts.insert(1, f"{counts['partial']} partial (a step failed)")
    left = counts.get("pending", 0) + counts.get("running", 0)
    if left:
        parts.append(f"{left} not finished (interrupted: run the same command again to resume)")
    n_targets = sum(s.get("n_targets", 0) for s in res.statuses.values() if s["state"] in ("done", "partial"))
    return (f"batch: {len(res.statuses)} session(s): {', '.join(parts)}; {n_targets} target(s); "
            f"{res.seconds:.0f} s; report {res.out / 'batch_report.html'}")
