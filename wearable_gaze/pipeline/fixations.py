"""The fixations step of ``process``: the fixations of segmented view lines each estimated as a
live session would, fixations of one point merged into targets (revisits are common); and the
files it writes (viewlines.csv with the fixation labels, estimates.csv, targets.csv,
targets.json and target_labels.npy, each through its formats module; docs/processing.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from estimator import BinocularSamples, GazeEstimate, run_estimator
from estimator.errormodel import ErrorModel
from estimator.frames import tangent_basis
from estimator.likelihood import gnomonic_residuals
from estimator.motion import MOVING, STATIC, TWO_POINTS, Trajectory, classify_lines, smooth_trajectory
from estimator.result import covariance_ellipsoid

from ..formats.targets import (
    ESTIMATE_COLUMNS,
    write_estimates,
    write_target_labels,
    write_target_paths,
    write_targets,
)
from ..formats.viewlines import write_viewlines_csv
from .estimate import estimate_target, model_options, radius95_mm, running_estimate, target_status
from .types import Fixation, Target, TargetsResult

log = logging.getLogger(__name__)

MIN_SPLIT_SAMPLES = 5
"""A fixation of two points is split only when each part keeps this many samples."""


def find_targets(samples: BinocularSamples, labels: np.ndarray, method: str, sigma_deg: float,
                 progress=None, error_model: ErrorModel | None = None) -> TargetsResult:
    """Test each fixation of view lines (N,) segmented into fixations for motion, estimate the
    static ones (their running estimates too), merge the static fixations of one target and
    estimate each target from all its lines; a moving fixation is a moving target of its own.

    A fixation of two points (a switch the segmenter missed) is split at the switch into two
    fixations, the labels renumbered in time order (``split_two_point_fixations``); a moving one
    gets its path (``estimator.motion.smooth_trajectory``).

    Args:
        samples: world view lines, in time order.
        labels: (N,) fixation index of each view line, -1 none
            (``estimator.segments.segment_fixations``).
        method, sigma_deg: the estimator and its angular noise.
        progress: called as progress(done, total) after each fixation.
        error_model: the covariances' error model for ``ml`` and ``voxel`` (running estimates,
            fixations, merges and targets); None: the inverse Fisher information.
    """
    labels, motion = split_two_point_fixations(samples, labels, sigma_deg)
    n_seg = len(motion)
    fixations = []
    running = {k: [] for k in ESTIMATE_COLUMNS}
    for k in range(n_seg):
        idx = np.flatnonzero(labels == k)
        fixations.append(_fixation(samples, k, idx, motion[k], method, sigma_deg, running, error_model))
        if progress:
            progress(k + 1, n_seg + 1)
    groups = merge_fixations(fixations, samples, method, sigma_deg, error_model)
    groups += [_Group(f.samples, [f.index], None, f.trajectory) for f in fixations if f.motion == MOVING]
    groups.sort(key=lambda g: g.fixations[0])
    targets = [moving_target(i, samples, g, method) if g.trajectory is not None else
               estimate_target(i, samples, g.samples, g.fixations, g.estimate, method, sigma_deg)
               for i, g in enumerate(groups)]
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
        return Fixation(k, idx, None, MOVING, smooth_trajectory(samples.select(idx), sigma_deg))
    e, usable = running_estimate(samples.select(idx), method, sigma_deg, error_model=error_model)
    for t, ek in usable:
        for name, v in zip(ESTIMATE_COLUMNS, (t, k, *(float(v) for v in ek.position_mm), radius95_mm(ek)),
                           strict=True):
            running[name].append(v)
    return Fixation(k, idx, e)


def split_two_point_fixations(samples: BinocularSamples, labels: np.ndarray,
                              sigma_deg: float) -> tuple[np.ndarray, list]:
    """Each fixation's motion test (``estimator.motion.classify_lines``); a fixation of two
    points split at its switch time into two (when each part keeps ``MIN_SPLIT_SAMPLES``).
    Returns the new (N,) labels, numbered 0, 1, ... in time order (-1 kept), and each new
    fixation's motion, 'static' or 'moving'."""
    n_seg = int(labels.max()) + 1 if (labels >= 0).any() else 0
    out = np.full(len(labels), -1)
    motion = []
    for k in range(n_seg):
        idx = np.flatnonzero(labels == k)
        if not len(idx):
            continue
        test = classify_lines(samples.select(idx), sigma_deg)
        parts = [idx]
        if test.kind == TWO_POINTS:
            before = samples.t_s[idx] < test.split_t
            if min(before.sum(), (~before).sum()) >= MIN_SPLIT_SAMPLES:
                parts = [idx[before], idx[~before]]
        for part in parts:
            out[part] = len(motion)
            motion.append(MOVING if test.kind == MOVING else STATIC)
        log.debug("fixation %d: %s over %d samples", k, test.kind, len(idx))
    return out, motion


