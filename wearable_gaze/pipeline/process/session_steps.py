"""The steps of ``process`` (docs/processing.md), each ``run_<step>(conf, inputs, progress) ->
outputs``: a plain function of its frozen configuration (``pipeline.process.stepconf``) and its inputs as
typed values, writing its files into the output folder and returning what it found.
``process_session`` calls them in order through ``steps.Steps`` (which caches them); the
step-by-step commands (``calibrate-eyes``, ``viewlines``) call the same functions.

Step 7, the areas of interest, is ``pipeline.steps.aoi``'s ``run`` (through ``run_aoi``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from calibration.camera import CameraCalibration
from estimator import BinocularSamples
from estimator.errormodel import ErrorModel
from estimator.slippage import seen_bias
from tracking.localise import FeatureMap
from tracking.markermap import MarkerMap

from ...errors import UserError
from ...formats.board import BOARD_FILE, read_board
from ...formats.eye_samples import EyeSamples
from ...formats.eyes import write_eyes
from ...formats.jsonio import write_json
from ...formats.marker_detections import NAME as DETECTIONS
from ...formats.marker_detections import write_marker_detections
from ...formats.markermap import load_marker_map
from ...formats.poses import write_poses_csv
from ...formats.viewlines import write_viewlines_csv
from ...progress import Progress
from ..maps.markers import build_map_files
from ..report.page import OverlayInputs, ReportTruth, write_report
from ..steps.aoi import AoiConfig, AoiResult, aoi_step
from ..steps.calibrate import (
    EyeRecordings,
    calibrate_camera_files,
    calibrate_eyes,
    correct_head_lines,
    head_lines_to_world,
    head_view_lines,
    view_lines,
)
from ..steps.device import device_comparison, device_poses, still_head_poses
from ..steps.errorbudget import BiasPrior, session_bias, with_bias
from ..steps.export import export_files, write_fixations_step
from ..steps.fixations import find_targets, write_targets_step
from ..steps.live_replay import replay_recording
from ..steps.segmentation import segment_view_lines
from ..steps.track import frame_times, track_video
from ..types import Poses, TargetsResult, ViewLinesResult
from .stepconf import (
    CameraConfig,
    ExportConfig,
    EyesConfig,
    ReportConfig,
    TargetsConfig,
    TrackingConfig,
    ViewlinesConfig,
)

BUILT_MAP = "built_map.json"
"""The map ``--build-map`` builds from the session's video, in the output folder."""


# --- 1. camera -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraInputs:
    """The session's camera-calibration folder (``views``: its board file and board views) and
    the camera.json to write (``out``)."""

    views: Path
    out: Path


def run_camera(conf: CameraConfig, inputs: CameraInputs, progress: Progress | None = None) -> CameraCalibration:
    """The scene camera calibrated from the session's board views, written to ``inputs.out``.

    Raises:
        UserError: the session has no camera-calibration recording, or it cannot calibrate.
    """
    board_file = inputs.views / BOARD_FILE
    if not board_file.is_file():
        raise UserError(f"{board_file}: no camera-calibration recording in the session; pass "
                        "--camera camera.json")
    board = read_board(inputs.views)
    cal, _ = calibrate_camera_files(board.views, board.spec, inputs.out, conf.model, conf.max_views,
                                    progress)
    return cal


# --- 2. eyes -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EyesInputs:
    """The scene ``camera``, the eye-calibration ``recordings`` and the eyes.json to write."""

    camera: CameraCalibration
    recordings: EyeRecordings
    out: Path


def run_eyes(conf: EyesConfig, inputs: EyesInputs, progress: Progress | None = None) -> dict:
    """The eye calibration (``calibrate.calibrate_eyes``), written to ``inputs.out``; returns
    its content (eyes.json's)."""
    result = calibrate_eyes(inputs.recordings, inputs.camera, conf.model, conf.centers, progress)
    write_eyes(inputs.out, result)
    return result


# --- 3. tracking ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class TrackingInputs:
    """Where the head poses come from, and poses.csv to write (``out``). One of:
    ``head_poses``, a device's or a live recording's poses file (taken as they are);
    ``still_t_s``, the eye samples' times, s (a still head); or the scene ``video`` (its
    ``stamps``, or None) tracked with ``camera`` in ``room``, a marker map or a markerless map
    (None: a marker map built from the video first, ``TrackingConfig.build_map``, from the camera
    file ``camera_path``, written as ``BUILT_MAP`` beside ``out``)."""

    out: Path
    head_poses: Path | None = None
    still_t_s: np.ndarray | None = None
    video: Path | None = None
    stamps: Path | None = None
    camera: CameraCalibration | None = None
    room: MarkerMap | FeatureMap | None = None
    camera_path: Path | None = None


