"""``process`` on a live ``--device`` recording (docs/live.md, "Recording"; docs/processing.md):
the live session's own estimation re-run on the samples it estimated, so that the targets are
the ones it published.

Live segments the view lines online (``estimator.segments.OnlineSegmenter``), estimates each
fixation with a streaming estimator updated sample by sample, and publishes each finished
fixation's own estimate under the id of the target its lines join (``pipeline.steps.live_estimation``);
the offline steps (``segment_view_lines``, ``find_targets``) segment the whole session at once and
re-estimate each merged target from all its lines, which on the same lines gives other points
(4.5-269 mm apart). ``replay`` feeds ``GazeEstimation`` (the live session's, not a copy of it)
exactly what the session fed it: each recorded eye sample that had a pose in ``live_poses.csv``,
with that pose, in order; every fixation it ended is then turned into its target as the session's
target worker did, in the same order (``GazeEstimation.finish`` touches nothing ``add`` reads, so
finishing after the last sample gives what finishing alongside did).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator import BinocularSamples
from estimator.motion import MOVING, STATIC

from ...errors import UserError
from ...formats.devices.pupil_net import RaySample
from ...formats.poses import read_poses_csv
from ...formats.targets import ESTIMATE_COLUMNS
from ..types import Fixation, TargetsResult
from .fixations import dwell_s
from .live_estimation import GazeEstimation, RayEyes, lines_to_samples, world_sample

log = logging.getLogger(__name__)

TIME_MATCH_S = 5e-7
"""A pose row belongs to the eye sample at its time: both written from the same session time
with 6 decimals (``live.record``)."""


def replay_recording(rays: BinocularSamples, live_poses: Path, method: str = "voxel") -> TargetsResult:
    """``replay`` with the poses read from a recording's ``live_poses.csv``.

    Raises:
        UserError: a malformed ``live_poses.csv``, or a pose row at a time with no eye sample.
    """
    t, _, T, _ = read_poses_csv(live_poses)
    return replay(rays, t, T, method)


def replay(rays: BinocularSamples, pose_t, T_world_from_cam, method: str = "voxel") -> TargetsResult:
    """The live session's fixations and targets, re-run.

    Args:
        rays: the recording's eye samples (``eye_rays.csv``): per-eye lines in the head frame, mm,
            time order.
        pose_t: (M,) session times, s, of the samples the session took (``live_poses.csv``).
        T_world_from_cam: (M, 4, 4) the pose each took, mm; NaN: it had none (not estimated).
        method: the streaming estimator the session ran (``live``'s default, ``voxel``).

    Returns:
        ``TargetsResult``: the view lines of the samples with a pose (world frame, the same set
        as ``process``'s view-line step gives a live recording), labelled with live's fixations
        (renumbered 0, 1, ... in order; -1: a saccade, a fixation too short, or the lines the
        segmenter took in before it saw the saccade that ended it), the fixations (each with the
        streaming estimate live published at its end), live's running estimates, and one target
        per id live published: the last one published under it (its point, covariance, status),
        with every fixation that took the id.

    Raises:
        UserError: a pose at a time with no eye sample (not this recording's poses).
    """
    rows = _posed_rows(rays, np.asarray(pose_t, float), np.asarray(T_world_from_cam, float))
    est = GazeEstimation([RayEyes(), RayEyes()], method)
    lines, running, finished = [], [], []
    for k, T in rows:
        rec = _ray_record(rays, k)
        lines.append(world_sample(est.eyes, float(rays.t_s[k]), rec, T))
        ended, e = est.add(float(rays.t_s[k]), rec, T)
        if ended is not None:
            finished.append(ended)
        if e is not None:
            running.append((e.t_s, e.fixation, e.position_mm, e.radius95_mm))
    if (last := est.end_fixation()) is not None:
        finished.append(last)
    published = [(done, est.finish(done)) for done in finished]     # the target worker's order
    return _result(lines_to_samples(lines) if lines else None, published, running)


def _posed_rows(rays: BinocularSamples, pose_t: np.ndarray, T: np.ndarray) -> list:
    """(eye sample index, pose (4, 4)) of each sample the session estimated, in time order."""
    if not len(pose_t):
        return []
    k = np.clip(np.searchsorted(rays.t_s, pose_t), 0, max(len(rays.t_s) - 1, 0))
    k = np.where((k > 0) & (np.abs(rays.t_s[k - 1] - pose_t) < np.abs(rays.t_s[k] - pose_t)), k - 1, k)
    if not len(rays.t_s) or np.any(np.abs(rays.t_s[k] - pose_t) > TIME_MATCH_S):
        bad = 0 if not len(rays.t_s) else int(np.flatnonzero(np.abs(rays.t_s[k] - pose_t) > TIME_MATCH_S)[0])
        raise UserError(f"live_poses.csv: the pose at t = {pose_t[bad]:.6f} s has no eye sample at that time in "
                        "eye_rays.csv; the two files are not of one live recording")
    posed = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1) & (rays.left_valid[k] | rays.right_valid[k])
    return [(int(i), T[j]) for j, i in enumerate(k) if posed[j]]


def _ray_record(rays: BinocularSamples, k: int) -> RaySample:
    """Eye sample ``k`` as the device reader handed it to the loop (each eye's centre and
    direction, head frame; NaN for an invalid eye)."""
    def eye(o, d, ok):
        return tuple(np.concatenate([o[k], d[k]])) if ok[k] else (np.nan,) * 6
    return RaySample(k, float(rays.t_s[k]), eye(rays.left_origin_mm, rays.left_direction, rays.left_valid),
                     eye(rays.right_origin_mm, rays.right_direction, rays.right_valid), bool(rays.left_valid[k]),
                     bool(rays.right_valid[k]), 1.0)


def _result(samples: BinocularSamples | None, published: list, running: list) -> TargetsResult:
    """The targets step's result from the replayed fixations and the targets live published for
    them (``(FinishedFixation, Target or None)``, in order). A fixation none of whose samples
    reached the estimator's lines (under load live sheds samples that come too late: one can end
    with none kept) is no fixation here, but the target live published for it is kept."""
    if samples is None:
        samples = BinocularSamples.from_arrays(np.zeros(0), *(np.zeros((0, 3)),) * 4)
    labels = np.full(len(samples), -1)
    label_of: dict[int, int] = {}          # live's fixation index -> its label here (fixations with lines)
    fixations: list[Fixation] = []
    for done, tg in published:
        if not done.lines:                 # its samples were all shed or left out: a fixation of no line
            continue
        n = len(fixations)
        idx = np.searchsorted(samples.t_s, [s.t_s for s in done.lines]).astype(int)
        labels[idx] = n
        label_of[done.fixation] = n
        moving = tg is not None and tg.moving
        fixations.append(Fixation(n, idx, None if moving else done.estimate, MOVING if moving else STATIC,
                                  tg.trajectory if moving else None))
    latest: dict = {}
    merged: dict[int, list[int]] = {}
    for done, tg in published:
        if tg is not None:
            latest[tg.index] = tg
            merged.setdefault(tg.index, []).extend([label_of[done.fixation]] if done.fixation in label_of else [])
    targets, tlabels = [], np.full(len(samples), -1)
    for i in sorted(latest):
        idx = np.flatnonzero(np.isin(labels, merged[i]))
        tlabels[idx] = i
        targets.append(replace(latest[i], fixations=tuple(merged[i]), samples=idx,
                               dwell_s=dwell_s(samples.t_s, labels, merged[i])))
    kept = [r for r in running if r[1] in label_of]
    cols = [[r[0] for r in kept], [label_of[r[1]] for r in kept], *zip(*[r[2] for r in kept], strict=True)] \
        if kept else [[]] * 5
    run = {name: np.asarray(v, float if name != "segment" else int) for name, v in
           zip(ESTIMATE_COLUMNS, [*cols, [np.nan if r[3] is None else r[3] for r in kept]], strict=True)}
    log.info("live replay: %d fixation(s), %d target(s) from %d view lines", len(fixations), len(targets),
             len(samples))
    return TargetsResult(samples, labels, fixations, run, targets, tlabels)
