"""Static fixations of one target merged across revisits (issue 15; docs/processing.md, Merging):
a fixation joins the earlier group whose lines and its own fit one point (a likelihood-ratio
test on the pooled view lines, each eye's calibration offsets marginalised), else it starts a
group of its own. Groups never merge with each other, so a group's id, once given, keeps its
meaning. ``process`` (``wearable_gaze.pipeline.steps.fixations.merge_fixations``) and the live session
(``wearable_gaze.pipeline.steps.live_estimation.TargetIds``) both use ``TargetMerger``.

World frame, mm, seconds; angles in degrees where the name says ``_deg``."""

from __future__ import annotations

import functools
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize

from .deprecation import module_getattr
from .frames import angle_deg
from .likelihood import gnomonic_residuals
from .lines import BinocularSamples
from .mergeform import GN_STEPS, Chart, MergeForm, _eye_lines, fixation_form, least_chi2
from .result import GazeEstimate

if TYPE_CHECKING:
    from .api import PooledEstimate

MERGE_LR_THRESHOLD = 16.27     # chi-square 99.9 % point, 3 dof
MERGE_MAX_DEG = 5.0
"""Only groups seen within this angle of a fixation's estimate are tested (a shortcut: the test
rejects anything this far off)."""
MERGE_BIAS_DEG = 0.5
"""The merge test's prior on each eye's fixed angular offset (standard deviation per axis,
degrees): an eye calibration's bias, the same in every fixation."""
MERGE_POSE_DEG = 0.2
"""... and on an offset of each fixation shared by both eyes (sd per axis, degrees) when the head
poses are tracked in the scene video (``ErrorModel.pose_offset_deg``; a device's SLAM: 0): the
head pose's error over a fixation turns both eyes' lines alike (on simulated walking sessions the
eyes' per-fixation offsets varied by 0.1-0.3 deg between fixations, vertically correlated up to
0.9 between the eyes)."""
MERGE_FIXATION_DEG = 0.1
"""... and on each eye's offset in one fixation beyond it (the calibration's error differs with
where the eye looks, which the head changes between revisits)."""
STILL_HEAD_MERGE_S = 3.0
"""Without head poses (the head taken as still, its frame as the world) a revisit joins a target
only if it begins within this many seconds of that target's last fixation. The still head is an
assumption that holds for a while, not a session: a head-worn tracker's wearer who is not on a
chin rest turns the head with most gaze shifts beyond about 20 deg and drifts between them, and 1
deg of head turn moves a point 2 m away by 35 mm in the head's frame, which the merge test (no
pose offset for such sessions) cannot tell from a revisit. A documented conservative value (no
published figure for how long a free head stays within the merge test's tolerance): a return
after one or two fixations is merged; on the second Tobii Pro Glasses 2 recording, fixations of
the Validate episode's poster 16 and 42 s apart landed on one head-frame point and were merged
into one target across the session before it."""


RELINEARIZE_GROWTH = 1.5
"""A target's ``MergeForm`` is linearised again at its current estimate, from all its lines,
when its lines have grown by this factor since the last time (so O(1) per line, amortised)."""


@dataclass
class MergeGroup:
    """One target's static fixations so far.

    Attributes:
        parts: each fixation's view lines (``BinocularSamples``, world frame), in the order they
            joined.
        members: the key the caller gave each fixation (``TargetMerger.add``), same order.
        estimate: the estimate from all their lines (``GazeEstimate``, world frame, mm).
        pooled: the estimator that gives it, kept (``estimator.api.PooledEstimate``): a fixation
            that joins is fed its own lines only.
        form: the merge test's chi2 of all their lines (``estimator.mergeform.MergeForm``).
        form_lines: the lines ``form`` was last linearised over (at the estimate of then).
    """

    parts: list
    members: list
    estimate: GazeEstimate
    pooled: PooledEstimate
    form: MergeForm
    form_lines: int

    def lines_with(self, more: BinocularSamples) -> BinocularSamples:
        """Its lines and ``more`` as one ``BinocularSamples``, in time order (stable: lines of one
        time keep the order they joined in)."""
        both = BinocularSamples.concatenate([*self.parts, more])
        return both.select(np.argsort(both.t_s, kind="stable"))