@dataclass(frozen=True)
class TrackingOutputs:
    """The poses tracked in the video (with their marker detections, ``Poses.detections``) and
    the map they were tracked in (None: taken from a device or a still head)."""

    poses: Poses | None = None
    room: MarkerMap | FeatureMap | None = None


def run_tracking(conf: TrackingConfig, inputs: TrackingInputs, progress: Progress | None = None) -> TrackingOutputs:
    """The head poses (poses.csv): the device's, a still head's, or tracked in the scene video
    (one frame in ``conf.every``, ``track.track_video``); in a marker map, the markers detected
    in each frame tracked too (``formats.marker_detections``, ``DETECTIONS`` beside poses.csv),
    which the report's overlay draws."""
    if inputs.head_poses is not None:
        device_poses(inputs.head_poses, inputs.out)
        return TrackingOutputs()
    if inputs.still_t_s is not None:
        still_head_poses(inputs.still_t_s, inputs.out)
        return TrackingOutputs()
    video, camera = cast(Path, inputs.video), cast(CameraCalibration, inputs.camera)
    room = inputs.room
    if room is None:
        if conf.build_map is None or inputs.camera_path is None:
            raise ValueError("tracking: no map to track in, and none to build")
        built = inputs.out.parent / BUILT_MAP
        side_mm, dictionary = conf.build_map
        build_map_files([video], inputs.camera_path, built, dictionary, side_mm, progress=progress)
        room = load_marker_map(built)
    times = frame_times(video, inputs.stamps)
    poses = track_video(video, camera, room, times, conf.every, progress)
    write_poses_csv(inputs.out, poses.t, poses.frame, poses.T_world_from_cam, poses.columns)
    if poses.detections is not None:                   # for the report's overlay: not detected again
        write_marker_detections(inputs.out.parent / DETECTIONS, poses.detections)
    return TrackingOutputs(poses, room)


# --- 4. view lines -------------------------------------------------------------------------------

@dataclass(frozen=True)
class ViewlinesInputs:
    """The head ``poses`` (read from ``poses_path``, named when no pose is near a sample), and
    the eyes: raw ``eye_samples`` with their calibrations ``eyes`` (left, right), or an imported
    session's ``eye_rays`` (head frame). ``out``: the view-line CSV to write; ``counts``: a JSON
    file for the counts, or None."""

    poses: Poses
    poses_path: Path
    out: Path
    eye_samples: EyeSamples | None = None
    eyes: list | None = None
    eye_rays: BinocularSamples | None = None
    counts: Path | None = None


def run_viewlines(conf: ViewlinesConfig, inputs: ViewlinesInputs, progress: Progress | None = None) -> ViewLinesResult:
    """World view lines (eq. 1-8, ``calibrate.view_lines``; an imported session's rays moved by
    the poses, ``calibrate.head_lines_to_world``), written unsegmented to ``inputs.out``."""
    if inputs.eye_rays is not None:
        result = head_lines_to_world(inputs.eye_rays, inputs.poses, conf.max_gap_s,
                                     inputs.poses_path, conf.correction_deg)
    else:
        samples, eyes = cast(EyeSamples, inputs.eye_samples), cast(list, inputs.eyes)
        result = view_lines(samples, eyes, inputs.poses, conf.max_gap_s,
                            inputs.poses_path, conf.correction_deg)
    write_viewlines_csv(inputs.out, result.samples)
    if inputs.counts is not None:
        write_json(inputs.counts, result.counts)
    return result


# --- 5. fixations and targets --------------------------------------------------------------------

@dataclass(frozen=True)
class TargetsInputs:
    """The unsegmented view lines (``samples``, time order), the session's gaze-bias ``prior``
    and ``error_model`` (the poses' error, before the bias is sized from the lines), the
    depth assumption written beside the targets (``errorbudget.depth_assumption``), and the
    output folder. A device's own gaze (``device_gaze``) is compared with the head ``poses``.
    A live ``--device`` recording's ``live_poses.csv`` (``live_poses``) with its head-frame
    ``eye_rays``: the targets live published, re-run (``live_replay``)."""

    samples: BinocularSamples
    prior: BiasPrior
    error_model: ErrorModel
    depth_assumption: str | None
    out: Path
    device_gaze: Path | None = None
    poses: Poses | None = None
    live_poses: Path | None = None
    eye_rays: BinocularSamples | None = None