def moving_target(index: int, samples: BinocularSamples, group, method: str) -> Target:
    """The moving target of one moving fixation (``group``: its view lines and path): its point
    is the path's position at the middle knot, with that knot's covariance, status 'moving'."""
    tr = group.trajectory
    pos, cov = tr.middle()
    idx = group.samples
    t = samples.t_s[idx]
    radii = np.asarray(covariance_ellipsoid(pos, cov, 0.95).radii_mm, float)
    return Target(index=index, position_mm=np.asarray(pos, float), covariance_mm2=cov,
                  axes95_mm=radii, status=target_status(MOVING, pos, radii, samples.select(idx)),
                  n_samples=len(idx), t_start=float(t.min()), t_end=float(t.max()),
                  fixations=tuple(int(f) for f in group.fixations), method=method, crb_mm=float("nan"),
                  samples=idx, moving=True, trajectory=tr)


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
                    error_model: ErrorModel | None = None) -> list:
    """Static fixations of one target merged and estimated again from all their lines: each
    fixation joins the group (seen within ``MERGE_MAX_DEG`` of it from the fixation's first eye)
    whose lines fit one point with its own best (``merge_statistic`` below
    ``MERGE_LR_THRESHOLD``, the least of them), else starts a group; fixations without a usable
    estimate are left out; merged estimates' covariances follow ``error_model``. Returns the groups
    in order of first fixation."""
    groups = []
    for f in fixations:
        if not f.usable:
            continue
        e, first = f.estimate, f.samples[0]
        origin = samples.left_origin_mm[first] if samples.left_valid[first] else samples.right_origin_mm[first]
        scored = []
        for g in groups:
            u, v = e.position_mm - origin, g.estimate.position_mm - origin
            if np.degrees(np.arccos(np.clip(u @ v / (np.linalg.norm(u) * np.linalg.norm(v)), -1, 1))) > MERGE_MAX_DEG:
                continue
            lr = merge_statistic(samples, (g.parts, g.estimate.position_mm), ([f.samples], e.position_mm), sigma_deg)
            if lr < MERGE_LR_THRESHOLD:
                scored.append((lr, len(scored), g))
        for _, _, g in sorted(scored, key=lambda x: x[:2]):
            both = np.sort(np.concatenate([g.samples, f.samples]))
            merged = run_estimator(samples.select(both), method, sigma_deg, **model_options(method, error_model))[1]
            if merged.ok:
                g.samples, g.estimate = both, merged
                g.fixations.append(f.index)
                g.parts.append(f.samples)
                break
        else:
            groups.append(_Group(f.samples, [f.index], e, parts=[f.samples]))
    return groups


MERGE_LR_THRESHOLD = 16.27     # chi-square 99.9 % point, 3 dof
MERGE_MAX_DEG = 5.0
"""Only groups seen within this angle of a fixation's estimate are tested (a shortcut: the test
rejects anything this far off)."""
MERGE_BIAS_DEG = 0.5
"""The merge test's prior on each eye's fixed angular offset (standard deviation per axis,
degrees): an eye calibration's bias, the same in every fixation."""
MERGE_FIXATION_DEG = 0.1
"""... and on each eye's offset in one fixation beyond it (the calibration's error differs with
where the eye looks, which the head changes between revisits)."""