class TargetMerger:
    """The groups of static fixations merged so far, and the test that adds one more.

    Each group keeps its estimator (``PooledEstimate``) and the merge test's chi2 of its lines as
    a form of bounded size (``MergeForm``), so that testing and adding a fixation costs that
    fixation's lines, not the group's (issue 27): the estimate after a join is the one a new
    estimator over all the group's lines gives (for ``voxel``, exactly), the test's statistic the
    one ``merge_statistic`` gives over all of them, to the group's linearisation.

    Args:
        pooled: makes a group's estimator (``PooledEstimate``: the caller's estimator, method and
            error model; nothing of the application here).
        sigma_deg: the angular noise of a view line the merge test assumes, degrees.
        pose_deg: the sd per axis of the head pose's error over one fixation, degrees (an offset
            shared by both eyes' lines; ``MERGE_POSE_DEG`` for poses tracked in the scene video,
            0 for a device's own SLAM poses).
        within_s: a fixation is tested only against groups whose last fixation ended at most
            this many seconds before it begins (``STILL_HEAD_MERGE_S`` without head poses;
            default: any).
    """

    def __init__(self, pooled: Callable[[], PooledEstimate], sigma_deg: float = 1.0, pose_deg: float = 0.0,
                 within_s: float = np.inf):
        self.pooled = pooled
        self.sigma_deg = float(sigma_deg)
        self.pose_deg = float(pose_deg)
        self.within_s = float(within_s)
        self.groups: list[MergeGroup] = []
        self._points = np.zeros((0, 3))           # each group's estimate (rows beyond the groups: room to grow)

    def __len__(self) -> int:
        return len(self.groups)

    def add(self, lines: BinocularSamples, estimate: GazeEstimate, key: Hashable = None) -> int:
        """A finished static fixation: its view lines (world frame, time order) and its own
        usable estimate. Returns the id (index into ``groups``) of the group it joins or starts.

        It joins the group (seen within ``MERGE_MAX_DEG`` of its estimate from the fixation's
        first eye) whose lines fit one point with its own best (``form_statistic`` below
        ``MERGE_LR_THRESHOLD``, the least of them) and whose pooled lines give a usable estimate,
        which becomes the group's; else it starts a group. ``key`` (e.g. the fixation's index) is
        kept in the group's ``members``."""
        if not estimate.ok or estimate.position_mm is None:
            raise ValueError(f"a fixation without a usable estimate cannot be merged ({estimate.status.value})")
        origin = lines.origin_mm(0)
        scored: list[tuple] = []
        near = angle_deg(estimate.position_mm - origin, self._points[:len(self.groups)] - origin) <= MERGE_MAX_DEG
        if np.isfinite(self.within_s):
            near &= np.array([lines.t_s[0] - g.parts[-1].t_s[-1] <= self.within_s for g in self.groups], bool)
        for k in np.flatnonzero(near):                     # one array op over the groups, however many
            g = self.groups[k]
            lr = form_statistic(g.form, lines, estimate.position_mm, self.sigma_deg, self.pose_deg)
            if lr < MERGE_LR_THRESHOLD:
                scored.append((lr, len(scored), k))
        for _, _, k in sorted(scored):
            g = self.groups[k]
            merged = g.pooled.add(lines)
            if merged.ok:
                self._join(g, lines, key, merged)
                self._points[k] = merged.position_mm
                return int(k)
            g.pooled.retract()
        pooled = self.pooled()
        pooled.keep(lines)
        chart = Chart.toward(origin, estimate.position_mm)
        form = self._form(lines, chart, chart.coords(estimate.position_mm))
        self.groups.append(MergeGroup([lines], [key], estimate, pooled, form, form.n_lines))
        if len(self.groups) > len(self._points):
            self._points = np.concatenate([self._points, np.zeros((len(self._points) + 1, 3))])
        self._points[len(self.groups) - 1] = estimate.position_mm
        return len(self.groups) - 1

    def _form(self, lines: BinocularSamples, chart: Chart, p: np.ndarray) -> MergeForm:
        return fixation_form(lines, chart, p, np.deg2rad(self.sigma_deg), MERGE_FIXATION_DEG, self.pose_deg)

    def _join(self, g: MergeGroup, lines: BinocularSamples, key: Hashable, merged: GazeEstimate) -> None:
        """``lines`` join ``g``, whose estimate becomes ``merged``; its form grows by theirs, or
        is linearised anew over all its lines at the new estimate (``RELINEARIZE_GROWTH``)."""
        g.parts.append(lines)
        g.members.append(key)
        g.estimate = merged
        assert merged.position_mm is not None               # merged.ok: the caller's test
        chart = g.form.chart
        g.form = g.form.plus(self._form(lines, chart, g.form.p0))
        if g.form.n_lines >= RELINEARIZE_GROWTH * g.form_lines:
            forms = [self._form(part, chart, chart.coords(merged.position_mm)) for part in g.parts]
            g.form = functools.reduce(MergeForm.plus, forms)
            g.form_lines = g.form.n_lines


