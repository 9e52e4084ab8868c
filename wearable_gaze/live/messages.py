"""The live session's messages, version 1 (docs/live.md, Messages): an estimate after each
sample that has one, a target when a fixation ends. Built here, encoded and sent by
``publish.Publisher``."""

from __future__ import annotations

import logging

from ..pipeline.types import Target
from .estimation import LiveEstimate

log = logging.getLogger(__name__)

MESSAGE_VERSION = 1


def estimate_message(e: LiveEstimate, latency_ms: float) -> dict:
    """An ``estimate`` message; ``latency_ms`` from the sample's arrival to now."""
    r = e.radius95_mm                                  # an eigen-decomposition: computed once
    return {"version": MESSAGE_VERSION, "type": "estimate", "t": round(e.t_s, 4), "fixation": e.fixation,
            "position_mm": [round(v, 1) for v in e.position_mm],
            "radius95_mm": None if r is None else round(r, 1),
            "n_samples": e.n_samples, "latency_ms": round(latency_ms, 2)}


def target_message(t: Target) -> dict:
    """A ``target`` message for a finished fixation's target (``GazeEstimation.end_fixation``):
    its id is ``t.index``, its fixation ``t.fixations[0]``."""
    return {"version": MESSAGE_VERSION, "type": "target", "target": t.index, "fixation": t.fixations[0],
            "t_start": round(t.t_start, 4), "t_end": round(t.t_end, 4),
            "position_mm": [round(v, 1) for v in t.position_mm],
            "ellipsoid95_radii_mm": None if t.covariance_mm2 is None else [round(float(v), 1) for v in t.axes95_mm],
            "n_samples": t.n_samples, "method": t.method}
