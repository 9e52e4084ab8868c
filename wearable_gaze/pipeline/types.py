"""Typed values the pipeline steps pass to each other (and ``live`` publishes): fixations,
targets and step results. World frame of the marker map, mm and s throughout.

A ``Target`` is what ``process`` writes as one record of targets.json / row of targets.csv,
``estimate --json --targets`` prints and the live session publishes (``Target.row`` /
``Target.from_row``: the record of ``formats.targets.target_record``, keys ``TARGET_KEYS``;
formats/targets.py reads and writes the records, and nothing else in the application indexes a
target by string keys).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.camera import CameraCalibration
from estimator import BinocularSamples, GazeEstimate
from estimator.direction import GazeDirection
from estimator.errormodel_regions import Sight
from estimator.motion import STATIC, Trajectory

from ..formats.marker_detections import MarkerDetections
from ..formats.targets import (  # noqa: F401  (TARGET_KEYS: a record's keys)
    DEPTH_ASSUMPTION,
    DIRECTION_COLUMN,
    DWELL,
    MOVING_COLUMN,
    TARGET_KEYS,
    record_sight,
    target_record,
)
from .steps.target_status import is_fixated


@dataclass
class Fixation:
    """One fixation: a run of view lines the segmenter put on one gazed point.

    Attributes:
        index: the fixation's number (its label in viewlines.csv).
        samples: (K,) indices of its view lines in the session's view lines, increasing.
        estimate: the estimate from its lines (fed in chunks as a live session would), or None
            (none for a moving fixation: a point estimate of a moving point is no answer).
        motion: what its lines looked at (``estimator.motion.classify_lines``): 'static' or
            'moving' (a fixation of two points is split into two static ones before this).
        trajectory: a moving fixation's path (``estimator.motion.smooth_trajectory``), or None.
    """

    index: int
    samples: np.ndarray
    estimate: GazeEstimate | None
    motion: str = STATIC
    trajectory: Trajectory | None = None

    @property
    def usable(self) -> bool:
        """A static fixation with an estimate that is ok (it may merge with others)."""
        return self.motion == STATIC and self.estimate is not None and self.estimate.ok


@dataclass(frozen=True, eq=False)
class Target:
    """A fixated 3D target: one or more fixations of the same point, merged and estimated again
    from all their view lines.

    Attributes:
        index: the target's number (0, 1, ... in order of first fixation).
        position_mm: (3,) estimate, world frame, mm; NaN when there is no usable estimate.
        covariance_mm2: (3, 3) covariance, mm^2, or None (no covariance, or read from a
            version-1 targets.json, which kept only the ellipsoid's semi-axes).
        axes95_mm: (3,) semi-axes of the 95 % confidence ellipsoid, increasing, mm; NaN without
            a covariance.
        status: its one status (``pipeline.steps.target_status``: 'ok', 'unresolved', 'direction-only',
            'moving', or why it is no target, e.g. 'too-near'), the same in every output.
        n_samples: binocular samples (view lines) of its fixations.
        t_start, t_end: time of its first and last sample, s.
        fixations: the fixation indices merged into it.
        method: the estimator.
        crb_mm: square root of the trace of the Cramér-Rao bound at the estimate, mm (NaN when
            the lines do not fix a point).
        samples: (n_samples,) indices of its view lines, or None when read from a file (the
            view lines' target labels are in target_labels.npy).
        moving: a moving target (smooth pursuit): its point is the path's position at the
            middle knot and its status 'moving'; the path is ``trajectory``.
        trajectory: a moving target's path (``estimator.motion.Trajectory``; target_paths.csv),
            or None (a static target, or one read from targets.json).
        sight: where its lines were seen from and how the error model shaped its covariance
            (``estimator.errormodel.Sight``), which draws its region at any level and its depth
            intervals; None without the error model.
        direction: where its lines looked (``estimator.direction.GazeDirection``: the cyclopean
            direction, its 95 % cone, the depth interval, which may have no far end): a
            direction-only target's answer, and beside the point of a static one; None for a
            moving target.
        depth_assumption: the assumption that fixes its depth, in words
            (``pipeline.steps.errorbudget.depth_assumption``), or None.
        dwell_s: the sum of its fixations' durations (each the time its samples stand for,
            ``estimator.aoi.fixation_duration_s``: fixations.csv's ``duration_s``), s; NaN unknown.

    Two targets compare equal only when they are the same object (arrays have no single truth
    value): compare ``row()`` for equal values.
    """

    index: int
    position_mm: np.ndarray
    covariance_mm2: np.ndarray | None
    axes95_mm: np.ndarray
    status: str
    n_samples: int
    t_start: float
    t_end: float
    fixations: tuple
    method: str
    crb_mm: float
    samples: np.ndarray | None = None
    moving: bool = False
    trajectory: Trajectory | None = None
    sight: Sight | None = None
    direction: GazeDirection | None = None
    depth_assumption: str | None = None
    dwell_s: float = float("nan")

    def level_covariance(self, probability: float) -> np.ndarray | None:
        """(3, 3) mm^2 whose ``probability`` ellipsoid is the region of that level (the error
        model's far side drawn for that level: ``estimator.errormodel.at_level``); the
        covariance itself when the target has no ``sight``; None without a covariance."""
        if self.covariance_mm2 is None or self.sight is None:
            return self.covariance_mm2
        return self.sight.level_covariance(self.covariance_mm2, self.position_mm, probability)

    def depth_interval(self, probability: float = 0.95) -> tuple[float, float]:
        """(near, far) mm: the ``probability`` interval of its distance from where it was seen
        (``sight``), symmetric in inverse depth (``estimator.errormodel.depth_interval``); (NaN,
        NaN) without one."""
        if self.sight is None or not np.all(np.isfinite(self.position_mm)):
            return float("nan"), float("nan")
        return self.sight.depth_interval(self.position_mm, probability)

    @property
    def ok(self) -> bool:
        """A static target with a usable point estimate."""
        return self.status == "ok" and bool(np.all(np.isfinite(self.position_mm)))

    @property
    def fixated(self) -> bool:
        """Whether it counts as a fixated target (``pipeline.steps.target_status.FIXATED``: not a
        ``too-near`` point, nor an estimate that failed without a direction)."""
        return is_fixated(self.status)

    def row(self, rounded: bool = False) -> dict:
        """The target's record (``formats.targets.target_record``: a row of targets.json, plain
        Python values, null for a value that does not exist), with ``moving: True`` for a moving
        target; ``rounded`` as the live messages send it."""
        return target_record(self.index, self.t_start, self.t_end, self.position_mm, self.axes95_mm, self.n_samples,
                             self.method, self.status, self.covariance_mm2, self.crb_mm, self.fixations, self.moving,
                             rounded, self.sight, self.direction, self.depth_assumption, self.dwell_s)

    @classmethod
    def from_row(cls, row: dict) -> Target:
        """A target from a record of targets.json (``read_targets``; no sample indices, no
        trajectory: read_target_paths has the paths). A null is NaN (a covariance: None)."""
        def vec(key):
            return np.array(row[key], float) if row[key] is not None else np.full(3, np.nan)

        cov = row["covariance_mm2"]
        return cls(index=int(row["target"]), position_mm=vec("position_mm"),
                   covariance_mm2=None if cov is None else np.array(cov, float),
                   axes95_mm=vec("ellipsoid95_radii_mm"), status=str(row["status"]), n_samples=int(row["n_samples"]),
                   t_start=_num(row["t_start"]), t_end=_num(row["t_end"]),
                   fixations=tuple(int(f) for f in row["fixations"]), method=str(row["method"]),
                   crb_mm=_num(row["crb_mm"]), moving=bool(row.get(MOVING_COLUMN, False)), sight=record_sight(row),
                   direction=GazeDirection.from_dict(row.get(DIRECTION_COLUMN)),
                   depth_assumption=row.get(DEPTH_ASSUMPTION),
                   dwell_s=_num(row.get(DWELL)))


def _num(v) -> float:
    return float("nan") if v is None else float(v)


@dataclass(frozen=True)
class ViewLinesResult:
    """The view-lines step: the session's eye samples as world view lines.

    Attributes:
        samples: the view lines (N,) of the samples with a head pose and a valid eye.
        counts: {'samples', 'written', 'no_pose', 'both_eyes_invalid'}: eye samples read, view
            lines written, dropped without a pose, dropped with both eyes invalid.
    """

    samples: BinocularSamples
    counts: dict


@dataclass(frozen=True)
class TargetsResult:
    """The fixations-and-targets step.

    Attributes:
        samples: the view lines (N,) segmented.
        labels: (N,) fixation index of each view line, -1 in a saccade or a short fixation.
        fixations: the fixations, in order.
        running: the running estimates (columns of estimates.csv: t, segment, x, y, z,
            radius95_mm; one entry per usable estimate).
        targets: the targets, fixations of one point merged.
        target_labels: (N,) target index of each view line, -1 none.
    """

    samples: BinocularSamples
    labels: np.ndarray
    fixations: list
    running: dict
    targets: list
    target_labels: np.ndarray


@dataclass(frozen=True)
class CameraResult:
    """The camera-calibration step.

    Attributes:
        calibration: the scene camera's calibration.
        warnings: why it cannot be trusted ([] when nothing is plainly wrong).
        preview: (H, 2W, 3) BGR image, the first view beside its undistorted version.
    """

    calibration: CameraCalibration
    warnings: list
    preview: np.ndarray


@dataclass(frozen=True)
class Poses:
    """Head poses of the scene video's frames (the tracking step; poses.csv).

    Attributes:
        t: (N,) frame times, s.
        frame: (N,) frame numbers.
        T_world_from_cam: (N, 4, 4) head (scene camera) poses, mm; NaN where there is none.
        columns: the other columns of poses.csv, (N,) each: n_markers, n_points, reproj_rms_px,
            status ('ok', 'interpolated', or why there is no pose).
        detections: the markers detected in each frame tracked, {frame: [``MarkerDetection``]}
            (``formats.marker_detections.MarkerDetections``), or None: not kept (poses read back,
            a device's).
    """

    t: np.ndarray
    frame: np.ndarray
    T_world_from_cam: np.ndarray
    columns: dict = field(default_factory=dict)
    detections: MarkerDetections | None = None

    @property
    def n_posed(self) -> int:
        """Frames with a pose, tracked or interpolated."""
        return sum(st in ("ok", "interpolated") for st in self.columns.get("status", ()))
