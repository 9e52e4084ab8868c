"""The Bayesian voxel estimator of the gazed point (method ``voxel``).

The grid (``estimator.grid.DensityGrid``) holds the log-likelihood of the angular noise model of
``estimator.likelihood``, each sample weighted by its reliability (the posterior probability that
it is no blink or saccade, from a Gaussian-plus-uniform mixture: the paper's "inaccurate gazes
spread thin", made a probability). Its maximum is the likelihood optimum; a quadratic fit of the
3x3x3 neighbourhood of the best voxel gives the sub-voxel peak and the Laplace covariance. The
grid is a box aligned with the posterior's principal axes, spanning +-``coverage_sigmas``
standard deviations. Every view line is kept, so when the peak leaves the central half of the box
or the posterior shrinks or grows by ``refine_factor``, a new box is laid and re-evaluated from all
kept lines: nothing is lost at a border, and precision is not limited by the voxel size.

The seed comes from what the lines determine, not from a count: the first box is laid as soon as
the lines' least-squares point (from running sums, O(1) per sample) lies ahead of the eyes and the
robust ML fit there is well conditioned. The work over all kept lines (seed fits, box layouts) is
bounded: over any stream it totals at most ``work_initial + work_per_line`` x the lines added, so
lines that never fix a point (a still head, diverging eyes) cost O(1) per sample, amortised.

The paper's method (``paper``) is in ``estimator.paper_voxel``.
"""

from __future__ import annotations

import logging

import numpy as np

from .errormodel import model_covariance
from .errormodel_regions import far_side, sight_info
from .grid import DensityGrid, _PendingBox, _quadratic_fit_local
from .likelihood import MLConfig, angular_log_likelihood, fisher_information, ml_point
from .lines import BinocularSample, BinocularSamples, ViewLines
from .reliability import REJECTED_SHARE, reliability_weight_at, reliability_weights_at
from .result import GazeEstimate, Status, failed
from .samplebuffer import VoxelWork, _SampleBuffer, spread_samples
from .triangulation import lse_point
from .voxelconfig import VoxelConfig

log = logging.getLogger(__name__)

_LAYING = "a new box is being laid over the kept lines"

__all__ = ["VoxelConfig", "VoxelEstimator", "VoxelWork"]


