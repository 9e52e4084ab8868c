"""One entry point per use: ``estimate`` over a batch, ``make_estimator`` for a stream.

Methods:
    ``lse``        the paper's LSE (eq. 12 stacked); biased toward the head at depth.
    ``geometric``  least squares on perpendicular distances.
    ``ml``         maximum likelihood on angular residuals, with covariance (at the Cramér-Rao bound).
    ``voxel``      the Bayesian voxel estimator (default): likelihood on an adaptive grid.
    ``paper``      the paper's stochastic voxel method, as written.
"""

from __future__ import annotations

import logging

import numpy as np

from .direction import with_direction
from .likelihood import MLConfig, ml_point
from .lines import BinocularSample, BinocularSamples, samples_from_stream
from .paper_voxel import PaperVoxelConfig, PaperVoxelEstimator
from .result import GazeEstimate, Status, failed, near_point_check
from .triangulation import lse_point, nearest_point_to_lines
from .voxel import VoxelConfig, VoxelEstimator

log = logging.getLogger(__name__)

METHODS = ("lse", "geometric", "ml", "voxel", "paper")
DEFAULT_METHOD = "voxel"


class LinesEstimator:
    """Streaming wrapper for the closed-form and ML methods: keeps the samples and re-solves over
    all of them on each update (O(N) per update; for ML warm-started from the last point)."""

    def __init__(self, method: str, sigma_deg: float = 1.0, ml_config: MLConfig | None = None):
        if method not in ("lse", "geometric", "ml"):
            raise ValueError(f"LinesEstimator handles lse, geometric and ml, not {method!r}")
        self.method = method
        self.ml_config = ml_config or MLConfig(sigma_deg=sigma_deg)
        self._samples: list[BinocularSample] = []
        self._batches: list[BinocularSamples] = []
        self._last: GazeEstimate | None = None

    def update(self, sample: BinocularSample) -> GazeEstimate:
        self._samples.append(sample)
        return self._solve()

    def add(self, samples: BinocularSamples) -> GazeEstimate:
        self._flush()
        self._batches.append(samples)
        return self._solve()

    def estimate(self) -> GazeEstimate:
        return self._last or failed(self.method, Status.INSUFFICIENT, "no samples yet", 0, 0)

    def _flush(self):
        if self._samples:
            self._batches.append(samples_from_stream(self._samples))
            self._samples = []

    def _solve(self) -> GazeEstimate:
        self._flush()
        if len(self._batches) > 1:
            self._batches = [BinocularSamples.concatenate(self._batches)]
        lines = self._batches[0].lines()
        if self.method == "lse":
            self._last = lse_point(lines)
        elif self.method == "geometric":
            self._last = nearest_point_to_lines(lines)
        else:
            x0 = self._last.position_mm if self._last is not None and self._last.ok else None
            self._last = ml_point(lines, self.ml_config, x0_mm=x0)
        return self._last


