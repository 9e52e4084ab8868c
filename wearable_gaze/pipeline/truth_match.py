"""Estimates paired with a simulated session's true targets (``truth/targets.json``): the one
matching the demo, the report, ``batch``'s report, the tests and the benchmarks use."""

from __future__ import annotations

import numpy as np


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