def merge_statistic(samples: BinocularSamples, a, b, sigma_deg: float) -> float:
    """The likelihood-ratio statistic of one point against two (3 more parameters) for two sets
    of fixations (``a``, ``b``: (a list of each fixation's sample indices, start point (3,) mm)),
    on the angular noise model with two offsets of each eye's lines marginalised out
    (``_bias_chi2``): one shared by all the fixations (prior sd ``MERGE_BIAS_DEG`` per axis: an
    eye calibration's bias) and one of each fixation (``MERGE_FIXATION_DEG``: the calibration's
    error differs where the eye looks), each chi2 minimised from the start points.

    It uses the lines themselves, not the estimates' covariances, which cannot reject when one
    fixation fixes its point poorly (a still head at 10 Hz: a depth range of metres; merging
    then drags the good estimate toward the poor one's lines). The offsets keep the revisits of
    a target seen through a biased eye calibration from a walking head together (without them
    most revisits were new targets); the shared one cannot explain two points seen a few
    degrees apart."""
    sigma = np.deg2rad(sigma_deg)
    chunks = [(line, k, (k, j)) for k, (parts, _) in enumerate((a, b)) for j, idx in enumerate(parts)
              for line in _eye_lines(samples.select(idx))]
    apart = _min_bias_chi2(chunks, np.concatenate([a[1], b[1]]), sigma)
    together = _min_bias_chi2([(line, 0, f) for line, _, f in chunks], np.asarray(a[1], float), sigma)
    return together - apart


def _eye_lines(s: BinocularSamples) -> list:
    """The lines of each eye with any: [(eye 0 left / 1 right, origins (n, 3), directions (n, 3),
    b1, b2), ...]."""
    out = []
    for eye, (valid, o, d) in enumerate(((s.left_valid, s.left_origin_mm, s.left_direction),
                                         (s.right_valid, s.right_origin_mm, s.right_direction))):
        if valid.any():
            out.append((eye, o[valid], d[valid], *tangent_basis(d[valid])))
    return out


def _bias_chi2(X, chunks, sigma: float) -> float:
    """chi2 of line chunks, ``(eye lines, point k, fixation key)`` each, at their points ``X``
    (3K,), with per eye a shared offset (sd ``MERGE_BIAS_DEG`` per axis) and one per fixation
    (``MERGE_FIXATION_DEG``) marginalised: per axis the residuals' covariance is
    ``sigma^2 I + f_i^2 (block ones) + f_s^2 (ones)``, inverted in closed form (Woodbury)."""
    P = np.asarray(X, float).reshape(-1, 3)
    fs2, fi2, s2 = np.deg2rad(MERGE_BIAS_DEG) ** 2, np.deg2rad(MERGE_FIXATION_DEG) ** 2, sigma**2
    total = 0.0
    for eye in (0, 1):
        sums = {}
        for (e, o, d, b1, b2), k, key in chunks:
            if e == eye:
                r = gnomonic_residuals(P[k], o, d, b1, b2)[0]
                q, sm, n = sums.get(key, (0.0, np.zeros(2), 0))
                sums[key] = (q + float(np.sum(r * r)), sm + r.sum(axis=0), n + len(r))
        u, w = np.zeros(2), 0.0
        for q, sm, n in sums.values():
            total += q / s2 - fi2 * float(sm @ sm) / (s2 * (s2 + n * fi2))
            u += sm / (s2 + n * fi2)
            w += n / (s2 + n * fi2)
        total -= fs2 * float(u @ u) / (1.0 + fs2 * w)
    return total


def _min_bias_chi2(chunks, x0, sigma: float) -> float:
    """The least ``_bias_chi2`` over the points, from ``x0`` (3K,) (searched in units of 100 mm)."""
    x0 = np.asarray(x0, float)
    fit = minimize(lambda z: _bias_chi2(100.0 * z, chunks, sigma), x0 / 100.0, method="BFGS",
                   options={"gtol": 1e-4})
    return float(fit.fun)


def write_targets_step(out: Path, result: TargetsResult, method: str) -> None:
    """The step's files in ``out``: viewlines.csv (with fixation labels), and through
    formats/targets.py estimates.csv, targets.csv and targets.json (the rows of ``Target.row``),
    target_paths.csv (the moving targets' paths) and target_labels.npy (the target of every
    view line)."""
    write_viewlines_csv(out / "viewlines.csv", result.samples, result.labels)
    write_estimates(out / "estimates.csv", result.running)
    write_targets(out, [tg.row() for tg in result.targets], method)
    write_target_paths(out / "target_paths.csv", {tg.index: (tg.trajectory.t_s, tg.trajectory.positions_mm,
                                                            tg.trajectory.covariances_mm2)
                                                 for tg in result.targets if tg.trajectory is not None})
    write_target_labels(out / "target_labels.npy", result.target_labels)