def form_statistic(form: MergeForm, lines: BinocularSamples, start_mm: ArrayLike, sigma_deg: float,
                   pose_deg: float = 0.0) -> float:
    """``merge_statistic`` of a group kept as its ``MergeForm`` and one fixation's view lines
    (world frame) whose estimate is ``start_mm`` (3,) mm: the least chi2 of one point against two,
    each found by ``GN_STEPS`` Gauss-Newton steps that linearise the fixation's lines again at the
    point of then (the group's form is a quadratic already). O(the fixation's lines)."""
    sigma = np.deg2rad(sigma_deg)

    def own(p: np.ndarray) -> MergeForm:
        return fixation_form(lines, form.chart, p, sigma, MERGE_FIXATION_DEG, pose_deg)

    xb, x = form.chart.coords(start_mm), form.p0
    for _ in range(GN_STEPS):
        apart, (_, xb) = least_chi2([form, own(xb)], MERGE_BIAS_DEG)
    for _ in range(GN_STEPS):
        together, (x,) = least_chi2([form.plus(own(x))], MERGE_BIAS_DEG)
    return together - apart


def merge_statistic(a: tuple, b: tuple, sigma_deg: float, pose_deg: float = 0.0) -> float:
    """The likelihood-ratio statistic of one point against two (3 more parameters) for two sets
    of fixations (``a``, ``b``: (a list of each fixation's view lines as ``BinocularSamples``,
    world frame; a start point (3,) mm)), on the angular noise model (``sigma_deg``) with two
    offsets of each eye's lines marginalised out (``_bias_chi2``): one shared by all the
    fixations (prior sd ``MERGE_BIAS_DEG`` per axis: an eye calibration's bias) and one of each
    fixation (``MERGE_FIXATION_DEG``: the calibration's error differs where the eye looks), and
    one of each fixation shared by both eyes (sd ``pose_deg``: the head pose's error), each chi2
    minimised from the start points.

    It uses the lines themselves, not the estimates' covariances, which cannot reject when one
    fixation fixes its point poorly (a still head at 10 Hz: a depth range of metres; merging
    then drags the good estimate toward the poor one's lines). The offsets keep the revisits of
    a target seen through a biased eye calibration from a walking head together (without them
    most revisits were new targets); the shared one cannot explain two points seen a few
    degrees apart."""
    sigma = np.deg2rad(sigma_deg)
    chunks = [(line, k, (k, j)) for k, (parts, _) in enumerate((a, b)) for j, part in enumerate(parts)
              for line in _eye_lines(part)]
    apart = _min_bias_chi2(chunks, np.concatenate([a[1], b[1]]), sigma, pose_deg)
    together = _min_bias_chi2([(line, 0, f) for line, _, f in chunks], np.asarray(a[1], float), sigma, pose_deg)
    return together - apart