def make_estimator(method: str = DEFAULT_METHOD, sigma_deg: float = 1.0, **options):
    """A streaming estimator: ``est.update(BinocularSample) -> GazeEstimate``, ``est.add(batch)``.

    Args:
        method: one of ``METHODS``.
        sigma_deg: angular noise std per tangent axis, degrees.
        **options: fields of ``VoxelConfig`` (voxel), ``PaperVoxelConfig`` (paper) or ``MLConfig`` (ml).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: choose one of {', '.join(METHODS)}")
    if method == "voxel":
        return VoxelEstimator(VoxelConfig(sigma_deg=sigma_deg, **options))
    if method == "paper":
        return PaperVoxelEstimator(PaperVoxelConfig(sigma_deg=sigma_deg, **options))
    if method == "ml":
        return LinesEstimator("ml", ml_config=MLConfig(sigma_deg=sigma_deg, **options))
    if options:
        raise ValueError(f"method {method!r} takes no options, got {sorted(options)}")
    return LinesEstimator(method)


def batch_options(method: str, n_samples: int, **options) -> dict:
    """``options`` for an estimator that will be fed a known batch of ``n_samples``: the paper's
    method seeds after ``PaperVoxelConfig.seed_samples`` (20) samples, more than a short fixation
    at a low eye rate has (Aria: 5 samples in 0.5 s at 10 Hz), so it seeds from the whole batch
    then (at least 2 samples). Other methods answer from 2 lines already."""
    if method == "paper" and "seed_samples" not in options and n_samples < PaperVoxelConfig.seed_samples:
        options = {**options, "seed_samples": max(2, int(n_samples))}
    return options


def run_estimator(samples: BinocularSamples, method: str = DEFAULT_METHOD, sigma_deg: float = 1.0,
                  **options):
    """Feed a batch of binocular samples (world frame) to a new estimator; return
    ``(estimator, GazeEstimate)`` so that its density can be exported.

    ``voxel`` and ``paper`` take the samples in time order, as they would stream: the seed comes
    from the first samples, as in a live session. A result without a point ahead of the eyes is
    answered by its direction (``estimator.direction.with_direction``, the cone's bias from
    ``options["error_model"]`` when given).
    """
    if samples.frame != "world":
        raise ValueError(f"samples must be in the world frame, got {samples.frame!r}")
    est = make_estimator(method, sigma_deg, **batch_options(method, len(samples), **options))
    if method == "voxel":
        seed = est.config.seed_samples
        result = est.add(samples.select(slice(0, seed)))
        for i in range(seed, len(samples)):
            result = est.update(samples.sample(i))
    else:
        result = est.add(samples)
    if result.ok:
        lines = samples.lines()
        result = near_point_check(result, lines.origins_mm, lines.directions)
    result = with_direction(result, samples, options.get("error_model"))
    if result.ok and result.position_mm is not None:
        outcome = f"{result.position_mm.round(1).tolist()} mm"
    else:
        outcome = f"{result.status.value}: {result.reason}"
    log.info("%s: %d samples, %d lines: %s", method, result.n_samples, result.n_lines, outcome)
    return est, result


NEAR_CHECK_SAMPLES = 4096
"""``PooledEstimate`` checks an answer's distance from the eyes (``near_point_check``: the median
along the lines) over at most this many samples, evenly spread over all it kept."""


class PooledEstimate:
    """``run_estimator`` over lines that arrive in batches in time order (a target's fixations,
    one after another), each answer that of one estimator fed all the lines so far.

    For ``voxel`` the estimator is kept, and a batch is fed to it alone, at the cost of its own
    lines (the voxel estimator's work over its kept lines is bounded, amortised, per line added):
    ``batched`` (default) adds each batch at once, as ``running_estimate`` feeds a fixation's
    chunks (the answer is the weighted likelihood's peak over all the lines, as
    ``run_estimator``'s; the samples' reliability weights are set per batch instead of per
    sample: on simulated sessions within 0.001 sd of the full re-run); else sample by sample as
    ``run_estimator`` feeds them, which gives its answer exactly. The other methods are run again
    over all the lines (``ml`` and the closed forms solve over every line anyway; ``paper`` seeds
    from a count that depends on the batch's size). A batch older than the last line, or an
    answer that is not usable (``retract`` then undoes it), makes the next answer a re-run over
    all the lines, in time order.

    Args:
        method, sigma_deg, **options: as ``run_estimator``'s.
        batched: see above (``voxel`` only).
    """

    def __init__(self, method: str = DEFAULT_METHOD, sigma_deg: float = 1.0, batched: bool = True, **options):
        self.method, self.sigma_deg, self.batched, self.options = method, float(sigma_deg), batched, options
        self.parts: list[BinocularSamples] = []
        self._stream = None                    # the kept voxel estimator, None: re-run at the next add
        self.reruns = 0                        # answers made by a re-run over all the lines (for tests)

    def __len__(self) -> int:
        """The samples kept."""
        return sum(len(p) for p in self.parts)

    def add(self, samples: BinocularSamples) -> GazeEstimate:
        """The estimate of all lines so far and ``samples`` (world frame, time order)."""
        if samples.frame != "world":
            raise ValueError(f"samples must be in the world frame, got {samples.frame!r}")
        in_order = not self.parts or not len(samples) or samples.t_s[0] >= self.parts[-1].t_s[-1]
        self.parts.append(samples)
        est = self._stream
        if est is None or not in_order or len(est) < est.config.seed_samples:
            return self._rerun()
        return _near_checked(self._feed(est, samples), est)

    def keep(self, samples: BinocularSamples) -> None:
        """Keep ``samples`` (world frame, time order) without an answer: the next ``add`` is a
        re-run over them and its own (a target's first fixation, which has its own estimate)."""
        self.parts.append(samples)
        self._stream = None

    def retract(self) -> None:
        """Undo the last ``add`` (its lines are forgotten; the next answer is a re-run)."""
        self.parts.pop()
        self._stream = None

    def _feed(self, est, samples: BinocularSamples) -> GazeEstimate:
        """``samples`` fed to the kept voxel estimator ``est`` (see ``batched``)."""
        if self.batched:
            return est.add(samples)
        result = est.estimate()
        for i in range(len(samples)):
            result = est.update(samples.sample(i))
        return result

    def _rerun(self) -> GazeEstimate:
        pooled = BinocularSamples.concatenate(self.parts)
        order = np.argsort(pooled.t_s, kind="stable")
        in_order = bool(np.all(order == np.arange(len(order))))
        self.reruns += 1
        if self.method != "voxel" or not self.batched:
            self.parts = [pooled.select(order)]
            est, result = run_estimator(self.parts[0], self.method, self.sigma_deg, **self.options)
            self._stream = est if self.method == "voxel" else None
            return result
        stream = self._stream = make_estimator("voxel", self.sigma_deg, **self.options)
        if not in_order:
            self.parts = [pooled.select(order)]
        for part in self.parts:
            result = self._feed(stream, part)
        return _near_checked(result, stream)


def _near_checked(result: GazeEstimate, stream: VoxelEstimator) -> GazeEstimate:
    """``near_point_check`` as ``run_estimator`` ends, over ``stream``'s kept lines of at most
    ``NEAR_CHECK_SAMPLES`` samples evenly spread (a median: bounded cost per answer)."""
    if not result.ok:
        return result
    lines = stream.view_lines(every=max(1, -(-len(stream) // NEAR_CHECK_SAMPLES)))
    return near_point_check(result, lines.origins_mm, lines.directions)


def estimate(samples: BinocularSamples, method: str = DEFAULT_METHOD, sigma_deg: float = 1.0,
             **options) -> GazeEstimate:
    """Estimate the gazed point from a batch of binocular samples (world frame); see
    ``run_estimator``. Lines that fix no point ahead of the eyes (parallel or diverging rays, one
    line per sample from a still head) give ``Status.DIRECTION_ONLY``: no point, the direction
    with its 95 % cone and depth interval (``estimator.direction``), when there are at least
    ``MIN_DIRECTION_SAMPLES`` samples."""
    return run_estimator(samples, method, sigma_deg, **options)[1]


def density_point_cloud(estimator):
    """The density of a ``voxel`` or ``paper`` estimator as an Open3D point cloud (voxel centres,
    world frame, mm) with per-point ``density`` (probability mass) and ``log_density``."""
    grid = getattr(estimator, "grid", None)
    if grid is None:
        raise ValueError("this estimator has no density grid yet (too few samples, or not voxel/paper)")
    log_values = isinstance(estimator, VoxelEstimator) or estimator.config.update == "multiply"
    return grid.to_point_cloud(log_values=log_values)
