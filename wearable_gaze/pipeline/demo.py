"""``wearable-gaze demo``: simulate the default session (lab-walkabout), process it end to end,
and print each target's estimate next to the truth and the Cramér-Rao bound.

It says first where it writes (a fresh folder unless ``--out`` names one), shows each step's
progress on stderr, reuses an earlier demo's results only when asked (``--out DIR --reuse``),
and ends with how to open the report."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..formats.session import load_session
from ..formats.truth import read_truth_targets
from ..progress import progress_bar
from ..sim.scenario import resolve
from ..sim.simulate import simulate
from .process.session import process_session
from .process.stepcache import format_result
from .report.truth_match import TruthFrame, match_positions

DEMO_PREFIX = "wearable-gaze-demo-"


def fresh_folder(base: Path, now: datetime | None = None) -> Path:
    """A folder name in ``base`` that does not exist yet: wearable-gaze-demo-YYYYmmdd-HHMMSS
    (local time), with -2, -3, ... appended when that one exists."""
    stem = DEMO_PREFIX + (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    out, k = Path(base) / stem, 1
    while out.exists():
        k += 1
        out = Path(base) / f"{stem}-{k}"
    return out


def demo_folder(out, reuse: bool, seed: int, duration_s: float, base: Path | None = None) -> tuple[Path, bool]:
    """Where the demo writes, and whether it reuses an earlier demo's session there.

    ``out`` None: a fresh folder in ``base`` (default the current one). A given ``out`` that
    holds anything is refused unless ``reuse``; with ``reuse`` its session must be a demo's of
    the same seed and duration.

    Raises:
        UserError: ``reuse`` without ``out``; an ``out`` in use without ``reuse``; an ``out``
            whose session is not this demo's.
    """
    if out is None:
        if reuse:
            raise UserError("--reuse needs --out DIR, the folder of an earlier demo")
        return fresh_folder(Path.cwd() if base is None else base).absolute(), False
    out = Path(out).absolute()
    session = out / "session" / "session.json"
    if not reuse:
        if session.is_file():
            raise UserError(f"--out {out}: holds an earlier demo's results; add --reuse to use them again, or choose "
                            "a new folder (leave --out out for a fresh one)")
        if out.is_dir() and any(out.iterdir()):
            raise UserError(f"--out {out}: is not empty; choose a new folder (leave --out out for a fresh one)")
        return out, False
    if not session.is_file():
        if out.is_dir() and any(out.iterdir()):
            raise UserError(f"--out {out}: holds no demo session (session/session.json) to reuse; choose a new "
                            "folder, or leave --out out for a fresh one")
        return out, False
    man = load_session(out / "session").manifest
    was = (man.get("seed"), float(man.get("scenario", {}).get("duration_s", -1)))
    if was != (seed, float(duration_s)):
        raise UserError(f"--out {out}: its demo has seed {was[0]} and {was[1]:g} s, not seed {seed} and "
                        f"{duration_s:g} s; pass --seed {was[0]} --duration {was[1]:g} to reuse it, or choose a new "
                        "folder")
    return out, True


@contextmanager
def _announce(what: str, err):
    """A line on ``err`` when a step starts and when it ends (with its time), a bar between
    them on a terminal: progress that a log or a pipe shows too."""
    t0 = time.perf_counter()
    print(f"demo: {what} ...", file=err, flush=True)
    with progress_bar(what, 1) as cb:
        yield cb
    print(f"demo: {what} done ({time.perf_counter() - t0:.1f} s)", file=err, flush=True)


STEP_NAMES = {"camera": "calibrating the scene camera", "eyes": "calibrating the eyes",
              "tracking": "tracking the head in the scene video", "viewlines": "view lines",
              "targets": "fixations and 3D targets", "export": "per-sample gaze and exports",
              "report": "plots, overlay and report"}


def run_demo(out=None, seed: int = 0, duration_s: float = 20.0, reuse: bool = False, resolution=None,
             err=None) -> int:
    """``wearable-gaze demo``: simulate the default session into OUT/session, process it into
    OUT/processed and print each target next to the truth.

    Args:
        out: the folder; None: a fresh ./wearable-gaze-demo-YYYYmmdd-HHMMSS. A given one must be
            new or empty unless ``reuse``.
        reuse: use the session and the processed steps an earlier demo left in ``out``.
        resolution: (width, height) of the scene video (default the scenario's 1280x720).
        err: where progress goes (default stderr); the results go to stdout, whose first line
            names the folder and whose last tells how to open the report.

    Returns:
        The exit status: 2 when no target could be estimated, else 0.

    Raises:
        UserError: as ``demo_folder``; a bad seed or duration (before anything is written).
    """
    err = sys.stderr if err is None else err
    t0 = time.perf_counter()
    out, reusing = demo_folder(out, reuse, seed, duration_s)
    scenario = None if reusing else resolve("lab-walkabout", duration_s, resolution)   # checked before any output
    print(f"wearable-gaze demo: writing into {out}" + (" (reusing its earlier results)" if reusing else ""))
    print("a simulated lab session (markers on the walls, four targets at 0.5-4 m, head sway, 1 deg eye noise, "
          f"{duration_s:g} s), processed end to end; progress on stderr.\n")
    session = out / "session"
    if scenario is not None:                      # not reusing
        with _announce(f"simulating {duration_s:g} s of scene video and eye data", err) as cb:
            simulate(scenario, session, seed, cb)
    res = process_session(session, out / "processed",
                          progress_factory=lambda name: _announce(str(STEP_NAMES.get(name, name)),
                                                                  err))
    if res.skipped:
        print(f"demo: reused, not redone: {', '.join(res.skipped)}", file=err)
    print(format_result(res))
    _compare(res, read_truth_targets(session / "truth" / "targets.json"), TruthFrame.from_record(
        res.summary.get("truth_frame")))
    for p in res.problems:
        print(f"problem: {p}")
    report = res.out / "report.html"
    print(f"\ndone in {time.perf_counter() - t0:.0f} s. To see it in 3D: pip install 'wearable-gaze[rerun]', then "
          f"wearable-gaze process {session} -o {res.out} --rerun demo.rrd && rerun demo.rrd")
    if "report" in res.summary and report.is_file():
        print(f"open the report in a browser: {report.as_uri()}")
    else:
        print(f"no report was written (see the problems above); the results are in {res.out}")
    return res.exit_status                                    # 2 no target could be estimated, 3 a step failed


def _compare(res, truth: list, frame: TruthFrame | None = None) -> None:
    """Each true target beside its estimate, the error and the Cramér-Rao bound; the truth moved
    into the world of the map used first (``frame``; None: the truth's own)."""
    print("\ncompared with the truth:")
    if frame is not None:
        print(frame.note())
        if frame.T_map_from_truth is None:
            return
        truth = frame.targets(truth)
    print(f"{'true target':>11} {'true position mm':>24} {'estimate mm':>24} {'error mm':>9} {'CRB mm':>7}")
    found = res.found
    for tt, k in match_positions([t.position_mm for t in found], truth, [t.index for t in found]):
        X = np.asarray(tt["position_mm"])
        if k is None:
            print(f"{tt['index']:>11} {X[0]:>7.0f} {X[1]:>7.0f} {X[2]:>8.0f}   not found")
            continue
        E = found[k].position_mm
        print(f"{tt['index']:>11} {X[0]:>7.0f} {X[1]:>7.0f} {X[2]:>8.0f} {E[0]:>7.0f} {E[1]:>7.0f} {E[2]:>8.0f} "
              f"{np.linalg.norm(E - X):>9.1f} {found[k].crb_mm:>7.1f}")
