"""Estimation in the live session (docs/live.md, The loop): an eye record and the head pose at
its time -> world view lines (the paper's eq. 1-8, through ``calibration`` and
``estimator.view_lines_to_world``), fixations detected online, a streaming estimator per
fixation, and at a fixation's end (``GazeEstimation.finish``, in the loop's target worker) its
lines tested for motion (``estimator.motion``: a moving point is published with its smoothed
path) or merged with the static targets seen before (``estimator.merge``, as ``process`` merges).

It lives in ``pipeline`` (no I/O here) so that ``process`` re-runs it on a live recording
(``pipeline.steps.live_replay``); the live session (``wearable_gaze.live``) imports it from here."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimator import (
    BinocularSample,
    BinocularSamples,
    GazeEstimate,
    Status,
    ViewLines,
    make_estimator,
    view_lines_to_world,
)
from estimator.direction import path_direction, with_direction
from estimator.motion import DEFAULT_KNOT_S, MIN_LINES, MOVING, classify_lines, smooth_trajectory
from estimator.result import covariance_ellipsoid
from estimator.segments import OnlineSegmenter

from ..types import Target
from .estimate import DEFAULT_ERROR_MODEL, model_options, static_direction, target_merger
from .target_status import estimate_status, target_status

log = logging.getLogger(__name__)

SIGMA_DEG = 1.0
"""The angular noise the motion test, the path and the merge test assume, degrees (``process``'s
default, and the streaming estimators')."""
MAX_END_LINES = 240
"""A finished fixation's lines are thinned evenly to at most this many (4 s at 60 Hz) before the
motion test, the path and the merge test (which keeps them for later revisits); the path's knots
are at least ``DEFAULT_KNOT_S`` apart and at most ``MAX_MOTION_KNOTS``: the cost, paid once per
fixation end in the target worker, stays bounded (about 0.2 s for the motion test on a 2-core
machine, against 12 s for a 20 s pursuit at 0.1 s knots)."""
MAX_MOTION_KNOTS = 30


@dataclass(frozen=True)
class LiveEstimate:
    """The running estimate of the current fixation's target after one sample.

    Attributes:
        t_s: the sample's session time, s.
        fixation: the fixation's index (0, 1, ... in the session).
        position_mm: (3,) estimated point, world frame, mm.
        covariance_mm2: (3, 3) its covariance, mm^2, or None.
        n_samples: samples the fixation's estimator has taken.
    """

    t_s: float
    fixation: int
    position_mm: np.ndarray
    covariance_mm2: np.ndarray | None
    n_samples: int

    @property
    def radius95_mm(self) -> float | None:
        """The largest radius of its 95 % ellipsoid, mm (None without a covariance); computed
        when asked, so that the loop's latency is measured before it, as before."""
        if self.covariance_mm2 is None:
            return None
        return float(covariance_ellipsoid(self.position_mm, self.covariance_mm2, 0.95).radii_mm.max())


class RayEyes:
    """The eye 'calibration' of a device that gives view lines itself: ``lines`` of raw readings
    (N, 6) (centre mm, unit direction; head frame) are those lines (the live estimation calls
    ``eyes[e].lines`` as it does an ``EyeCalibration``'s)."""

    @staticmethod
    def lines(raw) -> ViewLines:
        raw = np.asarray(raw, float).reshape(-1, 6)
        return ViewLines(raw[:, :3].copy(), raw[:, 3:].copy(), frame="cam")


def world_sample(eyes, t_s: float, rec, T_world_from_cam) -> BinocularSample:
    """One eye record as world view lines: each valid eye's camera-frame line (eq. 1-4,
    ``EyeCalibration.lines``) moved into the world by the head pose (eq. 7-8,
    ``estimator.view_lines_to_world``, both eyes in one call).

    Args:
        eyes: [left, right] ``EyeCalibration``.
        t_s: session time, s.
        rec: an ``EyeRecord`` with at least one valid eye (raw readings and validity per eye).
        T_world_from_cam: (4, 4) head pose at ``t_s``, mm.
    """
    valid = [e for e, ok in enumerate((rec.left_valid, rec.right_valid)) if ok]
    if all(isinstance(eyes[e], RayEyes) for e in valid) and (fast := _ray_world(rec, valid, T_world_from_cam)):
        return BinocularSample(t_s, *fast)
    cam = [eyes[e].lines(np.array([(rec.left, rec.right)[e]], float)) for e in valid]
    world = view_lines_to_world(ViewLines(np.concatenate([c.origins_mm for c in cam]),
                                          np.concatenate([c.directions for c in cam]), "cam"),
                                T_world_from_cam=T_world_from_cam)
    parts: list = [None] * 4
    for k, e in enumerate(valid):
        parts[2 * e:2 * e + 2] = world.origins_mm[k], world.directions[k]
    return BinocularSample(t_s, *parts)


def _unit_rows(d: np.ndarray) -> np.ndarray:
    return d / np.linalg.norm(d, axis=1)[:, None]


def _ray_world(rec, valid: list, T_world_from_cam) -> list | None:
    """``world_sample``'s four parts for a device's rays (``RayEyes``) without its argument checks
    (a third of the loop's CPU time a sample), computed by the same numpy operations in the same
    order, so the lines are bit for bit those of the checked path; None when a check would fail
    (a direction not finite or near zero, a pose not a proper rigid transform): the checked
    path then says why."""
    raw = np.array([(rec.left, rec.right)[e] for e in valid], float)
    T = np.asarray(T_world_from_cam, dtype=np.float64)
    n_raw = np.linalg.norm(raw[:, 3:], axis=1)
    if (raw.shape[1] != 6 or T.shape != (4, 4) or not np.all(np.isfinite(raw)) or np.any(n_raw <= 1e-12)
            or not np.all(np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)) <= 1e-6 + 1e-5 * np.eye(3))
            or np.linalg.det(T[:3, :3]) < 0 or not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])):
        return None
    d_cam = _unit_rows(raw[:, 3:] / n_raw[:, None])          # RayEyes.lines, then the lines of both eyes
    R = np.broadcast_to(T, (len(raw), 4, 4))[:, :3, :3]
    o_world = np.einsum("nij,nj->ni", R, raw[:, :3]) + np.broadcast_to(T, (len(raw), 4, 4))[:, :3, 3]
    d_world = _unit_rows(np.einsum("nij,nj->ni", R, d_cam))
    parts: list = [None] * 4
    for k, e in enumerate(valid):
        parts[2 * e:2 * e + 2] = o_world[k], d_world[k]
    return parts


