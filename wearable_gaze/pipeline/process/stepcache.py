"""The steps of ``process``, each cached by a fingerprint of its inputs and settings, and the
rules that keep the output folder consistent (docs/processing.md): which files each step writes,
which steps it needs, and what a step that failed or did not run leaves (nothing).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import UserError
from ...formats.atomic import write_text
from ...formats.jsonio import load_json
from ...formats.marker_detections import NAME as DETECTIONS
from ..report.page import OPTIONAL_FILES as REPORT_OPTIONAL
from ..report.page import REPORT_FILES
from ..steps.aoi import AOI_OUTPUTS

log = logging.getLogger(__name__)

STEPS = ("camera", "eyes", "tracking", "viewlines", "targets", "export", "aoi", "report")
ON_REQUEST = ("aoi",)
"""The steps that run only when asked for (``process --aois``)."""
# the files each step writes into the output folder ...
OUTPUTS = {
    "camera": ("camera.json", "camera_undistorted.png"),
    "eyes": ("eyes.json",),
    "tracking": ("poses.csv", "built_map.json", DETECTIONS),
    "viewlines": (".viewlines_unsegmented.csv", ".viewlines_counts.json"),
    "targets": ("viewlines.csv", "estimates.csv", "targets.csv", "targets.json", "target_labels.npy",
                "device_comparison.csv", "target_paths.csv", "fixations.csv"),
    "export": ("gaze.csv", "targets.ply"),
    "aoi": AOI_OUTPUTS,
    "report": REPORT_FILES,
}
# ... and the steps whose outputs it reads
NEEDS = {"camera": (), "eyes": ("camera",), "tracking": ("camera",), "viewlines": ("eyes", "tracking"),
         "targets": ("viewlines",), "export": ("targets",), "aoi": ("targets",), "report": ("targets",)}
# written or not: not needed to skip a step
OPTIONAL = (*REPORT_OPTIONAL, "device_comparison.csv", "target_paths.csv", "built_map.json", DETECTIONS)
OTHER_FILES = ("summary.json", ".steps.json")
GOOD = ("done", "cached", "external", "device")   # usable: outputs, a file given instead, or the device's own
EXIT_NO_TARGET = 2
"""``process``'s exit status when no target could be estimated (as for a bad input)."""
EXIT_PARTIAL = 3
"""... when targets were estimated but a step failed (or was not done as it needs a failed one):
the output folder lacks that step's files, e.g. no gaze.csv or report.html (docs/processing.md)."""



@dataclass
class ProcessResult:
    """What ``process_session`` did.

    Attributes:
        out: the output folder.
        found: the targets estimated in this run (``Target``); empty when the targets step
            failed or could not run. ``targets``: the same as rows of targets.json.
        problems: one line per problem, ``"step: what went wrong"``.
        skipped: steps whose outputs were up to date.
        timings: seconds per step run.
        summary: the contents of summary.json.
        status: per step: done, cached, external (a file given instead), failed, not_done (a step
            it needs failed), no_recording (a calibration-only session), or absent (not asked for).
        removed: outputs of an earlier run removed because this run invalidated them.
    """

    out: Path
    found: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)
    status: dict = field(default_factory=dict)
    removed: list = field(default_factory=list)

    @property
    def targets(self) -> list[dict]:
        """This run's targets as rows of targets.json (as summary.json holds them)."""
        return [t.row() for t in self.found]

    @property
    def failed(self) -> list:
        return [s for s in STEPS if self.status.get(s) == "failed"]

    @property
    def not_done(self) -> list:
        return [s for s in STEPS if self.status.get(s) == "not_done"]

    @property
    def outcome(self) -> str:
        """'ok': targets, and every step that ran succeeded; 'partial': targets, but a step
        failed or was not done (its outputs are missing); 'no_targets': no fixated target
        (``Target.fixated``: a too-near point is listed, not counted)."""
        if not any(t.fixated for t in self.found):
            return "no_targets"
        return "partial" if self.failed or self.not_done else "ok"

    @property
    def exit_status(self) -> int:
        """0 ok, ``EXIT_NO_TARGET`` (2) no target, ``EXIT_PARTIAL`` (3) partial (docs/processing.md)."""
        return {"ok": 0, "no_targets": EXIT_NO_TARGET, "partial": EXIT_PARTIAL}[self.outcome]


def fingerprint(paths, params) -> str:
    h = hashlib.sha1()
    for p in paths:
        p = Path(p)
        if p.is_dir():
            for q in sorted(p.rglob("*")):
                if q.is_file():
                    st = q.stat()
                    h.update(f"{q}:{st.st_size}:{st.st_mtime_ns}".encode())
        elif p.exists():
            st = p.stat()
            h.update(f"{p}:{st.st_size}:{st.st_mtime_ns}".encode())
        else:
            h.update(f"{p}:missing".encode())
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    return h.hexdigest()