def offset_chi2(samples: BinocularSamples, start_mm: ArrayLike, sigma_rad: float) -> float:
    """The least chi2 of one fixation's view lines (world frame) at one point, searched from
    ``start_mm`` (3,) mm, with each eye's calibration offsets marginalised as ``merge_statistic``
    does (``MERGE_BIAS_DEG`` and ``MERGE_FIXATION_DEG``); ``sigma_rad`` the angular noise. The
    motion test's static model: a static point seen from a moving head through a biased eye
    calibration is not a moving point. ``GN_STEPS`` Gauss-Newton steps on the fixation's
    ``MergeForm`` (within 0.1 % of a BFGS search on the lines, a tenth of its cost)."""
    chart = Chart.toward(samples.origin_mm(0), start_mm)
    p = chart.coords(start_mm)
    for _ in range(GN_STEPS):
        chi2, (p,) = least_chi2([fixation_form(samples, chart, p, sigma_rad, MERGE_FIXATION_DEG, 0.0)], MERGE_BIAS_DEG)
    return chi2


def offset_chi2_search(samples: BinocularSamples, start_mm: ArrayLike, sigma_rad: float) -> float:
    """``offset_chi2`` by a BFGS search on the lines (``_bias_chi2``): the reference for tests."""
    return _min_bias_chi2([(line, 0, (0, 0)) for line in _eye_lines(samples)], np.asarray(start_mm, float),
                          sigma_rad)


def _bias_chi2(X: np.ndarray, chunks: list[tuple], sigma: float, pose_deg: float = 0.0) -> float:
    """chi2 of line chunks, ``(eye lines, point k, fixation key)`` each, at their points ``X``
    (3K,) mm, with offsets marginalised: per eye one shared by all fixations (sd
    ``MERGE_BIAS_DEG`` per axis), per eye and fixation one (``MERGE_FIXATION_DEG``), and per
    fixation one shared by both eyes (sd ``pose_deg``: the head pose's error over a fixation,
    which turns both lines alike; ``MERGE_POSE_DEG`` for poses tracked in the scene video). Per
    axis the residuals' covariance is ``sigma^2 I + U D U^T`` (``U`` the lines' membership of
    the offsets' groups, ``D`` their variances; ``sigma`` in radians), inverted by Woodbury on
    the groups' sums."""
    P = np.asarray(X, float).reshape(-1, 3)
    s2 = sigma**2
    groups: dict = {}
    stats = []                                            # per chunk: (its groups, n, sum r (2,))
    total = 0.0
    for (e, o, d, b1, b2), k, key in chunks:
        r = gnomonic_residuals(P[k], o, d, b1, b2)[0]
        total += float(np.sum(r * r)) / s2
        member = [groups.setdefault(g, len(groups)) for g in (("eye", e), ("eye-fix", e, key), ("fix", key))]
        stats.append((member, len(r), r.sum(axis=0)))
    var = np.array([np.deg2rad({"eye": MERGE_BIAS_DEG, "eye-fix": MERGE_FIXATION_DEG, "fix": pose_deg}[g[0]])
                    ** 2 for g in groups])
    R = len(groups)
    UtU, Utr = np.zeros((R, R)), np.zeros((R, 2))
    for member, n, sm in stats:
        UtU[np.ix_(member, member)] += n
        Utr[member] += sm
    keep = var > 0
    A = s2 * np.diag(1.0 / var[keep]) + UtU[np.ix_(keep, keep)]
    b = Utr[keep]
    return total - float(np.sum(b * np.linalg.solve(A, b))) / s2


def _min_bias_chi2(chunks: list[tuple], x0: np.ndarray, sigma: float, pose_deg: float = 0.0) -> float:
    """The least ``_bias_chi2`` over the points, from ``x0`` (3K,) mm (searched in units of
    100 mm); ``sigma`` in radians."""
    x0 = np.asarray(x0, float)
    fit = minimize(lambda z: _bias_chi2(100.0 * z, chunks, sigma, pose_deg), x0 / 100.0, method="BFGS",
                   options={"gtol": 1e-4})
    return float(fit.fun)


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"RELINEARISE_GROWTH": "RELINEARIZE_GROWTH"})
