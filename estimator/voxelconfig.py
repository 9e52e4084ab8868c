"""The voxel estimator's settings (``VoxelConfig``; the estimator: ``estimator.voxel``)."""

from __future__ import annotations

from dataclasses import dataclass

from .errormodel import ErrorModel


@dataclass(frozen=True)
class VoxelConfig:
    """Settings of the Bayesian voxel estimator (``voxel``).

    Attributes:
        sigma_deg: angular noise std per tangent axis, degrees.
        grid_size: voxels per box axis (n; the box has n^3 voxels).
        coverage_sigmas: the box spans +- this many posterior standard deviations per axis.
        refine_factor: re-lay the box when a posterior std along a box axis changed by this factor.
        seed_samples: fewest binocular samples before a seed is tried (default 1: the seed waits for
            the lines to fix a point ahead of the eyes, with a well-conditioned ML fit, not for a count).
        seed_method: ``ml`` or ``lse`` (the paper's seed; biased toward the head at depth: the box
            then has to travel, which it does without losing anything).
        outlier_prob: prior probability that a sample is a blink or saccade (reliability
            weighting); 0 turns the weighting off.
        min_spacing_mm: smallest voxel edge, mm.
        max_extent_mm: largest box edge, mm (a bound on the search volume early on).
        max_relayouts: box re-layouts allowed within one ``add`` or ``update`` before the peak
            is declared unbounded (lines nearly parallel). Counted over the updates a box takes,
            it ended a far target's stream on the paper path (1.5, 0.5, 5 m) as unbounded in
            some trials of benchmarks/accuracy_vs_crb.py: a peak that moves as lines come is
            re-laid many times over a stream.
        work_per_line: the bound on work over all kept lines (seed fits, box layouts): each line
            added allows this many line re-evaluations; over any stream they total at most
            ``work_initial + work_per_line * lines added``. A fit or layout beyond the allowance is
            deferred until enough samples have come in (``VoxelEstimator.work``).
        work_initial: line re-evaluations allowed before any line is added.
        work_burst: the allowance saved up is at most this many times the kept lines (and at
            least ``work_initial``), so one update makes at most about this many passes over them.
        error_model: the reported covariance's error model (``estimator.errormodel``); None reports
            the grid's Laplace covariance (the angular noise ``sigma_deg`` alone). The model is
            evaluated over all kept lines when their number has grown by ``model_growth`` since
            the last time (so O(1) per line, amortised); in between, its noise part shrinks as
            1/lines and its bias floor stays. The grid, the seed and the reliability weights keep
            the plain likelihood of ``sigma_deg``.
        model_growth: see ``error_model``.
        fit_samples: the seed fits after the first box and the error model are evaluated over at
            most this many kept samples (``samplebuffer.spread_samples``: runs of consecutive
            samples spread over the stream), the model's noise part scaled to all of them: the
            cost of one update stays bounded however long a fixation lasts.
        update_fit_samples: in streaming (``update``), the same bound (at most ``fit_samples``), so
            that one such fit costs a millisecond or two.
        layout_chunk_lines: in streaming, the kept lines one update may re-evaluate: a new box
            over more is laid over several updates, this many lines each (the old box answers
            meanwhile; the batch ``add`` lays every box at once), and a seed fit (counting twice
            its lines) or an error-model refit waits for a later update when this one's work so
            far leaves too few (the last box and model answer meanwhile; an update's first such
            work always runs, and so does the model's first fit): no update holds a stream up
            for more than about one such piece of work.
        relay_lines: a box whose density has no peak inside it has no answer to give while
            another is laid, so with at most this many kept lines it is laid anew within the
            update (a paper-path stream of 400 lines once ended mid-layout, without an answer,
            in benchmarks/accuracy_vs_crb.py); with more, over several updates as above.
    """

    sigma_deg: float = 1.0
    grid_size: int = 12
    coverage_sigmas: float = 3.0
    refine_factor: float = 2.0
    seed_samples: int = 1
    seed_method: str = "ml"
    outlier_prob: float = 0.02
    min_spacing_mm: float = 1e-3
    max_extent_mm: float = 40000.0
    max_relayouts: int = 12
    work_per_line: float = 16.0
    work_initial: float = 0.0
    work_burst: float = 4.0
    error_model: ErrorModel | None = None
    model_growth: float = 1.1
    fit_samples: int = 2048
    update_fit_samples: int = 256
    layout_chunk_lines: int = 128
    relay_lines: int = 1024

    def __post_init__(self) -> None:
        if not self.sigma_deg > 0:
            raise ValueError(f"sigma_deg must be positive, got {self.sigma_deg}")
        if self.grid_size < 5:
            raise ValueError(f"grid_size must be at least 5, got {self.grid_size}")
        if self.seed_method not in ("ml", "lse"):
            raise ValueError(f"seed_method must be 'ml' or 'lse', got {self.seed_method!r}")
        if self.seed_samples < 1:
            raise ValueError(f"seed_samples must be at least 1, got {self.seed_samples}")
        if not (self.work_per_line >= 4 and self.work_initial >= 0 and self.work_burst >= 2):
            raise ValueError(f"work_per_line must be at least 4, work_initial non-negative and work_burst at least 2, "
                             f"got {self.work_per_line}, {self.work_initial} and {self.work_burst}")
        if not self.refine_factor > 1:
            raise ValueError(f"refine_factor must exceed 1, got {self.refine_factor}")
        if not 0 <= self.outlier_prob < 1:
            raise ValueError(f"outlier_prob must be in [0, 1), got {self.outlier_prob}")
        if self.error_model is not None and not isinstance(self.error_model, ErrorModel):
            raise ValueError(f"error_model must be an ErrorModel or None, got {type(self.error_model).__name__}")
        if not self.model_growth > 1:
            raise ValueError(f"model_growth must exceed 1, got {self.model_growth}")
        if min(self.fit_samples, self.update_fit_samples) < 64 or self.layout_chunk_lines < 2:
            raise ValueError(f"fit_samples and update_fit_samples must be at least 64 and layout_chunk_lines at least "
                             f"2, got {self.fit_samples}, {self.update_fit_samples} and {self.layout_chunk_lines}")