def content_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def changed_output(out: Path, recorded: dict) -> str | None:
    """The first output of a step whose content is no longer what the step wrote (``recorded``:
    {file name: SHA-256}), with what happened to it, or None: all as written."""
    for name, digest in recorded.items():
        p = out / name
        if not p.is_file():
            return f"{name} is gone"
        if content_digest(p) != digest:
            return f"{name} changed"
    return None


def missing_output(out: Path) -> str | None:
    """What an output folder lacks of a finished run, by name, or None: ``summary.json``, a
    readable ``.steps.json``, ``targets.json``, or a file a step recorded there as written (its
    presence only: a batch skips a finished session without reading its files)."""
    for name in ("summary.json", ".steps.json", "targets.json"):
        if not (out / name).is_file():
            return f"{name} is gone"
    try:
        state = load_json(out / ".steps.json", "steps-state")
    except UserError:
        return ".steps.json is unreadable"
    for entry in state.values():
        for name in entry["outputs"]:
            if not (out / name).is_file():
                return f"{name} is gone"
    return None


class Steps:
    """Runs steps with caching and problem recording, and keeps the output folder consistent:
    a step being redone has no outputs until it succeeds, and the outputs of a step that failed
    or could not run (or depends on one that did) are removed."""

    def __init__(self, out: Path, force: bool, result: ProcessResult, progress_factory, protect=()):
        self.out = out
        self.force = force
        self.result = result
        self.progress_factory = progress_factory
        self.protect = {Path(p).resolve() for p in protect}      # files given as inputs: never removed
        self.state_path = out / ".steps.json"
        self.status = result.status
        self.given: set[str] = set()                              # steps replaced by a file given
        self.current: str | None = None                          # the step running now
        self.outputs: dict = {}                                  # what each step run returned
        self.state = {} if force else self._load_state()

    def _load_state(self) -> dict:
        """{step: {"inputs": fingerprint, "outputs": {file: SHA-256}}} of ``.steps.json``; any
        file that is not one (an older format, a crash, an edit, bytes that are not UTF-8, a
        nesting too deep) is a warning and every step is redone."""
        if not self.state_path.is_file():
            return {}
        try:
            return load_json(self.state_path, "steps-state")
        except UserError as exc:
            log.warning("%s is unreadable (%s); redoing every step", self.state_path, exc)
            return {}

    def run(self, name: str, paths: list, params: dict, step: Callable, conf, inputs: Callable[[], object]) -> bool:
        """Run the step ``step(conf, inputs(), progress)`` unless its fingerprint (the files
        ``paths`` and the settings ``params``) matches the last run's and its outputs are as it
        wrote them. ``inputs`` is called only when the step runs (a cached step reads nothing);
        what the step returns is kept in ``outputs[name]``. Returns True when the outputs are
        usable; a ``UserError`` (from the step or its inputs) is the step's failure."""
        bad = [d for d in NEEDS[name] if self.status.get(d) not in GOOD]
        if bad:
            self.status[name] = "not_done"
            return False
        fp = fingerprint(paths, params)
        if self._cached(name, fp):
            self.result.skipped.append(name)
            self.status[name] = "cached"
            return True
        self.current = name
        self._remove(name)                        # redone: no output of the old run until it succeeds
        t0 = time.perf_counter()
        try:
            with self._progress(name) as progress:
                self.outputs[name] = step(conf, inputs(), progress)
        except UserError as exc:
            self.fail(name, str(exc))
            return False
        finally:
            self.current = None
        self.result.timings[name] = time.perf_counter() - t0
        self.status[name] = "done"
        self.state[name] = {"inputs": fp, "outputs": {o: content_digest(self.out / o) for o in OUTPUTS[name]
                                                      if (self.out / o).is_file()}}
        self._save()
        return True

    def _progress(self, name: str):
        """The step's progress callback in a context (``progress_factory``), or None."""
        if self.progress_factory is not None:
            return self.progress_factory(name)
        return contextlib.nullcontext(None)

    def _cached(self, name: str, fp: str) -> bool:
        """The step's inputs and settings are unchanged (``fp``), and so is every output it
        wrote, by content (a file cut short or edited since is not this step's result: the step
        is redone, with a line saying why)."""
        entry = self.state.get(name)
        needed = [self.out / o for o in OUTPUTS[name] if o not in OPTIONAL]
        if self.force or entry is None or entry["inputs"] != fp or not all(o.is_file() for o in needed):
            return False
        why = changed_output(self.out, entry["outputs"])
        if why is not None:
            log.warning("%s: %s since step '%s' wrote it; redoing the step", self.out, why, name)
            return False
        return True

    def external(self, name, path: Path, load: Callable[[], object]) -> bool:
        """The step is replaced by a file the user gave (``path``; its outputs in OUT are left
        alone), checked once here by reading it (``load()``) rather than by every step that reads
        it."""
        self.given.add(name)
        if not path.is_file():
            self.fail(name, f"{path}: no such file; check the --{name} path, or leave the option out to calibrate "
                            "from the session")
            return False
        try:
            load()
        except UserError as exc:
            self.fail(name, str(exc))
            return False
        self.status[name] = "external"
        return True

    def fail(self, name, message: str | None = None) -> None:
        self.status[name] = "failed"
        if message:
            self.result.problems.append(f"{name}: {message}")
        self._remove(name)

    def finish(self, aborted: bool = False) -> None:
        """Mark what did not run and remove every output that is no longer this run's: of a
        step that failed, of one that needs a failed one, of one not run whose inputs were
        redone. ``aborted``: an exception is on its way out of the step running now. A step run
        only on request (``ON_REQUEST``) and not asked for is not marked."""
        if aborted and self.current is not None:
            self.status[self.current] = "failed"
        for name in STEPS:
            st = self.status.get(name)
            upstream = [self.status.get(d) for d in NEEDS[name]]
            if st is None and name not in ON_REQUEST and any(u not in GOOD for u in upstream):
                if aborted or any(u in ("failed", "not_done") for u in upstream):
                    self.status[name] = "not_done"
            if self.status.get(name) in ("failed", "not_done", "no_recording") or (st is None and "done" in upstream):
                self._remove(name)

    def _remove(self, name) -> None:
        if name in self.given:
            return
        if self.state.pop(name, None) is not None:
            self._save()
        for f in OUTPUTS[name]:
            p = self.out / f
            if p.is_file() and p.resolve() not in self.protect:
                p.unlink()
                self.result.removed.append(p.name)
                log.info("removed %s: step '%s' is not valid in this run", p, name)

    def _save(self):
        write_text(self.state_path, json.dumps(self.state, indent=1))