class TargetIds:
    """Target ids kept across fixations (issue 15): a static fixation's lines and estimate go to
    the merge test (``estimator.merge.TargetMerger``, the one ``process`` merges with; groups
    re-estimated by ``method`` with the default error model): it takes the id of the group it
    joins, or a new one. A moving fixation gets a new id no later fixation takes. An id, once
    given, never changes meaning: groups only grow, and never merge with each other.

    Not thread-safe: only the loop's target worker calls it (fixations in order).
    """

    def __init__(self, method: str = "voxel", sigma_deg: float = SIGMA_DEG):
        self.merger = target_merger(method, sigma_deg, DEFAULT_ERROR_MODEL)     # poses tracked in the scene video
        self.group_ids: list[int] = []     # the id of each of the merger's groups
        self.n_ids = 0

    def __len__(self) -> int:
        return self.n_ids

    def id_for(self, lines: BinocularSamples, estimate: GazeEstimate, key=None) -> int:
        """The id of a finished static fixation's target: ``lines`` its view lines (world frame,
        mm, time order), ``estimate`` its own usable estimate, ``key`` kept in its group."""
        group = self.merger.add(lines, estimate, key)
        if group == len(self.group_ids):
            self.group_ids.append(self.new_own())
        return self.group_ids[group]

    def new_own(self) -> int:
        """A new id that no later fixation is matched to (a moving target's: as in ``process``, a
        moving fixation is a target of its own)."""
        self.n_ids += 1
        return self.n_ids - 1


