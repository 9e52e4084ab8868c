"""The settings of ``process``'s steps (docs/processing.md): one frozen ``ProcessConfig`` built
once from ``process_session``'s options at the boundary, a few named presets (``PRESETS``, as
hloc's ``confs``), and the small frozen configuration each step's ``run`` takes
(``pipeline.process.session_steps``), derived from it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from estimator.deprecation import renamed_kwargs
from estimator.merge import STILL_HEAD_MERGE_S
from estimator.segments import SegmentConfig
from tracking.timeline import MAX_POSE_GAP_S


@dataclass(frozen=True)
class CameraConfig:
    """The camera step: the lens ``model`` ('pinhole', 'fisheye') and the board views kept
    (``max_views``) when more are found (``calibrate.calibrate_camera_views``)."""

    model: str = "pinhole"
    max_views: int = 40


@renamed_kwargs({"centres": "centers"})
@dataclass(frozen=True)
class EyesConfig:
    """The eyes step: the raw -> image ``model`` ('quadratic', 'cubic', 'tps') and the eyes'
    ``centers`` if known, head frame mm (None: found from two or more wall distances, else a
    nominal headset's; ``calibrate.calibrate_eyes``)."""

    model: str = "quadratic"
    centers: np.ndarray | None = None


@dataclass(frozen=True)
class TrackingConfig:
    """The tracking step.

    Attributes:
        every: track one frame in this many, SLERP the rest (``track.track_video``).
        build_map: (marker side, mm; dictionary name) of a map built from the video before
            tracking (``mapping.build_map_files``), or None.
    """

    every: int = 2
    build_map: tuple | None = None


@dataclass(frozen=True)
class ViewlinesConfig:
    """The view-lines step.

    Attributes:
        max_gap_s: a sample without a head pose within this is dropped and counted, s (0: only
            the poses a live recording took, none interpolated).
        correction_deg: a person's per-eye correction (``formats.person``), or None.
    """

    max_gap_s: float = MAX_POSE_GAP_S
    correction_deg: np.ndarray | None = None


@dataclass(frozen=True)
class ExportConfig:
    """The export step: a person's per-eye correction of the head lines (``formats.person``),
    or None."""

    correction_deg: np.ndarray | None = None


@dataclass(frozen=True)
class TargetsConfig:
    """The targets step: the estimator ``method`` ('voxel', 'ml', 'paper', 'lse'), the angular
    noise of a view line it assumes (``sigma_deg``), the fixation ``segment`` settings, and how
    long before a revisit the target it joins must have been seen (``merge_within_s``:
    ``estimator.merge.STILL_HEAD_MERGE_S`` without head poses; infinity: any time)."""

    method: str = "voxel"
    sigma_deg: float = 1.0
    segment: SegmentConfig = field(default_factory=SegmentConfig)
    merge_within_s: float = float("inf")


@dataclass(frozen=True)
class ReportConfig:
    """The report step.

    Attributes:
        overlay: draw the gaze on the scene video (overlay.mp4).
        overlay_video: also the full-resolution overlay_full.mp4.
        world: what the world frame is, in the report's words (``device.world_words``).
    """

    overlay: bool = True
    overlay_video: bool = False
    world: str = ""


@dataclass(frozen=True)
class ProcessConfig:
    """``process_session``'s settings, built once from its options (docs/processing.md).

    Attributes:
        method, sigma_deg: the targets' estimator and a view line's angular noise, degrees.
        overlay, report: write the overlay video; write the report at all.
        track_every: track one frame in this many.
        segment_config: fixation segmentation (None: the session's eye rate's, ``for_session``).
        person: a person.json whose per-eye correction the view lines get, or None;
            ``correction_deg``: that correction, read once (``formats.person``).
        build_map: (marker side mm, dictionary) of a map to build from the video, or None.
        sfm_map: a markerless map folder to localise the video's frames in, or None.
        overlay_video: the report also writes overlay_full.mp4.
        map_kind: the map tracked in: 'session', 'given', 'built' or 'markerless'
            (``process_options.applicable`` sets it).
        aois: an AOI file (docs/aois.md): the AOI step runs; ``aoi_specs``: its areas, read once.
    """

    method: str = "voxel"
    sigma_deg: float = 1.0
    overlay: bool = True
    report: bool = True
    track_every: int = 2
    segment_config: SegmentConfig | None = None
    person: Path | None = None
    correction_deg: np.ndarray | None = None
    build_map: tuple | None = None
    sfm_map: Path | None = None
    overlay_video: bool = False
    map_kind: str = "session"
    aois: Path | None = None
    aoi_specs: tuple = ()

    def for_session(self, eye_rate_hz: float | None) -> ProcessConfig:
        """With the segmentation settings resolved: the window follows the eye rate (8 samples
        at 60 Hz, 2 at 10 Hz) unless they were given."""
        if self.segment_config is not None:
            return self
        seg = SegmentConfig.for_rate(eye_rate_hz) if eye_rate_hz else SegmentConfig()
        return dataclasses.replace(self, segment_config=seg)

    def targets_conf(self, still_head: bool = False) -> TargetsConfig:
        """``still_head``: the session has no head poses (its head taken as still)."""
        return TargetsConfig(self.method, self.sigma_deg, self.segment_config or SegmentConfig(),
                             STILL_HEAD_MERGE_S if still_head else float("inf"))

    def tracking_conf(self) -> TrackingConfig:
        return TrackingConfig(self.track_every, self.build_map)

    def viewlines_conf(self, max_gap_s: float = MAX_POSE_GAP_S) -> ViewlinesConfig:
        return ViewlinesConfig(max_gap_s, self.correction_deg)

    def export_conf(self) -> ExportConfig:
        return ExportConfig(self.correction_deg)

    def report_conf(self, world: str) -> ReportConfig:
        return ReportConfig(self.overlay, self.overlay_video, world)

    def person_record(self) -> dict:
        """The person's correction as a step's fingerprint holds it ({} without one)."""
        return {} if self.correction_deg is None else {"person": self.correction_deg.tolist()}


PRESETS = {
    "default": ProcessConfig(),
    "quick": ProcessConfig(method="ml", overlay=False, track_every=3),
    "every_frame": ProcessConfig(track_every=1),
    "no_report": ProcessConfig(report=False),
}
"""Named settings: 'default' (``process``'s own), 'quick' (the ML estimator, no overlay, one
frame in three tracked), 'every_frame' (every frame tracked), 'no_report' (no plots or report)."""


def preset(name: str, **changes: Any) -> ProcessConfig:
    """The preset ``name`` (``PRESETS``) with ``changes`` to its fields.

    Raises:
        KeyError: no such preset.
    """
    return dataclasses.replace(PRESETS[name], **changes)