def _target_line(t) -> str:
    """One target's row of ``format_result``: its point and 95 % semi-axes ('-' without), samples,
    time span, dwell (its fixations' durations summed) and its status (``Target.status``, as
    targets.json and the report have it); a direction-only target's direction, cone and depth
    interval after its status."""
    def num(v, width):
        return f"{v:>{width}.0f}" if np.isfinite(v) else f"{'-':>{width}}"

    x, y, z = (num(v, 8) for v in t.position_mm)
    a1, a2, a3 = (num(v, 6) for v in t.axes95_mm)
    dwell = f"{t.dwell_s:>7.1f}" if np.isfinite(t.dwell_s) else f"{'-':>7}"
    line = (f"{t.index:>6} {x} {y} {z} {a1} {a2} {a3} {t.n_samples:>8} {t.t_start:>5.1f}-{t.t_end:<5.1f} {dwell}  "
            f"{t.status}")
    g = t.direction
    if g is not None and not np.all(np.isfinite(t.position_mm)):
        near, far = g.depth95_mm
        depth = f"{near / 1000:.2f}-{far / 1000:.2f} m" if np.isfinite(far) else f">= {near / 1000:.2f} m"
        line += (f" (direction {g.unit[0]:.3f} {g.unit[1]:.3f} {g.unit[2]:.3f}, 95 % cone {g.cone95_deg:.2f} deg, "
                 f"depth {depth})")
    return line


def format_result(res: ProcessResult) -> str:
    """The text ``process`` prints: this run's targets, and what failed or was not done."""
    n = sum(t.fixated for t in res.found)
    rest = len(res.found) - n
    lines = [f"{n} fixated target(s) in {res.out}" + (f" ({rest} more listed that are no target: status)" if rest
                                                       else "") + ":"]
    lines.append(f"{'target':>6} {'x mm':>8} {'y mm':>8} {'z mm':>8} {'95% semi-axes mm':>20} {'samples':>8} "
                 f"{'time s':>12} {'dwell s':>7}  status")
    lines += [_target_line(t) for t in res.found]
    if res.failed:
        lines.append("FAILED: " + ", ".join(res.failed) + " (the problems are listed on stderr and in summary.json)")
    if res.outcome == "partial":
        lines.append(f"PARTIAL: targets estimated, but not every step succeeded (exit status {res.exit_status})")
    if res.not_done:
        lines.append("not done, as they need a failed step: " + ", ".join(res.not_done))
    if res.removed:
        lines.append(f"removed {len(res.removed)} output(s) of an earlier run that this run invalidated (listed in "
                     "summary.json)")
    if res.skipped:
        lines.append("unchanged, not redone: " + ", ".join(res.skipped) + " (--force redoes them)")
    if "report" in res.summary:
        lines.append(f"report: {res.summary['report']}")
    if "rerun" in res.summary:
        lines.append(f"rerun: {res.summary['rerun']}")
    return "\n".join(lines)
