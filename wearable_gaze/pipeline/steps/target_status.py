"""A target's status: the one place it is derived (``process``, ``estimate --targets`` and the
live session call ``target_status`` / ``estimate_status``; the CLI table, the report, targets.json
and the live messages print the ``Target.status`` it gave, never one of their own), what each
status means for people (``STATUS_NOTES``) and which statuses are fixated targets (``FIXATED``;
docs/processing.md, "Target statuses")."""

from __future__ import annotations

import numpy as np

from estimator import NEAR_POINT_MM, BinocularSamples, GazeEstimate, Status

OK = Status.OK.value
MOVING = "moving"
UNRESOLVED = "unresolved"
"""A target's status when its 95 % region reaches from the eyes to beyond twice its distance:
the lines fix a direction but not a depth (a still head beyond a few metres), and the point is
no answer to "where did the person look"."""
DIRECTION_ONLY = Status.DIRECTION_ONLY.value
TOO_NEAR = Status.TOO_NEAR.value

FIXATED = (OK, UNRESOLVED, DIRECTION_ONLY, MOVING)
"""The statuses of a fixated target, counted as one in the CLI, the report and summary.json. A
``too-near`` point (the view lines are wrong: docs/importers.md) and an estimate that failed
without a direction (``degenerate``, ``behind``, ``insufficient-data``) are listed, not counted."""

STATUS_NOTES = {
    OK: "a point with its 95 % region",
    UNRESOLVED: "a point whose 95 % region reaches past twice its distance: the direction holds, the depth does not",
    DIRECTION_ONLY: "the view lines fix a direction (its 95 % cone), not a point: the depth interval may have no "
                    "far end",
    MOVING: "a moving target: the point is its path's middle (target_paths.csv)",
    TOO_NEAR: "nearer the eyes than anyone fixates: the view lines are wrong (eye model, visual axes, eye labels); "
              "not a target",
}
"""What each status means, as the report says it beside the status."""


def is_fixated(status: str) -> bool:
    """Whether a target of ``status`` counts as a fixated target (``FIXATED``)."""
    return status in FIXATED


def status_note(status: str) -> str:
    """The sentence the report shows beside ``status`` ('' for one without a note)."""
    return STATUS_NOTES.get(status, "")


def target_status(status: str, position_mm, axes95_mm, samples: BinocularSamples, far_side: float = 1.0) -> str:
    """The status a target is published with: the estimator's, unless its point is nearer the
    eyes than anyone fixates (``too-near``; also for a moving target's point) or a static
    target's 95 % ellipsoid's longest semi-axis, before the error model's far-side stretch
    (``far_side``, ``estimator.errormodel.far_side``: the semi-axes are divided by it), exceeds
    its distance from the eyes (``unresolved``: the far end of its depth interval is unbounded).
    A moving target stays ``moving`` (never ``ok``): its path's covariances (target_paths.csv,
    with the eyes' bias floor) say how well its depth is known. ``direction-only`` (no point)
    stays as it is."""
    if status not in (OK, MOVING) or not np.all(np.isfinite(position_mm)):
        return status
    lines = samples.lines()
    dist = float(np.median(np.einsum("ij,ij->i", np.asarray(position_mm, float) - lines.origins_mm,
                                     lines.directions)))
    if dist < NEAR_POINT_MM:
        return TOO_NEAR
    if status == OK and np.all(np.isfinite(axes95_mm)) and float(np.max(axes95_mm)) / far_side > dist:
        return UNRESOLVED
    return status


def estimate_status(e: GazeEstimate, samples: BinocularSamples) -> str:
    """``target_status`` of a static target's estimate ``e`` from its view lines ``samples``
    (N,): its point, 95 % semi-axes and the error model's far-side stretch, as ``process``'s
    targets and the live session's static targets are published."""
    pos = e.position_mm if e.position_mm is not None else np.full(3, np.nan)
    ellipsoid = e.ellipsoid(0.95) if e.covariance_mm2 is not None else None
    radii = ellipsoid.radii_mm if ellipsoid is not None else np.full(3, np.nan)
    far = float(e.info.get("error_model", {}).get("far_side_factor", 1.0))
    return target_status(e.status.value, pos, radii, samples, far)
