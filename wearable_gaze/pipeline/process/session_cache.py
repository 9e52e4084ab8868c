"""The values ``process`` works on: the session's files (``SessionFiles``, resolved once from its
manifest) and ``SessionCache``, the one explicit cache of the session's inputs and the steps'
outputs as values, each read once, only when a step that runs needs it; it also gives each step
its inputs (``pipeline.process.session_steps``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import cast

import numpy as np

from calibration.camera import CameraCalibration
from estimator import BinocularSamples
from tracking.markermap import MarkerMap

from ...formats.camera import load_camera
from ...formats.eye_rays import read_eye_rays
from ...formats.eye_samples import EyeSamples, read_eye_csv
from ...formats.eyes import load_eyes
from ...formats.marker_detections import NAME as DETECTIONS
from ...formats.marker_detections import MarkerDetections, read_marker_detections
from ...formats.markermap import load_marker_map
from ...formats.poses import read_poses_csv
from ...formats.sfmmap import load_sfm_map
from ...formats.targets import read_targets
from ...formats.viewlines import read_viewlines_csv
from ...formats.walls import read_walls
from ..report.page import OverlayInputs, load_truth, session_title
from ..report.truth_match import TruthFrame
from ..steps.aoi import aoi_outlines
from ..steps.calibrate import read_eye_recordings
from ..steps.device import device_points, report_notes
from ..steps.errorbudget import targets_bias_note
from ..types import Poses, Target
from .options import report_truth
from .session_steps import (
    BUILT_MAP,
    ExportInputs,
    EyesInputs,
    ReportInputs,
    TargetsInputs,
    TrackingInputs,
    ViewlinesInputs,
)
from .stepconf import ProcessConfig


@dataclass(frozen=True)
class SessionFiles:
    """The session's files, resolved once from its manifest (None: the session has none)."""

    root: Path
    camera_views: Path
    eye_calibration: Path
    has_recording: bool
    video: Path | None
    markers: Path | None
    stamps: Path | None
    eye_samples: Path | None
    eye_rays: Path | None = None            # an imported session: the device's rays, head frame
    head_poses: Path | None = None          # ... the device's head poses
    device_gaze: Path | None = None         # ... the device's own 3D gaze (comparison only)
    pose_source: str | None = None          # ... 'device', 'scene_video' or 'still_head'
    eye_rate_hz: float | None = None
    import_report: Path | None = None
    clock_offset_s: float = 0.0             # ... the device's clock at session time 0, s
    truth_targets: Path | None = None       # a simulated session's truth, shown in the report
    truth_head_poses: Path | None = None
    truth_map: Path | None = None           # ... its true marker map (the truth's frame)
    truth_moved: Path | None = None         # ... the markers moved during it
    live_poses: Path | None = None          # a live --device recording: the pose each sample took live

    @classmethod
    def of(cls, s) -> SessionFiles:
        """The files of a loaded session ``s`` (``formats.session.load_session``)."""
        files, source = s.manifest["files"], s.manifest.get("source", {})
        return cls(root=s.root, camera_views=s.root / files.get("camera_views", "calibration/camera"),
                   eye_calibration=s.root / files.get("eye_calibration", "calibration/eye"),
                   has_recording=s.manifest.get("has_recording", True), video=s.path("scene_video"),
                   markers=s.path("marker_map"), stamps=s.path("scene_timestamps"),
                   eye_samples=s.path("eye_samples"), eye_rays=s.path("eye_rays"),
                   head_poses=s.path("head_poses"), device_gaze=s.path("device_gaze"),
                   pose_source=source.get("pose_source"), eye_rate_hz=s.manifest.get("eye_rate_hz"),
                   import_report=s.path("import_report"),
                   clock_offset_s=float(source.get("clock_offset_s", 0.0)),
                   truth_targets=s.path("truth_targets"), truth_head_poses=s.path("truth_head_poses"),
                   truth_map=s.path("truth_markers") or (s.path("truth_targets") and s.path("marker_map")),
                   truth_moved=s.path("truth_moved_markers"), live_poses=s.path("live_poses"))