@dataclass(frozen=True)
class FinishedFixation:
    """A fixation that has ended, as the loop hands it to the target worker: all its target
    needs, taken from the estimation's state at its end (``GazeEstimation.end_fixation``).

    Attributes:
        fixation: its index (0, 1, ... in the session).
        lines: its ``BinocularSample`` (world frame, time order), without the lines the segmenter
            took in before it saw the saccade.
        estimate: its streaming estimator's latest usable ``GazeEstimate``, or its latest one when none
            was usable (then ``finish`` answers the fixation by its direction).
        t_start, t_end: its first sample's and its latest estimate's session times, s.
        n_samples: samples its estimator took.
    """

    fixation: int
    lines: tuple
    estimate: GazeEstimate
    t_start: float
    t_end: float
    n_samples: int


def warm_up(method: str) -> None:
    """Run the estimator once on synthetic lines before the session starts: its first update
    in a process pays one-time costs (about 1.5 s for ``voxel``) that would otherwise hold up the
    first eye samples of the session."""
    est = make_estimator(method, **model_options(method, DEFAULT_ERROR_MODEL))
    X = np.array([100.0, -50.0, 1500.0])                       # a point 1.5 m ahead, mm
    for k in range(30):
        lo = np.array([-32.0 + 3.0 * np.sin(k), 0.0, 0.0])
        ro = lo + [64.0, 0.0, 0.0]
        est.update(BinocularSample(k / 60.0, lo, (X - lo) / np.linalg.norm(X - lo), ro,
                                   (X - ro) / np.linalg.norm(X - ro)))


