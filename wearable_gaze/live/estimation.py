"""Estimation in the live session (docs/live.md, The loop): an eye record and the head pose at
its time -> world view lines (the paper's eq. 1-8, through ``calibration`` and
``estimator.view_lines_to_world``), fixations detected online, a streaming estimator per
fixation, target ids kept across fixations, and a finished fixation's lines tested for motion
(``estimator.motion``): a moving point is published with its smoothed path."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from estimator import BinocularSample, BinocularSamples, ViewLines, make_estimator, view_lines_to_world
from estimator.motion import DEFAULT_KNOT_S, MIN_LINES, MOVING, classify_lines, smooth_trajectory
from estimator.result import covariance_ellipsoid
from estimator.segments import OnlineSegmenter, same_target

from ..pipeline.estimate import DEFAULT_ERROR_MODEL, model_options, target_status
from ..pipeline.types import Target

log = logging.getLogger(__name__)

MOTION_SIGMA_DEG = 1.0
"""The angular noise the motion test and the path assume, degrees (``process``'s default)."""
MAX_MOTION_LINES = 240
"""A finished fixation's lines are thinned evenly to at most this many (4 s at 60 Hz) before the
motion test and the path, whose knots are at least ``DEFAULT_KNOT_S`` apart and at most
``MAX_MOTION_KNOTS``: their cost, paid once per fixation end in the loop, stays bounded (about
0.2 s on a 2-core machine, against 12 s for a 20 s pursuit at 0.1 s knots)."""
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
    cam = [eyes[e].lines(np.array([(rec.left, rec.right)[e]], float)) for e in valid]
    world = view_lines_to_world(ViewLines(np.concatenate([c.origins_mm for c in cam]),
                                          np.concatenate([c.directions for c in cam]), "cam"),
                                T_world_from_cam=T_world_from_cam)
    parts: list = [None] * 4
    for k, e in enumerate(valid):
        parts[2 * e:2 * e + 2] = world.origins_mm[k], world.directions[k]
    return BinocularSample(t_s, *parts)


class TargetIds:
    """Target ids: an estimate that is a target seen before (``estimator.segments.same_target``,
    as ``process`` merges fixations) gets that target's id, any other a new one."""

    def __init__(self):
        self.known: list = []        # (position_mm (3,), covariance_mm2 (3, 3) or None) of each id,
                                     # None for a moving target's (never matched again)

    def __len__(self) -> int:
        return len(self.known)

    def id_for(self, position_mm, covariance_mm2, origin_mm=None) -> int:
        """The id of the target at ``position_mm`` (world, mm), seen from ``origin_mm``."""
        for k, known in enumerate(self.known):
            if known is not None and same_target(position_mm, covariance_mm2, *known, origin=origin_mm):
                return k
        self.known.append((position_mm, covariance_mm2))
        return len(self.known) - 1

    def new_moving(self) -> int:
        """A new id for a moving target (as in ``process``, a moving fixation is a target of its
        own: no later fixation is matched to it)."""
        self.known.append(None)
        return len(self.known) - 1


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
    """Eye records with their head poses in; running estimates and finished fixations' targets out.

    Fixations are found online (``OnlineSegmenter``, on binocular samples' cyclopean
    directions); a sample inside a saccade belongs to no target; each fixation gets a fresh
    streaming estimator (``estimator.make_estimator(method)``), whose covariance for ``ml`` and
    ``voxel`` follows the default error model (``pipeline.estimate.DEFAULT_ERROR_MODEL``).

    Args:
        eyes: [left, right] ``EyeCalibration``.
        method: the streaming estimator.
    """

    def __init__(self, eyes, method: str = "voxel"):
        self.eyes = eyes
        self.method = method
        self.segmenter = OnlineSegmenter()
        self.targets = TargetIds()
        self.fixation = 0                 # the current fixation's index
        self.head_mm = None               # (3,) an eye's origin at the latest sample, world, mm
        self._new_fixation()

    def _new_fixation(self) -> None:
        self.estimator = make_estimator(self.method, **model_options(self.method, DEFAULT_ERROR_MODEL))
        self.n_samples = 0
        self.t_start: float | None = None
        self.last: tuple | None = None    # (GazeEstimate, t_s) of the latest estimate
        self.lines: list = []             # the fixation's BinocularSample, for the motion test at its end

    @property
    def current_mm(self) -> np.ndarray | None:
        """(3,) the current fixation's latest estimate, world, mm (None before one)."""
        return None if self.last is None else self.last[0].position_mm

    def add(self, t_s: float, rec, T_world_from_cam) -> tuple[Target | None, LiveEstimate | None]:
        """One eye record at session time ``t_s`` with at least one valid eye, and the head pose
        (4, 4) at that time.

        Returns:
            (the target of the fixation this sample ended, or None; the running estimate after
            this sample, or None: in a saccade, or the estimator has none yet).
        """
        sample = world_sample(self.eyes, t_s, rec, T_world_from_cam)
        self.head_mm = sample.left_origin_mm if sample.left_origin_mm is not None else sample.right_origin_mm
        ended = None
        if rec.left_valid and rec.right_valid:              # one eye alone is off the cyclopean line by
            cyc = sample.left_direction + sample.right_direction    # half the vergence: not a saccade
            if self.segmenter.update(t_s, cyc / np.linalg.norm(cyc)):      # a saccade seen, or a gap
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

    def end_fixation(self, saccade_lines: int = 0) -> Target | None:
        """End the current fixation (a saccade, or the session's end): its target when it lasted
        ``min_fixation_s`` and had an estimate, else None. The next fixation starts afresh.

        Its lines but the last ``saccade_lines`` (a saccade is seen once it fills half the
        segmenter's windows: up to ``window`` lines already after it), thinned to
        ``MAX_MOTION_LINES``, are tested for motion (``estimator.motion.classify_lines``, as
        ``process`` does): a moving point is a moving target (``moving_target``) with a new id.
        A static one (``pipeline.types.Target``) has the id of the same target seen before, or a
        new one, as ``index``; its one fixation in ``fixations``; no Cramér-Rao bound (NaN)."""
        target = None
        if (self.last is not None and self.t_start is not None
                and self.last[1] - self.t_start >= self.segmenter.config.min_fixation_s):
            target = self.moving_target(self.lines[:len(self.lines) - saccade_lines])
            if target is None:
                est, t_end = self.last
                r = est.ellipsoid(0.95)
                target = Target(index=self.targets.id_for(est.position_mm, est.covariance_mm2, self.head_mm),
                                position_mm=est.position_mm, covariance_mm2=est.covariance_mm2,
                                axes95_mm=np.full(3, np.nan) if r is None else r.radii_mm,
                                status=str(est.status.value), n_samples=self.n_samples, t_start=self.t_start,
                                t_end=t_end, fixations=(self.fixation,), method=self.method, crb_mm=float("nan"))
        self.fixation += 1
        self._new_fixation()
        return target

    def moving_target(self, lines: list) -> Target | None:
        """The current fixation's target when its ``lines`` (``BinocularSample``, in time order)
        are of a moving point, else None: its path (``estimator.motion.smooth_trajectory``) in
        ``trajectory``, its point the path's at the middle knot with that knot's covariance,
        status 'moving' (or why not, as ``pipeline.estimate.target_status`` says), as ``process``
        reports one."""
        if len(lines) < MIN_LINES:
            return None
        step = -(-len(lines) // MAX_MOTION_LINES)                    # ceil: at most MAX_MOTION_LINES
        samples = lines_to_samples(lines[::step])
        knot_s = max(DEFAULT_KNOT_S, float(np.ptp(samples.t_s)) / (MAX_MOTION_KNOTS - 1))
        if classify_lines(samples, MOTION_SIGMA_DEG, knot_s=knot_s).kind != MOVING:
            return None
        path = smooth_trajectory(samples, MOTION_SIGMA_DEG, knot_s=knot_s)
        pos, cov = path.middle()
        radii = np.asarray(covariance_ellipsoid(pos, cov, 0.95).radii_mm, float)
        log.debug("fixation %d: a moving target over %d lines", self.fixation, len(samples))
        return Target(index=self.targets.new_moving(), position_mm=np.asarray(pos, float), covariance_mm2=cov,
                      axes95_mm=radii, status=target_status(MOVING, pos, radii, samples), n_samples=self.n_samples,
                      t_start=self.t_start, t_end=float(lines[-1].t_s), fixations=(self.fixation,),
                      method=self.method, crb_mm=float("nan"), moving=True, trajectory=path)


def lines_to_samples(lines: list) -> BinocularSamples:
    """Streaming ``BinocularSample`` (a missing eye's origin and direction None) as
    ``BinocularSamples`` (NaN where an eye is missing), world frame."""
    nan = np.full(3, np.nan)

    def rows(name):
        return [nan if getattr(s, name) is None else getattr(s, name) for s in lines]

    return BinocularSamples.from_arrays([s.t_s for s in lines], rows("left_origin_mm"), rows("left_direction"),
                                        rows("right_origin_mm"), rows("right_direction"))
