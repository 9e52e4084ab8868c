"""The fixations step of ``process``: the fixations of segmented view lines each estimated as a
live session would, fixations of one point merged into targets (revisits are common); and the
files it writes (viewlines.csv with the fixation labels, estimates.csv, targets.csv,
targets.json and target_labels.npy, each through its formats module; docs/processing.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import BinocularSamples, GazeEstimate, angular_log_likelihood, run_estimator
from estimator.segments import same_target

from ..formats.targets import ESTIMATE_COLUMNS, write_estimates, write_target_labels, write_targets
from ..formats.viewlines import write_viewlines_csv
from .estimate import estimate_target, radius95_mm, running_estimate
from .types import Fixation, TargetsResult

log = logging.getLogger(__name__)



def find_targets(samples: BinocularSamples, labels: np.ndarray, method: str, sigma_deg: float,
                 progress=None) -> TargetsResult:
    """Estimate each fixation of view lines (N,) segmented into fixations (its running estimate
    too), merge the fixations of one target and estimate each target from all its lines.

    Args:
        samples: world view lines, in time order.
        labels: (N,) fixation index of each view line, -1 none
            (``estimator.segments.segment_fixations``).
        method, sigma_deg: the estimator and its angular noise.
        progress: called as progress(done, total) after each fixation.
    """
    n_seg = int(labels.max()) + 1 if (labels >= 0).any() else 0
    fixations = []
    running = {k: [] for k in ESTIMATE_COLUMNS}
    for k in range(n_seg):
        idx = np.flatnonzero(labels == k)
        e, usable = running_estimate(samples.select(idx), method, sigma_deg)
        fixations.append(Fixation(k, idx, e))
        for t, ek in usable:
            for name, v in zip(ESTIMATE_COLUMNS, (t, k, *(float(v) for v in ek.position_mm), radius95_mm(ek)),
                               strict=True):
                running[name].append(v)
        if progress:
            progress(k + 1, n_seg + 1)
    groups = merge_fixations(fixations, samples, method, sigma_deg)
    targets = [estimate_target(i, samples, g.samples, g.fixations, g.estimate, method, sigma_deg)
               for i, g in enumerate(groups)]
    tlabels = np.full(len(samples), -1)
    for tg in targets:
        tlabels[tg.samples] = tg.index
    log.info("%d fixation(s), %d target(s) from %d view lines", n_seg, len(targets), len(samples))
    return TargetsResult(samples, labels, fixations, {k: np.array(v) for k, v in running.items()}, targets, tlabels)


@dataclass
class _Group:
    """Fixations merged so far: their view lines, fixation indices and estimate."""

    samples: np.ndarray
    fixations: list = field(default_factory=list)
    estimate: GazeEstimate | None = None


def merge_fixations(fixations: list, samples: BinocularSamples, method: str, sigma_deg: float) -> list:
    """Fixations of one target (``estimator.segments.same_target``, seen from the first sample's
    eye) merged and estimated again from all their lines; fixations without a usable estimate
    are left out. Returns the groups in order of first fixation."""
    groups = []
    for f in fixations:
        if not f.usable:
            continue
        e, first = f.estimate, f.samples[0]
        origin = samples.left_origin_mm[first] if samples.left_valid[first] else samples.right_origin_mm[first]
        for g in groups:
            ge = g.estimate
            if same_target(e.position_mm, e.covariance_mm2, ge.position_mm, ge.covariance_mm2, origin=origin):
                both = np.sort(np.concatenate([g.samples, f.samples]))
                merged = run_estimator(samples.select(both), method, sigma_deg)[1]
                if not _lines_agree(samples, (g.samples, ge), (f.samples, e), merged, sigma_deg):
                    continue
                g.samples, g.estimate = both, merged
                g.fixations.append(f.index)
                break
        else:
            groups.append(_Group(f.samples, [f.index], e))
    return groups


MERGE_LR_THRESHOLD = 16.27     # chi-square 99.9 % point, 3 dof


def _lines_agree(samples: BinocularSamples, a, b, merged: GazeEstimate, sigma_deg: float) -> bool:
    """Whether two fixations' lines (``a``, ``b``: (sample indices, estimate)) fit one point:
    the likelihood-ratio test of one point against two (3 more parameters), on the angular noise
    model. ``same_target`` compares the two estimates' covariances, which cannot reject when one
    fixation fixes its point poorly (a still head at 10 Hz: a depth range of metres); merging then
    drags the good estimate toward the poor one's lines. This test uses the lines themselves."""
    if not merged.ok:
        return False
    sigma = np.deg2rad(sigma_deg)
    ll = 0.0
    for idx, e in (a, b):
        lines = samples.select(idx).lines()
        ll += float(angular_log_likelihood(e.position_mm[None], lines.origins_mm, lines.directions, sigma)[0])
        ll -= float(angular_log_likelihood(merged.position_mm[None], lines.origins_mm, lines.directions, sigma)[0])
    return 2.0 * ll < MERGE_LR_THRESHOLD


def write_targets_step(out: Path, result: TargetsResult, method: str) -> None:
    """The step's files in ``out``: viewlines.csv (with fixation labels), and through
    formats/targets.py estimates.csv, targets.csv and targets.json (the rows of ``Target.row``)
    and target_labels.npy (the target of every view line)."""
    write_viewlines_csv(out / "viewlines.csv", result.samples, result.labels)
    write_estimates(out / "estimates.csv", result.running)
    write_targets(out, [tg.row() for tg in result.targets], method)
    write_target_labels(out / "target_labels.npy", result.target_labels)