class GazeEstimation:
    """Eye records with their head poses in; running estimates and finished fixations out (``add``,
    ``end_fixation``: cheap, on the loop's thread), and a finished fixation's target (``finish``:
    the motion and merge tests, in the loop's target worker; docs/live.md, The loop).

    Fixations are found online (``OnlineSegmenter``, on binocular samples' cyclopean rays, the
    world-frame test ``process`` makes); a sample inside a saccade belongs to no target; each fixation gets a fresh
    streaming estimator (``estimator.make_estimator(method)``), whose covariance for ``ml`` and
    ``voxel`` follows the default error model (``pipeline.steps.estimate.DEFAULT_ERROR_MODEL``).
    ``add`` and ``end_fixation`` are called from one thread, ``finish`` from one other (it alone
    touches ``targets``).

    Args:
        eyes: [left, right] ``EyeCalibration``.
        method: the streaming estimator.
    """

    def __init__(self, eyes, method: str = "voxel"):
        self.eyes = eyes
        self.method = method
        self.segmenter = OnlineSegmenter()
        self.targets = TargetIds(method)
        self.fixation = 0                 # the current fixation's index
        self._new_fixation()

    def _new_fixation(self) -> None:
        self.estimator = make_estimator(self.method, **model_options(self.method, DEFAULT_ERROR_MODEL))
        self.n_samples = 0
        self.t_start: float | None = None
        self.last: tuple | None = None    # (GazeEstimate, t_s) of the latest estimate
        self.lines: list = []             # the fixation's BinocularSample, for ``finish`` at its end

    @property
    def current_mm(self) -> np.ndarray | None:
        """(3,) the current fixation's latest estimate, world, mm (None before one)."""
        return None if self.last is None else self.last[0].position_mm

    def add(self, t_s: float, rec, T_world_from_cam) -> tuple[FinishedFixation | None, LiveEstimate | None]:
        """One eye record at session time ``t_s`` with at least one valid eye, and the head pose
        (4, 4) at that time.

        Returns:
            (the fixation this sample ended, for ``finish``, or None; the running estimate after
            this sample, or None: in a saccade, or the estimator has none yet).
        """
        sample = world_sample(self.eyes, t_s, rec, T_world_from_cam)
        ended = None
        # both eyes valid (world_sample gives a line for each valid eye, None for the others); one
        # eye alone is off the cyclopean line by half the vergence: not a saccade
        if (sample.left_direction is not None and sample.right_direction is not None
                and sample.left_origin_mm is not None and sample.right_origin_mm is not None):
            cyc = sample.left_direction + sample.right_direction
            mid = 0.5 * (sample.left_origin_mm + sample.right_origin_mm)
            lines = (np.array([sample.left_origin_mm, sample.right_origin_mm]),
                     np.array([sample.left_direction, sample.right_direction]))
            if self.segmenter.update(t_s, cyc / np.linalg.norm(cyc), mid, lines):
                # a saccade seen, or a gap
                ended = self.end_fixation(self.segmenter.config.window if self.segmenter.in_saccade else 0)
        if self.segmenter.in_saccade:                       # between fixations: no target's line
            return ended, None
        if self.t_start is None:
            self.t_start = t_s
        est = self.estimator.update(sample)
        self.n_samples += 1
        self.lines.append(sample)
        if not est.ok:
            return ended, None
        self.last = (est, t_s)
        return ended, LiveEstimate(t_s, self.fixation, est.position_mm, est.covariance_mm2, self.n_samples)

    def end_fixation(self, saccade_lines: int = 0) -> FinishedFixation | None:
        """End the current fixation (a saccade, or the session's end); the next starts afresh.
        Cheap, on the loop's thread: returns what its target needs (``finish`` makes it) when it
        lasted ``min_fixation_s``, else None. Its lines but the last
        ``saccade_lines`` (a saccade is seen once it fills half the segmenter's windows: up to
        ``window`` lines already after it) are kept. A fixation whose estimator gave no usable
        estimate is handed on with its latest one (``finish`` answers it by its direction when its
        lines fix one)."""
        done = None
        t_last = self.last[1] if self.last is not None else (self.lines[-1].t_s if self.lines else None)
        if (t_last is not None and self.t_start is not None
                and t_last - self.t_start >= self.segmenter.config.min_fixation_s):
            # no usable estimate: the lines may still fix a direction (finish answers it)
            est = self.last[0] if self.last is not None else self.estimator.estimate()
            done = FinishedFixation(self.fixation, tuple(self.lines[:len(self.lines) - saccade_lines]), est,
                                    self.t_start, t_last, self.n_samples)
        self.fixation += 1
        self._new_fixation()
        return done

    def finish(self, done: FinishedFixation) -> Target | None:
        """The target of a finished fixation (in the loop's target worker, fixations in order):
        ``finish_ended`` of its lines thinned (``thin_fixation``)."""
        return self.finish_ended(thin_fixation(done))

    def finish_ended(self, done: EndedFixation) -> Target | None:
        """The target of a finished fixation, its lines thinned (``thin_fixation``; fixations in
        order: in the loop's target worker, or the live session's target process).

        Its lines are tested for motion (``estimator.motion.classify_lines``, as ``process``
        does): a moving point is a moving target (``moving_target``) with a new id. A static one
        (``pipeline.types.Target``: its own estimate) has as ``index`` the id of the target whose
        lines its own join (``TargetIds.id_for``, the merge test ``process`` runs), or a new one;
        its one fixation in ``fixations``; no Cramér-Rao bound (NaN); its status from
        ``pipeline.steps.target_status.estimate_status`` (as ``process``) and its direction. One without
        a usable point is direction-only (``direction_target``); None when its lines give no
        direction either."""
        samples = done.samples
        target = None if samples is None else self.moving_target(done, samples)
        if target is not None:
            return target
        est = done.estimate
        if not est.ok or est.position_mm is None:
            return self.direction_target(done, samples)
        r = est.ellipsoid(0.95)
        index = (self.targets.new_own() if samples is None
                 else self.targets.id_for(samples, est, key=done.fixation))
        status = estimate_status(est, samples) if samples is not None else str(est.status.value)
        return Target(index=index, position_mm=est.position_mm, covariance_mm2=est.covariance_mm2,
                      axes95_mm=np.full(3, np.nan) if r is None else r.radii_mm, status=status,
                      n_samples=done.n_samples, t_start=done.t_start, t_end=done.t_end, fixations=(done.fixation,),
                      method=self.method, crb_mm=float("nan"), sight=est.sight(),
                      direction=None if samples is None else static_direction(est, samples, status,
                                                                              DEFAULT_ERROR_MODEL))

    def direction_target(self, done: EndedFixation, samples: BinocularSamples | None) -> Target | None:
        """The target of a finished static fixation without a usable point: direction-only
        (``estimator.direction.with_direction``, as ``process`` answers it) with an id of its
        own, or None when its lines give no direction either."""
        if samples is None:
            return None
        est = with_direction(done.estimate, samples, DEFAULT_ERROR_MODEL)
        if est.status is not Status.DIRECTION_ONLY:
            return None
        return Target(index=self.targets.new_own(), position_mm=np.full(3, np.nan), covariance_mm2=None,
                      axes95_mm=np.full(3, np.nan), status=estimate_status(est, samples), n_samples=done.n_samples,
                      t_start=done.t_start, t_end=done.t_end, fixations=(done.fixation,), method=self.method,
                      crb_mm=float("nan"), direction=est.direction)

    def moving_target(self, done: EndedFixation, samples: BinocularSamples) -> Target | None:
        """The target of the finished fixation ``done`` when its (thinned) lines ``samples``
        (world frame, time order) are of a moving point, else None: its path
        (``estimator.motion.smooth_trajectory``) in ``trajectory``, its point the path's at the
        middle knot with that knot's covariance and its direction there
        (``estimator.direction.path_direction``), status 'moving' (or why not, as
        ``pipeline.steps.target_status.target_status`` says), as ``process`` reports one."""
        if len(samples) < MIN_LINES:
            return None
        knot_s = max(DEFAULT_KNOT_S, float(np.ptp(samples.t_s)) / (MAX_MOTION_KNOTS - 1))
        if classify_lines(samples, SIGMA_DEG, knot_s=knot_s).kind != MOVING:
            return None
        path = smooth_trajectory(samples, SIGMA_DEG, knot_s=knot_s, error_model=DEFAULT_ERROR_MODEL)
        pos, cov = path.middle()
        radii = np.asarray(covariance_ellipsoid(pos, cov, 0.95).radii_mm, float)
        log.debug("fixation %d: a moving target over %d lines", done.fixation, len(samples))
        t_end = done.t_end if done.t_last_line is None else done.t_last_line
        return Target(index=self.targets.new_own(), position_mm=np.asarray(pos, float), covariance_mm2=cov,
                      axes95_mm=radii, status=target_status(MOVING, pos, radii, samples), n_samples=done.n_samples,
                      t_start=done.t_start, t_end=t_end, fixations=(done.fixation,),
                      method=self.method, crb_mm=float("nan"), moving=True, trajectory=path,
                      direction=path_direction(samples, path))


