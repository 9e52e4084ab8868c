"""The live session's messages, version 1 (docs/live.md, Messages): an estimate after each
sample that has one, a target when a fixation ends (a moving target with its path). Built here, encoded and sent by
``publish.Publisher``."""

from __future__ import annotations

import logging

import numpy as np

from estimator.result import covariance_ellipsoid

from ..pipeline.steps.live_estimation import LiveEstimate
from ..pipeline.types import Target

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
    the target's record (``Target.row``, rounded: the same fields as targets.json, one function
    makes both) after ``version``, ``type`` and ``fixation`` (``t.fixations[0]``). A moving target
    (``t.moving``) has ``"moving": true`` and its path: ``path`` [[t, x, y, z], ...] (s, mm) at the
    path's knots and ``path_radii95_mm`` [[r1, r2, r3], ...], each knot's 95 % ellipsoid semi-axes
    (increasing)."""
    rec = t.row(rounded=True)
    msg = {"version": MESSAGE_VERSION, "type": "target", "target": rec.pop("target"), "fixation": t.fixations[0]}
    msg |= rec
    if t.moving and t.trajectory is not None:
        tr = t.trajectory
        msg["path"] = [[round(float(tk), 4), *(round(float(v), 1) for v in x)]
                       for tk, x in zip(tr.t_s, tr.positions_mm, strict=True)]
        msg["path_radii95_mm"] = [[round(float(v), 1) for v in np.asarray(covariance_ellipsoid(x, c, 0.95).radii_mm)]
                                  for x, c in zip(tr.positions_mm, tr.covariances_mm2, strict=True)]
    return msg
