"""Estimation in the live session (docs/live.md, The loop): the live loop's names for
``pipeline.live_estimation``, where the estimation lives so that ``process`` can re-run it on a
live recording (``pipeline.live_replay``)."""

from __future__ import annotations

from ..pipeline.live_estimation import (
    MAX_END_LINES,
    MAX_MOTION_KNOTS,
    SIGMA_DEG,
    FinishedFixation,
    GazeEstimation,
    LiveEstimate,
    RayEyes,
    TargetIds,
    lines_to_samples,
    warm_up,
    world_sample,
)

__all__ = ["MAX_END_LINES", "MAX_MOTION_KNOTS", "SIGMA_DEG", "FinishedFixation", "GazeEstimation",
           "LiveEstimate", "RayEyes", "TargetIds", "lines_to_samples", "warm_up", "world_sample"]