@dataclass(frozen=True)
class EndedFixation:
    """A finished fixation as its target is made from it (``GazeEstimation.finish_ended``):
    ``FinishedFixation``'s fields, its lines thinned evenly to at most ``MAX_END_LINES`` as arrays
    (a few kB: the live session sends it to its target process).

    Attributes:
        samples: the thinned lines (world frame, time order), or None when it had none.
        t_last_line: its last line's session time (before thinning), s, or None.
        fixation, estimate, t_start, t_end, n_samples: ``FinishedFixation``'s.
    """

    fixation: int
    samples: BinocularSamples | None
    t_last_line: float | None
    estimate: GazeEstimate
    t_start: float
    t_end: float
    n_samples: int


def thin_fixation(done: FinishedFixation) -> EndedFixation:
    """``done`` with its lines thinned evenly to at most ``MAX_END_LINES`` (every ``step``-th
    from the first) and as arrays, for ``GazeEstimation.finish_ended``."""
    step = -(-len(done.lines) // MAX_END_LINES)                  # ceil: at most MAX_END_LINES
    samples = lines_to_samples(done.lines[::step]) if done.lines else None
    return EndedFixation(done.fixation, samples, float(done.lines[-1].t_s) if done.lines else None, done.estimate,
                         done.t_start, done.t_end, done.n_samples)


def lines_to_samples(lines: Sequence[BinocularSample]) -> BinocularSamples:
    """Streaming ``BinocularSample`` (a missing eye's origin and direction None) as
    ``BinocularSamples`` (NaN where an eye is missing), world frame."""
    nan = np.full(3, np.nan)

    def rows(name):
        return [nan if getattr(s, name) is None else getattr(s, name) for s in lines]

    return BinocularSamples.from_arrays([s.t_s for s in lines], rows("left_origin_mm"), rows("left_direction"),
                                        rows("right_origin_mm"), rows("right_direction"))