class SessionCache:
    """The session's inputs and the steps' outputs as values, each read once, when a step first
    needs it: from the session, or from the file a step wrote or was given (what a cached step
    leaves: a run gives the same results whether the steps before it ran or were cached). A step
    that ran leaves what it found here (``targets``, a built ``marker_map``): it is not read
    back. The ``*_inputs`` methods give each step its inputs, called only when it runs.

    Args:
        files: the session's files; out: the output folder.
        camera, eyes: the calibration files given in place of the steps (None: calibrated).
    """

    def __init__(self, files: SessionFiles, out: Path, camera: Path | None, eyes: Path | None):
        self.files, self.out = files, out
        self.camera_given, self.eyes_given = camera, eyes
        self.camera_path = camera or out / "camera.json"
        self.eyes_path = eyes or out / "eyes.json"
        self.poses_path = out / "poses.csv"
        self.raw_viewlines = out / ".viewlines_unsegmented.csv"        # the view lines, before segmenting
        self.viewline_counts = out / ".viewlines_counts.json"

    @cached_property
    def camera(self) -> CameraCalibration:
        return load_camera(self.camera_path)

    @cached_property
    def eyes(self) -> list:
        return load_eyes(self.eyes_path)

    @cached_property
    def eye_samples(self) -> EyeSamples:
        return read_eye_csv(cast(Path, self.files.eye_samples))[0]

    @cached_property
    def eye_rays(self) -> BinocularSamples:
        return read_eye_rays(cast(Path, self.files.eye_rays))

    @cached_property
    def marker_map(self) -> MarkerMap:
        """The map given, or the one built from the video (``BUILT_MAP``)."""
        return load_marker_map(self.files.markers or self.out / BUILT_MAP)

    @cached_property
    def poses(self) -> Poses:
        return Poses(*read_poses_csv(self.poses_path))

    @cached_property
    def detections(self) -> MarkerDetections | None:
        """The markers the tracking step detected in each frame it tracked (``DETECTIONS``), or
        None: it kept none (a device's or a still head's poses, a markerless map)."""
        path = self.out / DETECTIONS
        return read_marker_detections(path) if path.is_file() else None

    @cached_property
    def targets(self) -> list[Target]:
        return [Target.from_row(r) for r in read_targets(self.out / "targets.json")]

    def has_map(self) -> bool:
        """A marker map was given or built."""
        return self.files.markers is not None or (self.out / BUILT_MAP).is_file()

    def eye_paths(self) -> list:
        """The files the view lines are made from."""
        f = self.files
        return [f.eye_rays] if f.eye_rays is not None else [f.eye_samples, self.eyes_path]

    def eyes_inputs(self) -> EyesInputs:
        recordings = read_eye_recordings(read_walls(self.files.eye_calibration))
        return EyesInputs(self.camera, recordings, self.eyes_path)

    def video_inputs(self, room=None) -> TrackingInputs:
        """The scene video tracked in ``room`` (None: in the map built from it first)."""
        return TrackingInputs(self.poses_path, video=self.files.video, stamps=self.files.stamps,
                              camera=self.camera, room=room, camera_path=self.camera_path)

    def marker_inputs(self) -> TrackingInputs:
        return self.video_inputs(self.marker_map)

    def markerless_inputs(self, sfm_map: Path) -> TrackingInputs:
        return self.video_inputs(load_sfm_map(sfm_map)[0])

    def still_head_inputs(self) -> TrackingInputs:
        return TrackingInputs(self.poses_path, still_t_s=self.eye_rays.t_s)

    def viewlines_inputs(self) -> ViewlinesInputs:
        if self.files.eye_rays is not None:
            rays = self.eye_rays
            return ViewlinesInputs(self.poses, self.poses_path, self.raw_viewlines, eye_rays=rays,
                                   counts=self.viewline_counts)
        samples, eyes = self.eye_samples, self.eyes
        return ViewlinesInputs(self.poses, self.poses_path, self.raw_viewlines, samples, eyes,
                               counts=self.viewline_counts)

    def targets_inputs(self, prior, error_model, depth: str | None) -> TargetsInputs:
        samples = read_viewlines_csv(self.raw_viewlines)[0].samples
        device_gaze = self.files.device_gaze
        live = self.files.live_poses
        return TargetsInputs(samples, prior, error_model, depth, self.out, device_gaze,
                             self.poses if device_gaze is not None else None, live,
                             self.eye_rays if live is not None else None)

    def export_inputs(self, with_camera: bool) -> ExportInputs:
        """``with_camera``: the 2D gaze too (the camera is calibrated)."""
        imported = self.files.eye_rays is not None
        rays = self.eye_rays if imported else None
        samples, eyes = (None, None) if imported else (self.eye_samples, self.eyes)
        camera = self.camera if with_camera else None
        return ExportInputs(self.poses, self.targets, self.out, camera,
                            self.files.clock_offset_s, samples, eyes, rays)

    def overlay_inputs(self) -> OverlayInputs:
        camera = self.camera
        eyes = self.eyes if self.eyes_path.is_file() else None
        return OverlayInputs(camera, eyes, self.eye_samples, self.marker_map if self.has_map() else None,
                             cast(Path, self.files.video), self.detections)

    def report_inputs(self, conf: ProcessConfig, frame: TruthFrame | None,
                      overlay: bool) -> ReportInputs:
        """``overlay``: the overlay can be drawn (the camera's calibration and raw eye samples)."""
        f = self.files
        truth, truth_notes = report_truth(load_truth(f.truth_targets, f.truth_head_poses), frame)
        points: np.ndarray | None
        if conf.sfm_map is not None:
            points = load_sfm_map(conf.sfm_map)[0].points_world
        else:
            points = device_points(f.root)
        mm = self.marker_map if self.has_map() else None
        no_overlay = f.eye_rays is not None and conf.overlay    # asked for, but an import has none
        notes = report_notes(f.pose_source, no_overlay, f.import_report)
        notes += targets_bias_note(self.out / "targets.json")
        return ReportInputs(self.out, session_title(f.root), notes + truth_notes, truth, mm, points,
                            aoi_outlines(conf.aoi_specs, mm),
                            self.overlay_inputs if overlay else None)
