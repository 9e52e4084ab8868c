"""``wearable-gaze demo``: simulate the default session (lab-walkabout), process it end to end,
and print each target's estimate next to the truth and the Cramér-Rao bound."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..formats.truth import read_truth_targets
from ..progress import progress_bar
from ..sim.simulate import simulate_scenario
from .process import format_result, process_session


def match_positions(positions, truth: list, ids=None) -> list:
    """Pairs (truth entry, index into ``positions`` or None): each true fixed target (a truth
    entry with ``position_mm``) with the nearest estimate (M, 3) within 30 % of its distance
    + 100 mm; each id of ``ids`` (M,) (default: each estimate) used once."""
    P = np.asarray(positions, float).reshape(-1, 3)
    ids = list(range(len(P))) if ids is None else list(ids)
    pairs, used = [], set()
    for tt in truth:
        if "position_mm" not in tt:
            continue
        X = np.asarray(tt["position_mm"])
        best = None
        for k, p in enumerate(P):
            if ids[k] in used or not np.isfinite(p[0]):
                continue
            d = np.linalg.norm(p - X)
            if best is None or d < best[0]:
                best = (d, k)
        if best is not None and best[0] < 0.3 * np.linalg.norm(X) + 100:
            used.add(ids[best[1]])
            pairs.append((tt, best[1]))
        else:
            pairs.append((tt, None))
    return pairs


def match_targets(found: list, truth: list) -> list:
    """``match_positions`` for target records (targets.json, summary.json, live target messages:
    ``target``, ``position_mm``, null for none): pairs (truth entry, record or None)."""
    pairs = match_positions([f["position_mm"] or [np.nan] * 3 for f in found], truth, [f["target"] for f in found])
    return [(tt, None if k is None else found[k]) for tt, k in pairs]


def run_demo(out: Path, seed: int = 0, duration_s: float = 20.0) -> int:
    """Simulate the default session into OUT/session (once), process it into OUT/processed and print each
    target next to the truth. Returns the exit status: 2 when no target could be estimated, else 0."""
    t0 = time.perf_counter()
    session = out / "session"
    print("wearable-gaze demo: a simulated lab session (markers on the walls, four targets at 0.5-4 m, head "
          f"sway, 1 deg eye noise, {duration_s:.0f} s), processed end to end.\n")
    if not (session / "session.json").is_file():
        with progress_bar("simulating", 1) as cb:
            simulate_scenario("lab-walkabout", session, seed, duration_s, None, cb)
        print(f"simulated session: {session}")
    res = process_session(session, out / "processed", progress_factory=lambda name: progress_bar(name, 1))
    print(format_result(res))
    truth = read_truth_targets(session / "truth" / "targets.json")
    print("\ncompared with the truth:")
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
    for p in res.problems:
        print(f"problem: {p}")
    if "report" in res.summary:
        print(f"\nopen {res.out / 'report.html'} in a browser to see the result ({time.perf_counter() - t0:.0f} s)")
    return res.exit_status                                    # 2 when no target could be estimated