def run_targets(conf: TargetsConfig, inputs: TargetsInputs, progress: Progress | None = None) -> TargetsResult:
    """Fixations segmented (``conf.segment``), the gaze bias sized from them, and the targets
    estimated (``fixations.find_targets``); writes the view lines with their segments, the
    targets, estimates and fixations tables (and device_comparison.csv)."""
    samples, out = inputs.samples, inputs.out
    budget: dict | None = None
    if inputs.live_poses is not None:      # a live recording: the targets live published
        rays = cast(BinocularSamples, inputs.eye_rays)
        result = replay_recording(rays, inputs.live_poses, conf.method)
    else:
        labels = segment_view_lines(samples, conf.segment)
        budget = session_bias(inputs.prior, seen_bias(samples, labels))     # sized from the lines
        result = find_targets(samples, labels, conf.method, conf.sigma_deg, progress,
                              with_bias(inputs.error_model, budget), conf.segment.min_fixation_s,
                              conf.merge_within_s)
    write_targets_step(out, result, conf.method, budget, inputs.depth_assumption)
    write_fixations_step(out, result)
    if inputs.device_gaze is not None:
        device_comparison(inputs.device_gaze, samples, result.targets, cast(Poses, inputs.poses),
                          out / "device_comparison.csv")
    return result


# --- 6. exports ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class ExportInputs:
    """The head-frame view lines: an imported session's ``eye_rays``, or ``eye_samples`` with
    their calibrations ``eyes``; the head ``poses``, the ``targets``, the scene ``camera`` (None:
    no 2D gaze), the device's clock at session time 0 (``clock_offset_s``, s) and the output
    folder."""

    poses: Poses
    targets: list
    out: Path
    camera: CameraCalibration | None = None
    clock_offset_s: float = 0.0
    eye_samples: EyeSamples | None = None
    eyes: list | None = None
    eye_rays: BinocularSamples | None = None


def run_export(conf: ExportConfig, inputs: ExportInputs, progress: Progress | None = None) -> None:
    """gaze.csv (per eye sample) and targets.ply (``export.export_files``), the head lines with
    the person's correction (``conf.correction_deg``) if any."""
    if inputs.eye_rays is not None:
        head = inputs.eye_rays
    else:
        head = head_view_lines(cast(EyeSamples, inputs.eye_samples), cast(list, inputs.eyes))
    if conf.correction_deg is not None:
        head = correct_head_lines(head, conf.correction_deg)
    export_files(inputs.out, head, inputs.poses, inputs.targets, inputs.camera,
                 inputs.clock_offset_s)


# --- 7. areas of interest, 8. report --------------------------------------------------------------

@dataclass(frozen=True)
class AoiFolderInputs:
    """The output folder of the steps before, the AOI file's areas (``specs``, ``read_aois``'s)
    and the marker map for marker areas (None: none)."""

    out: Path
    specs: tuple
    marker_map: Path | None = None


def run_aoi(conf: AoiConfig, inputs: AoiFolderInputs, progress: Progress | None = None) -> AoiResult:
    """The AOI tables and plot in the output folder (``aoi.aoi_step``)."""
    return aoi_step(inputs.out, inputs.specs, inputs.out, inputs.marker_map, conf)


@dataclass(frozen=True)
class ReportInputs:
    """What the report shows beside the earlier steps' files in ``out``.

    Attributes:
        out: the output folder; ``title``: the session's name.
        notes: sentences the reader needs (where the poses came from, the bias, the truth).
        truth: a simulated session's truth, in the world of the map used, or None.
        marker_map: the map the video was tracked in, or None.
        room_points_mm: (N, 3) points of the room for the 3D view, world mm, or None.
        aois: the areas' outlines (``aoi.aoi_outlines``).
        overlay: gives the overlay's inputs, called only when it is drawn; None: no overlay.
    """

    out: Path
    title: str
    notes: list
    truth: ReportTruth | None = None
    marker_map: MarkerMap | None = None
    room_points_mm: np.ndarray | None = None
    aois: list = field(default_factory=list)
    overlay: Callable[[], OverlayInputs] | None = None


def run_report(conf: ReportConfig, inputs: ReportInputs, progress: Progress | None = None) -> None:
    """The plots, the overlay and report.html (``report.write_report``)."""
    write_report(inputs.out, inputs.title, inputs.overlay, progress, inputs.notes, inputs.truth,
                 inputs.marker_map, conf.overlay_video, inputs.room_points_mm, world=conf.world,
                 aois=inputs.aois)
