"""The fixations step of ``process``: the fixations of segmented view lines each estimated as a
live session would, fixations of one point merged into targets (revisits are common); and the
files it writes (viewlines.csv with the fixation labels, estimates.csv, targets.csv,
targets.json and target_labels.npy, each through its formats module; docs/processing.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from estimator import BinocularSamples, GazeEstimate, Status
from estimator.aoi import fixation_durations_s
from estimator.direction import path_direction
from estimator.errormodel import DEFAULT_BIAS_DEG, ErrorModel
from estimator.frames import angle_deg
from estimator.motion import MOVING, STATIC, TWO_POINTS, Trajectory, classify_lines, smooth_trajectory
from estimator.result import covariance_ellipsoid
from estimator.segments import SegmentConfig

from ...formats.targets import (
    ESTIMATE_COLUMNS,
    write_estimates,
    write_target_labels,
    write_target_paths,
    write_targets,
)
from ...formats.viewlines import write_viewlines_csv
from ..types import Fixation, Target, TargetsResult
from .estimate import estimate_target, radius95_mm, running_estimate, target_merger
from .target_status import target_status

log = logging.getLogger(__name__)

MIN_SPLIT_SAMPLES = 5
"""A fixation of two points is split only when each part keeps this many samples."""


def find_targets(samples: BinocularSamples, labels: np.ndarray, method: str, sigma_deg: float,
                 progress=None, error_model: ErrorModel | None = None,
                 min_fixation_s: float = SegmentConfig.min_fixation_s,
                 merge_within_s: float = float("inf")) -> TargetsResult:
    """Test each fixation of view lines (N,) segmented into fixations for motion, estimate the
    static ones (their running estimates too), merge the static fixations of one target and
    estimate each target from all its lines; a moving fixation is a moving target of its own,
    and so is a static fixation whose lines fix a direction but no point (``direction-only``:
    ``direction_only_groups``), so that every fixation with a direction is answered.

    A fixation of two points (a switch the segmenter missed) is split at the switch into two
    fixations, the labels renumbered in time order, a part shorter than ``min_fixation_s`` (the
    segmentation's) in none (``split_two_point_fixations``); a moving one gets its path
    (``estimator.motion.smooth_trajectory``).

    Args:
        samples: world view lines, in time order.
        labels: (N,) fixation index of each view line, -1 none
            (``estimator.segments.segment_fixations``).
        method, sigma_deg: the estimator and its angular noise.
        progress: called as progress(done, total) after each fixation.
        error_model: the covariances' error model for ``ml`` and ``voxel`` (running estimates,
            fixations, merges and targets); None: the inverse Fisher information.
        merge_within_s: a revisit is merged only with a target seen this many seconds before
            it (``estimator.merge.STILL_HEAD_MERGE_S`` without head poses; default: any).
    """
    labels, motion = split_two_point_fixations(samples, labels, sigma_deg, min_fixation_s)
    n_seg = len(motion)
    fixations = []
    running: dict[str, list] = {k: [] for k in ESTIMATE_COLUMNS}
    for k in range(n_seg):
        idx = np.flatnonzero(labels == k)
        fixations.append(_fixation(samples, k, idx, motion[k], method, sigma_deg, running, error_model))
        if progress:
            progress(k + 1, n_seg + 1)
    groups = merge_fixations(fixations, samples, method, sigma_deg, error_model, merge_within_s)
    groups += join_pursuits(fixations, samples, sigma_deg, error_model)
    groups += direction_only_groups(fixations)
    groups.sort(key=lambda g: g.fixations[0])
    targets = [moving_target(i, samples, g, method) if g.trajectory is not None else
               estimate_target(i, samples, g.samples, g.fixations, g.estimate, method, sigma_deg, error_model)
               for i, g in enumerate(groups)]
    targets = [replace(tg, dwell_s=dwell_s(samples.t_s, labels, tg.fixations)) for tg in targets]
    tlabels = np.full(len(samples), -1)
    for tg in targets:
        tlabels[tg.samples] = tg.index
    log.info("%d fixation(s), %d target(s) (%d moving) from %d view lines", n_seg, len(targets),
             sum(tg.moving for tg in targets), len(samples))
    return TargetsResult(samples, labels, fixations, {k: np.array(v) for k, v in running.items()}, targets, tlabels)


def _fixation(samples: BinocularSamples, k: int, idx: np.ndarray, motion: str, method: str, sigma_deg: float,
              running: dict, error_model: ErrorModel | None = None) -> Fixation:
    """Fixation ``k`` of the view lines ``idx``: a static one estimated as a live session would
    (its usable running estimates appended to ``running``), a moving one with its path."""
    if motion == MOVING:
        path = smooth_trajectory(samples.select(idx), sigma_deg, error_model=path_model(error_model))
        return Fixation(k, idx, None, MOVING, path)
    e, usable = running_estimate(samples.select(idx), method, sigma_deg, error_model=error_model)
    for t, ek in usable:
        for name, v in zip(ESTIMATE_COLUMNS, (t, k, *(float(v) for v in ek.position_mm), radius95_mm(ek)),
                           strict=True):
            running[name].append(v)
    return Fixation(k, idx, e)


def dwell_s(t_s: np.ndarray, labels: np.ndarray, fixations) -> float:
    """A target's dwell time: the sum of the durations of its ``fixations``, s, each the time its
    view lines stand for (``estimator.aoi.fixation_durations_s``: one sample interval per line,
    gaps up to 75 ms filled, Tobii's I-VT convention; the AOI measures' and fixations.csv's).

    Args:
        t_s: (N,) the session's view lines' times, s; labels: (N,) the fixation of each, -1 none.
        fixations: the target's fixation labels.
    """
    return float(np.sum(fixation_durations_s(t_s, labels, fixations)))


def direction_only_groups(fixations: list) -> list:
    """The static fixations whose estimate is direction-only (``estimator.direction``: their
    lines fix a direction with its cone, not a point), each a group of its own: they go around
    the merge test, which compares points, so that each is answered by its own direction."""
    return [_Group(f.samples, [f.index], f.estimate, parts=[f.samples]) for f in fixations
            if f.motion == STATIC and f.estimate is not None and f.estimate.status is Status.DIRECTION_ONLY]


def path_model(error_model: ErrorModel | None) -> ErrorModel | None:
    """The error model of a moving target's path: ``error_model`` with its bias at least
    ``estimator.errormodel.DEFAULT_BIAS_DEG`` (0.5 deg). A path's smoothing errs where the point
    curves or speeds up (lag), which its covariance does not count, and the lines cannot size a
    bias on a moving point (``estimator.slippage`` takes static fixations): with a bias sized from
    a good calibration (0.1 deg) the simulated pursuit's 95 % regions held 43 % of its true path."""
    if error_model is None or error_model.bias_deg >= DEFAULT_BIAS_DEG:
        return error_model
    return replace(error_model, bias_deg=DEFAULT_BIAS_DEG)


PURSUIT_GAP_S = 0.5
"""Two moving fixations in a row with at most this gap between them (a blink or a catch-up
saccade the segmenter cut the pursuit at) ..."""
PURSUIT_JOIN_DEG = 5.0
"""... whose paths meet across the gap within this angle as seen from the eyes are one moving
target, its path fitted over both fixations' lines."""


def join_pursuits(fixations: list, samples: BinocularSamples, sigma_deg: float,
                  error_model: ErrorModel | None = None) -> list:
    """The moving fixations as groups (``_Group`` with the path), consecutive ones of one pursuit
    joined (``PURSUIT_GAP_S``, ``PURSUIT_JOIN_DEG``) and their path fitted again over all their
    lines: the depth of a short piece, which vergence fixes poorly, is then averaged with the
    rest of the pursuit."""
    groups: list = []
    for f in fixations:
        if f.motion != MOVING:
            continue
        g = groups[-1] if groups else None
        if g is not None and g.fixations[-1] == f.index - 1 and _continues(g.trajectory, f.trajectory, samples,
                                                                          f.samples[0]):
            g.samples = np.sort(np.concatenate([g.samples, f.samples]))
            g.fixations.append(f.index)
            g.trajectory = smooth_trajectory(samples.select(g.samples), sigma_deg,
                                             error_model=path_model(error_model))
        else:
            groups.append(_Group(f.samples, [f.index], None, f.trajectory))
    return groups


def _continues(before, after, samples: BinocularSamples, first: int) -> bool:
    """Whether path ``after`` starts where ``before`` ended: a gap of at most ``PURSUIT_GAP_S``
    and the two ends within ``PURSUIT_JOIN_DEG`` as seen from the eyes at ``after``'s first line."""
    t0, t1 = float(before.t_s[-1]), float(after.t_s[0])
    if t1 - t0 > PURSUIT_GAP_S:
        return False
    o = samples.origin_mm(first)
    return bool(angle_deg(before.positions_mm[-1] - o, after.positions_mm[0] - o) <= PURSUIT_JOIN_DEG)


def split_two_point_fixations(samples: BinocularSamples, labels: np.ndarray, sigma_deg: float,
                              min_fixation_s: float = SegmentConfig.min_fixation_s) -> tuple[np.ndarray, list]:
    """Each fixation's motion test (``estimator.motion.classify_lines``); a fixation of two
    points split at its switch time into two (when each part keeps ``MIN_SPLIT_SAMPLES``). A part
    lasting less than ``min_fixation_s`` is no fixation (-1), as the segmentation drops one:
    on Neon's demo it was the tail of a saccade the segmenter left on the next fixation (0.05 s,
    11 samples, which became a target of its own); both parts that short: not split.
    Returns the new (N,) labels, numbered 0, 1, ... in time order (-1 kept), and each new
    fixation's motion, 'static' or 'moving'."""
    n_seg = int(labels.max()) + 1 if (labels >= 0).any() else 0
    out = np.full(len(labels), -1)
    motion: list = []
    for k in range(n_seg):
        idx = np.flatnonzero(labels == k)
        if not len(idx):
            continue
        test = classify_lines(samples.select(idx), sigma_deg)
        parts = [idx]
        if test.kind == TWO_POINTS:
            before = samples.t_s[idx] < test.split_t
            if min(before.sum(), (~before).sum()) >= MIN_SPLIT_SAMPLES:
                parts = [p for p in (idx[before], idx[~before]) if np.ptp(samples.t_s[p]) >= min_fixation_s] or [idx]
        for part in parts:
            out[part] = len(motion)
            motion.append(MOVING if test.kind == MOVING else STATIC)
        log.debug("fixation %d: %s over %d samples", k, test.kind, len(idx))
    return out, motion


def moving_target(index: int, samples: BinocularSamples, group, method: str) -> Target:
    """The moving target of one moving fixation (``group``: its view lines and path): its point
    is the path's position at the middle knot, with that knot's covariance, status 'moving', and
    its direction there (``estimator.direction.path_direction``)."""
    tr = group.trajectory
    pos, cov = tr.middle()
    idx = group.samples
    lines = samples.select(idx)
    t = samples.t_s[idx]
    radii = np.asarray(covariance_ellipsoid(pos, cov, 0.95).radii_mm, float)
    return Target(index=index, position_mm=np.asarray(pos, float), covariance_mm2=cov,
                  axes95_mm=radii, status=target_status(MOVING, pos, radii, lines),
                  n_samples=len(idx), t_start=float(t.min()), t_end=float(t.max()),
                  fixations=tuple(int(f) for f in group.fixations), method=method, crb_mm=float("nan"),
                  samples=idx, moving=True, trajectory=tr, direction=path_direction(lines, tr))


@dataclass
class _Group:
    """Fixations merged so far: their view lines, fixation indices and estimate (or a moving
    fixation alone, with its path), and each fixation's view lines (``parts``)."""

    samples: np.ndarray
    fixations: list = field(default_factory=list)
    estimate: GazeEstimate | None = None
    trajectory: Trajectory | None = None
    parts: list = field(default_factory=list)


def merge_fixations(fixations: list, samples: BinocularSamples, method: str, sigma_deg: float,
                    error_model: ErrorModel | None = None, within_s: float = float("inf")) -> list:
    """Static fixations of one target merged and estimated again from all their lines, one
    fixation at a time in order, by ``estimator.merge.TargetMerger`` (the test the live session
    runs too): a fixation joins the group whose pooled lines fit one point with its own, else
    starts a group; fixations without a usable estimate are left out; merged estimates (from
    ``method`` with ``sigma_deg``) have covariances that follow ``error_model``. Returns the
    groups in order of first fixation, each with its sorted view-line indices (N,) and parts."""
    merger = target_merger(method, sigma_deg, error_model, within_s)
    by_index = {}
    for f in fixations:
        if f.usable:
            merger.add(samples.select(f.samples), f.estimate, key=f.index)
            by_index[f.index] = f
    groups = []
    for g in merger.groups:
        parts = [by_index[k].samples for k in g.members]
        groups.append(_Group(np.sort(np.concatenate(parts)), list(g.members), g.estimate, parts=parts))
    return groups


def write_targets_step(out: Path, result: TargetsResult, method: str, error_model: dict | None = None,
                       depth_assumption: str | None = None) -> None:
    """The step's files in ``out``: viewlines.csv (with fixation labels), and through
    formats/targets.py estimates.csv, targets.csv and targets.json (the rows of ``Target.row``,
    each named the session's ``depth_assumption`` if any; ``error_model``: the bias's record,
    ``pipeline.steps.errorbudget.session_bias``), target_paths.csv (the moving targets' paths) and
    target_labels.npy (the target of every view line)."""
    write_viewlines_csv(out / "viewlines.csv", result.samples, result.labels)
    write_estimates(out / "estimates.csv", result.running)
    write_targets(out, [replace(tg, depth_assumption=depth_assumption).row() if depth_assumption else tg.row()
                        for tg in result.targets], method, error_model)
    write_target_paths(out / "target_paths.csv", {tg.index: (tg.trajectory.t_s, tg.trajectory.positions_mm,
                                                            tg.trajectory.covariances_mm2)
                                                 for tg in result.targets if tg.trajectory is not None})
    write_target_labels(out / "target_labels.npy", result.target_labels)