class VoxelEstimator:
    """Bayesian voxel estimator (method ``voxel``); streaming with ``update``, batch with ``add``.

    Example:
        >>> est = VoxelEstimator(VoxelConfig(sigma_deg=1.0))
        >>> for s in stream:                      # BinocularSample, world frame
        ...     result = est.update(s)            # GazeEstimate after this sample
    """

    method = "voxel"

    @property
    def relayouts(self) -> int:
        """Boxes laid so far (the same count as ``work.layouts``)."""
        return self.work.layouts

    def __init__(self, config: VoxelConfig | None = None):
        config = VoxelConfig() if config is None else config
        self.config = config
        self._sigma = np.deg2rad(config.sigma_deg)
        self._buf = _SampleBuffer()
        self.grid: DensityGrid | None = None
        self._design_std: np.ndarray | None = None
        self._last: GazeEstimate | None = None
        self.work = VoxelWork()
        self._allowance = float(config.work_initial)   # line re-evaluations still allowed
        # (point, Laplace covariance) of the last peak: the weights' posterior
        self._posterior: tuple[np.ndarray, np.ndarray] | None = None
        # the error model: (lines then, noise covariance then, bias floor, info, their mean origin)
        self._model: tuple[int, np.ndarray, np.ndarray, dict, np.ndarray] | None = None
        self._pending: _PendingBox | None = None   # a box being laid over several updates (streaming)
        self._seed_failure = ""                    # why the last seed fit failed (its reason, for people)
        self._budget: int | None = None            # lines this streaming update may still re-evaluate (None: batch)
        self._chain = 0                            # boxes laid in this update (``max_relayouts``)

    def __len__(self) -> int:
        return self._buf.n

    def update(self, sample: BinocularSample) -> GazeEstimate:
        """Add one binocular sample (world frame) and return the current estimate."""
        self._budget = self.config.layout_chunk_lines
        i = self._buf.append_one(sample)
        self._allow(int(self._buf.valid[i].sum()))
        if self.grid is not None:
            self._set_weights(slice(i, i + 1))
            self._accumulate(slice(i, i + 1))
        self._last = self._settle()
        return self._last

    def add(self, samples: BinocularSamples) -> GazeEstimate:
        """Add many samples at once (the batch API) and return the estimate after all of them."""
        if samples.frame != "world":
            raise ValueError(f"samples must be in the world frame, got {samples.frame!r}")
        self._budget = None
        sl = self._buf.append(samples)
        self._allow(int(self._buf.valid[sl].sum()))
        if self.grid is not None:
            self._set_weights(sl)
            self._accumulate(sl)
        self._last = self._settle()
        return self._last

    def estimate(self) -> GazeEstimate:
        """The estimate after the samples added so far."""
        if self._last is None:
            return failed(self.method, Status.INSUFFICIENT, "no samples yet", 0, 0)
        return self._last

    def view_lines(self, every: int = 1) -> ViewLines:
        """All kept lines (world frame), with their sample indices; with ``every`` > 1, the lines
        of every ``every``-th sample only."""
        if every == 1:
            return self._buf.view_lines()
        o, d, si = self._buf.lines(slice(0, self._buf.n, every))
        return ViewLines(o, d, "world", si)

    @property
    def weights(self) -> np.ndarray:
        """(N,) reliability weight of each kept sample."""
        return self._buf.weight[:self._buf.n].copy()

    def log_density_at(self, pts_mm) -> np.ndarray:
        """The weighted log-likelihood (M,) at world points (M, 3), evaluated from the kept lines."""
        o, d, si = self._buf.lines()
        return angular_log_likelihood(pts_mm, o, d, self._sigma, weights=self._buf.weight[si])

    # --- internals ----------------------------------------------------------------------------

    def _n_lines(self) -> int:
        return self._buf.n_lines

    def _allow(self, new_lines: int) -> None:
        """Grow the allowance for ``new_lines`` lines added, up to its cap."""
        cfg = self.config
        cap = max(cfg.work_initial, cfg.work_burst * self._buf.n_lines)
        self._allowance = min(self._allowance + cfg.work_per_line * new_lines, cap)

    def _fits_budget(self, n_lines: int) -> bool:
        """Whether this streaming update may still re-evaluate ``n_lines`` kept lines (a seed fit
        counts twice its lines): its first such work always, more within its
        ``layout_chunk_lines`` (the batch ``add``: always). Work that may not is postponed to a
        later update (counted), the last box and error model answering meanwhile."""
        b = self._budget
        if b is None or b >= self.config.layout_chunk_lines or n_lines <= b:
            return True
        self.work.postponed += 1
        return False

    def _spend(self, n_lines: int) -> None:
        if self._budget is not None:
            self._budget -= n_lines

    def _fit_samples(self) -> int:
        """The most kept samples a seed fit or the error model sees (streaming: fewer)."""
        cfg = self.config
        return cfg.fit_samples if self._budget is None else min(cfg.fit_samples, cfg.update_fit_samples)

    def _fit_lines(self) -> int:
        """About the lines a seed fit or the error model sees."""
        return min(self._buf.n_lines, 2 * self._fit_samples())

    def _afford(self, n_lines: int) -> bool:
        """Take ``n_lines`` line re-evaluations from the allowance, or say the work must wait."""
        if n_lines > self._allowance:
            self.work.deferred += 1
            log.debug("voxel: a fit over %d lines deferred (work bound)", n_lines)
            return False
        self._allowance -= n_lines
        self.work.lines_refit += n_lines
        return True

    def _seed_gate(self) -> str:
        """Whether the kept lines determine a point worth a seed fit, in O(1) from the buffer's
        running sums: '' if so, else why not. The lines' least-squares point must exist (not all
        lines parallel) and lie ahead of the eyes on average (diverging lines meet behind them)."""
        b = self._buf
        if b.n_lines < 2:
            return f"{b.n_lines} view line so far"
        ev = np.linalg.eigvalsh(b.sum_P)
        if ev[0] <= 1e-9 * max(ev[-1], 1e-300):
            return "the view lines are (nearly) parallel"
        x = np.linalg.solve(b.sum_P, b.sum_Po)
        if float(b.sum_d @ x) - b.sum_do <= 0:
            return "the lines meet behind the eyes: the view directions diverge"
        return ""

    def _fail(self, status, reason) -> GazeEstimate:
        self._posterior = None
        return failed(self.method, status, reason, self._buf.n, self._n_lines())

    def _seed(self, x0=None) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
        cfg = self.config
        # at most ``fit_samples`` of the kept samples, the information scaled to all of them: a
        # seed, not the answer (the box's peak is, over every kept line)
        o, d, si = self._buf.lines(spread_samples(self._buf.n, self._fit_samples()))
        lines = ViewLines(o, d, "world", si)
        self.work.seed_fits += 1
        if x0 is not None or cfg.seed_method == "ml":
            # the same model as the grid's: Gaussian inliers, and blinks or saccades as a mixture
            loss = "mixture" if cfg.outlier_prob > 0 else "gaussian"
            # a seed, not the answer: the grid's peak is the optimum, so a loose stop will do
            est = ml_point(lines, MLConfig(sigma_deg=cfg.sigma_deg, loss=loss, outlier_prob=max(cfg.outlier_prob, 1e-9),
                                           max_iterations=30, tolerance_mm=1e-3), x0_mm=x0)
        else:
            est = lse_point(lines)
        if not est.ok or est.position_mm is None:     # (ok: never None)
            return None, est.reason
        F = fisher_information(est.position_mm, lines.origins_mm, self._sigma) * (self._buf.n_lines / max(len(si), 1))
        if np.linalg.cond(F) > 1e14:
            return None, "the view lines do not yet fix a point"
        return (est.position_mm, np.linalg.inv(F)), ""

    def _layout(self, center, cov) -> bool:
        """Lay a new box for posterior N(center, cov) and re-evaluate every kept sample into it:
        at once (True), or in streaming, with more kept lines than the update's budget
        (``_fits_budget``), over this and the next updates (False: ``_pending``, until
        ``_advance`` has filled it)."""
        cfg = self.config
        w, V = np.linalg.eigh(0.5 * (cov + cov.T))
        if np.linalg.det(V) < 0:
            V[:, 0] = -V[:, 0]
        std = np.sqrt(np.clip(w, 0, None))
        std = np.clip(std, cfg.min_spacing_mm * cfg.grid_size / (2 * cfg.coverage_sigmas),
                      cfg.max_extent_mm / (2 * cfg.coverage_sigmas))
        spacing = 2 * cfg.coverage_sigmas * std / cfg.grid_size
        log.debug("voxel: box %d laid at %s mm, voxel %s mm, over %d kept lines", self.work.layouts + 1,
                  np.round(center, 1).tolist(), np.round(spacing, 2).tolist(), self._buf.n_lines)
        self.work.layouts += 1
        self._chain += 1
        self._pending = _PendingBox(DensityGrid(center, V, spacing, cfg.grid_size), std, center, cov)
        return self._advance()

    def _advance(self) -> bool:
        """Evaluate the next kept samples into the pending box, under its posterior's weights: all
        of them (batch), or about as many lines as this streaming update's budget has left; once
        every kept sample is in, it replaces the box (True). Samples added meanwhile are in the
        old box and come to the new one in turn."""
        p = self._pending
        assert p is not None                          # called while a box is being laid
        stop = self._buf.n
        if self._budget is not None:
            most = min(self._budget, self.config.layout_chunk_lines)
            if most < 2:
                self.work.postponed += 1
                return False
            stop = min(stop, p.done + most // 2)
        sl = slice(p.done, stop)
        self._spend(int(self._buf.valid[sl].sum()))
        self._set_weights(sl, p.center, p.cov)
        self._accumulate(sl, p.grid)
        p.done = stop
        if stop < self._buf.n:
            return False
        self.grid, self._design_std, self._pending = p.grid, p.std, None
        return True

    def _set_weights(self, sl, center=None, cov=None):
        """Reliability weight of samples ``sl`` given the current posterior (center, cov)."""
        if self.config.outlier_prob <= 0:
            return
        if center is None:
            if self._posterior is None:
                return
            center, cov = self._posterior
        b = self._buf
        if isinstance(sl, slice) and sl.stop - sl.start == 1:
            i = sl.start
            b.set_weight(i, reliability_weight_at(center, cov, b.o[i], b.d[i], b.valid[i], self._sigma,
                                                  self.config.outlier_prob))
            return
        o, d, si = b.lines(sl)
        if len(si) == 0:
            return
        first = int(si.min())
        m = int(si.max()) - first + 1
        b.set_weights(first, reliability_weights_at(center, cov, o, d, si - first, m, self._sigma,
                                                    self.config.outlier_prob))

    def _accumulate(self, sl, grid=None):
        o, d, si = self._buf.lines(sl)
        target = self.grid if grid is None else grid
        assert target is not None                     # a box laid or being laid
        target.add_lines(o, d, self._buf.weight[si] * (-0.5 / self._sigma**2))

    def _settle(self) -> GazeEstimate:
        """The estimate after the samples added: seed and lay boxes as needed (in streaming, a box
        over many lines is laid over several updates, ``_layout``)."""
        cfg = self.config
        n_lines = self._buf.n_lines
        self._chain = 0                               # ``max_relayouts`` bounds the boxes laid in one update
        if self._pending is not None:
            self._advance()
        if self._posterior_rejected():
            # the box answers from a few early lines only (e.g. one eye's first lines, which meet
            # near that eye): drop it and seed again from every kept line, nothing is lost
            log.debug("voxel: the posterior rejects most of the %d kept samples; seeding again", self._buf.n)
            self.grid = None
            self._posterior = None
        if self.grid is None:
            failed = self._seed_box(n_lines)
            if failed is not None:
                return failed
        while self._chain < cfg.max_relayouts:
            grid = self.grid
            assert grid is not None                   # seeded above, or re-laid before ``continue``
            idx = grid.argmax()
            fit = None
            if idx.min() > 0 and idx.max() < grid.n - 1:
                fit = _quadratic_fit_local(grid, idx)
            if fit is None:
                failed = self._relay_without_peak(grid, idx, n_lines)
                if failed is not None:
                    return failed
                continue
            offset, cov_local = fit
            point = grid.center_mm + grid.axes @ offset
            cov = grid.axes @ cov_local @ grid.axes.T
            # a peak inside the box with a valid fit is an answer even when the box would be
            # re-laid (refined or re-centred) but the work bound defers it, or it is being laid
            if (self._pending is None and self._needs_layout(offset, cov_local)
                    and self._afford(n_lines)):
                if self._layout(point, cov):
                    continue
            return self._result(point, cov)
        self.grid = self._pending = None      # back to the O(1) seed test (nothing is lost: see above)
        log.debug("voxel: no bounded maximum after %d re-layouts; back to seeding", cfg.max_relayouts)
        return self._fail(Status.DEGENERATE, "the density has no bounded maximum: the view lines are "
                                             "nearly parallel (target too far for this head motion)")

    def _seed_box(self, n_lines: int) -> GazeEstimate | None:
        """Without a box: seed one and lay it when the samples allow (``_seed_gate``, the work
        bound over the ``n_lines`` kept lines); the failure to return, or None once it is laid."""
        cfg = self.config
        if self._pending is not None:
            return self._fail(Status.INSUFFICIENT, f"no estimate yet: {_LAYING}")
        if self._buf.n < cfg.seed_samples:
            gathering = f"gathering samples for the seed: {self._buf.n} of {cfg.seed_samples}"
            return self._fail(Status.INSUFFICIENT, gathering)
        why = self._seed_gate()
        if why:
            return self._fail(Status.INSUFFICIENT, f"no seed yet: {why}")
        if not self._fits_budget(2 * self._fit_lines()):
            return self._fail(Status.INSUFFICIENT, "no seed yet: the fit waits for the next update "
                                                   "(bounded work per update)")
        if not self._afford(2 * n_lines):
            return self._fail(Status.INSUFFICIENT, f"no seed yet: {self._seed_failure or 'the last fits failed'}; "
                                                   "the next fit waits for more samples (bounded work per sample)")
        self._spend(2 * self._fit_lines())
        seed, reason = self._seed()
        if seed is None:
            self._seed_failure = reason
            return self._fail(Status.INSUFFICIENT, f"no seed yet: {reason}")
        laid = self._layout(*seed)
        self._chain = 0                               # boxes laid from this seed on count
        if not laid:
            return self._fail(Status.INSUFFICIENT, f"no estimate yet: {_LAYING}")
        return None

    def _relay_without_peak(self, grid, idx, n_lines: int) -> GazeEstimate | None:
        """The box's maximum (voxel ``idx``) is at its border, or not a peak at this voxel size:
        lay the box anew from the continuous optimum over every kept line (nothing is lost);
        the failure to return, or None when the new box is laid."""
        # without a peak the box has no answer to give while another is laid over the next
        # updates (a stream could end there), so over few lines this update does the whole work
        budget = self._budget
        if n_lines <= self.config.relay_lines:
            self._budget = None
        try:
            return self._relay_now(grid, idx, n_lines)
        finally:
            self._budget = budget

    def _relay_now(self, grid, idx, n_lines: int) -> GazeEstimate | None:
        """``_relay_without_peak``'s work, under the update's budget if it has one."""
        no_peak_here = f"the density has no clear peak in this box; {_LAYING}"
        if self._pending is not None:             # the box being laid: looked at once finished
            return None if self._advance() else self._fail(Status.INSUFFICIENT, no_peak_here)
        if not self._fits_budget(2 * self._fit_lines()):               # in the next updates
            return self._fail(Status.INSUFFICIENT, no_peak_here)
        if not self._afford(2 * n_lines):
            return self._fail(Status.INSUFFICIENT, "the density has no clear peak yet; the box is "
                                                   "laid anew once more samples have come in "
                                                   "(bounded work per sample)")
        self._spend(2 * self._fit_lines())
        seed, reason = self._seed(x0=grid.index_to_world(idx)[0])
        if seed is None:
            # back to seeding: the O(1) test waits for lines that fix a point, and the next
            # box is evaluated from every kept line, so dropping this one loses nothing
            self.grid = None
            return self._fail(Status.INSUFFICIENT, f"the density has no clear peak yet: {reason}")
        if not self._layout(*seed):
            return self._fail(Status.INSUFFICIENT, no_peak_here)
        return None

    def _posterior_rejected(self) -> bool:
        """Whether the box's posterior weighs the kept samples at less than ``REJECTED_SHARE`` of
        their number (then it is wrong, not they) and a new seed and box are affordable; O(1)."""
        b = self._buf
        return (self.grid is not None and self._pending is None and self.config.outlier_prob > 0
                and b.weight_sum < REJECTED_SHARE * b.n and self._allowance >= 3 * b.n_lines
                and self._fits_budget(2 * self._fit_lines()))

    def _needs_layout(self, offset_mm, cov_local) -> bool:
        """Lay a new box when the peak (box frame, mm) left the central half, or the posterior
        std along a box axis changed by more than ``refine_factor``."""
        g = self.grid
        assert g is not None and self._design_std is not None    # asked of a laid box's peak
        if np.max(np.abs(offset_mm / g.spacing_mm)) > g.n / 4:
            return True
        floor = self.config.min_spacing_mm * g.n / (2 * self.config.coverage_sigmas)
        ratio = np.maximum(np.sqrt(np.maximum(np.diag(cov_local), 0.0)), floor) / self._design_std
        return bool(ratio.max() > self.config.refine_factor or ratio.min() < 1 / self.config.refine_factor)

    def _reported_covariance(self, point, cov, info: dict):
        """The covariance to report for the peak ``point`` with Laplace covariance ``cov``: the
        error model's (see ``VoxelConfig.error_model``), else ``cov``."""
        model = self.config.error_model
        if model is None:
            return cov
        L = self._buf.n_lines
        if self._model is None or (L >= self.config.model_growth * self._model[0]
                                   and self._fits_budget(self._fit_lines())):
            self._spend(self._fit_lines())
            # over at most ``fit_samples`` kept samples (O(1) per update): the noise part shrinks
            # as 1 / the lines' summed weight, the bias floor does not depend on their number
            b = self._buf
            o, d, si = b.lines(spread_samples(b.n, self._fit_samples()))
            C, minfo = model_covariance(point, ViewLines(o, d, "world", si), self._sigma, model, b.weight[si])
            if C is None:
                return cov
            bias, linear = minfo.pop("bias_cov"), minfo.pop("linear_cov")
            share = float(b.weight[si].sum() / (b.weight[:b.n] @ b.valid[:b.n].sum(axis=1)))
            self._model = (L, (linear - bias) * share, bias, minfo, o.mean(axis=0))
        n0, noise, bias, minfo, origin = self._model
        C_lin = noise * (n0 / L) + bias
        C, f = far_side(C_lin, point, origin, model.far_side_k)
        info["error_model"] = {**minfo, "far_side_factor": round(f, 3),
                               **sight_info(C_lin, point, origin, model.far_side_k)}
        return C

    def _result(self, point, cov) -> GazeEstimate:
        g = self.grid
        assert g is not None                          # a peak of a laid box
        info = {"voxel_mm": g.spacing_mm.tolist(), "relayouts": self.work.layouts, "seed_fits": self.work.seed_fits}
        self._posterior = (point, cov)
        cov = self._reported_covariance(point, cov, info)
        # behind the eyes? check against the latest sample's lines (O(1) per update)
        i = self._buf.n - 1
        valid = self._buf.valid[i]
        ahead = ((point - self._buf.o[i][valid]) * self._buf.d[i][valid]).sum(1)
        if len(ahead) and ahead.max() <= 0:
            return GazeEstimate(self.method, Status.BEHIND, point, cov, self._buf.n, self._n_lines(),
                                "the lines meet behind the eyes: the view directions diverge", info)
        return GazeEstimate(self.method, Status.OK, point, cov, self._buf.n, self._n_lines(), "", info)

    def credible_volume_mm3(self, probability: float = 0.95) -> float:
        """Volume, mm^3, of the smallest set of voxels holding ``probability`` of the grid's mass
        (meaningful once the posterior spans several voxels, which the box layout ensures)."""
        if self.grid is None:
            raise ValueError("no density yet: add samples first")
        v = self.grid.values.ravel()
        p = np.sort(np.exp(v - v.max()))[::-1]
        n = int(np.searchsorted(np.cumsum(p) / p.sum(), probability) + 1)
        return float(n * np.prod(self.grid.spacing_mm))
