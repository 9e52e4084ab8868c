"""The voxel estimator's streaming update does bounded work however long a fixation lasts
(issue 29): a new box over many kept lines is laid over several updates, and the re-seeds and
the error model see at most ``fit_samples`` samples; the estimate stays the offline one."""

import numpy as np

import estimator.voxel as voxel
from estimator.errormodel import ErrorModel
from estimator.samplebuffer import spread_samples
from estimator.voxel import VoxelConfig, VoxelEstimator
from tests.helpers import walkabout_samples

CHUNK, FIT = 64, 128            # small bounds, so that a short stream exceeds them many times over
CFG = VoxelConfig(error_model=ErrorModel(), layout_chunk_lines=CHUNK, fit_samples=FIT)
TARGET = np.array([120.0, -60.0, 1100.0])


def _counting(monkeypatch):
    """Lines handed to the grid, to the seed fits and to the error model, per call."""
    seen = {"grid": [], "fit": [], "model": []}
    add_lines, ml_point, model_cov = voxel.DensityGrid.add_lines, voxel.ml_point, voxel.model_covariance

    def grid(self, o, *a, **k):
        seen["grid"].append(len(np.atleast_2d(o)))
        return add_lines(self, o, *a, **k)

    def fit(lines, *a, **k):
        seen["fit"].append(len(lines))
        return ml_point(lines, *a, **k)

    def model(point, lines, *a, **k):
        seen["model"].append(len(lines))
        return model_cov(point, lines, *a, **k)

    monkeypatch.setattr(voxel.DensityGrid, "add_lines", grid)
    monkeypatch.setattr(voxel, "ml_point", fit)
    monkeypatch.setattr(voxel, "model_covariance", model)
    return seen


def _offline(samples, config=CFG):
    """The estimate of ``process`` (``pipeline.steps.estimate.running_estimate``): the samples added in
    20 batches, each box laid at once."""
    est = VoxelEstimator(config)
    for part in np.array_split(np.arange(len(samples)), 20):
        e = est.add(samples.select(part))
    return e


def test_each_streaming_update_evaluates_a_bounded_number_of_kept_lines(monkeypatch):
    samples = walkabout_samples(TARGET, np.random.default_rng(4), n=1200)
    seen = _counting(monkeypatch)
    est = VoxelEstimator(CFG)
    most = {"grid": 0, "fit": 0, "model": 0}
    for i in range(len(samples)):
        e = est.update(samples.sample(i))
        for k, v in seen.items():
            most[k] = max(most[k], sum(v))
            v.clear()
    assert e.ok and len(est.view_lines()) == 2 * len(samples)
    assert est.work.layouts >= 3                      # boxes laid long after the first lines
    assert most["grid"] <= CHUNK + 2                 # one chunk of the new box, and the new sample
    assert most["fit"] <= 2 * FIT and most["model"] <= 2 * FIT


def test_the_streaming_estimate_is_the_offline_one_within_a_tenth_of_its_sd():
    samples = walkabout_samples(TARGET, np.random.default_rng(5), n=1200)
    est = VoxelEstimator(CFG)
    for i in range(len(samples)):
        e = est.update(samples.sample(i))
    off = _offline(samples)
    assert e.ok and off.ok
    d = e.position_mm - off.position_mm
    assert np.sqrt(d @ np.linalg.solve(off.covariance_mm2, d)) < 0.1
    sd, sd_off = np.sqrt(np.diag(e.covariance_mm2)), np.sqrt(np.diag(off.covariance_mm2))
    assert np.all(np.abs(sd / sd_off - 1) < 0.1)


def test_the_error_model_over_spread_runs_of_samples_is_the_one_over_all():
    """The model over ``fit_samples`` samples, its noise part scaled to all the lines, gives the
    sd of the model over every line within 10 %."""
    samples = walkabout_samples(TARGET, np.random.default_rng(6), n=1200)
    few = _offline(samples, VoxelConfig(error_model=ErrorModel(), fit_samples=FIT))
    full = _offline(samples, VoxelConfig(error_model=ErrorModel(), fit_samples=len(samples)))
    assert np.allclose(few.position_mm, full.position_mm)
    sd, sd_full = np.sqrt(np.diag(few.covariance_mm2)), np.sqrt(np.diag(full.covariance_mm2))
    assert np.all(np.abs(sd / sd_full - 1) < 0.1)


def test_spread_samples_are_runs_of_consecutive_samples_over_the_whole_stream():
    assert spread_samples(100, 128) == slice(0, 100)
    idx = spread_samples(10000, 128, runs=16)
    assert len(idx) == 128 and idx[0] == 0 and idx[-1] == 9999
    assert np.all(np.diff(idx) > 0) and np.sum(np.diff(idx) == 1) == 128 - 16


def test_no_streaming_update_stacks_work_over_the_kept_lines(monkeypatch):
    """With the default settings (issue 29: bursts in the live loop), once the kept lines exceed
    one update's budget (``layout_chunk_lines``) an update does at most one piece of work over
    them: a seed fit, a part of a box's layout (at most the budget's lines), or an error-model
    refit (over at most ``update_fit_samples`` samples); the rest waits for the next updates."""
    cfg = VoxelConfig(error_model=ErrorModel())
    # about a millisecond of CPU a piece: a line into a box costs ~8.5 us (12^3 voxels), a fit or
    # model over 256 samples 1.3-2.7 ms (before: boxes over 1,024 lines, fits over 2,048 samples)
    assert cfg.layout_chunk_lines <= 128 and cfg.update_fit_samples <= 256
    samples = walkabout_samples(TARGET, np.random.default_rng(7), n=1500)
    seen = _counting(monkeypatch)
    est = VoxelEstimator(cfg)
    stacked = pieces = 0
    for i in range(len(samples)):
        e = est.update(samples.sample(i))
        layout = [n for n in seen["grid"] if n > 2]              # the new sample's own lines aside
        assert sum(layout) <= cfg.layout_chunk_lines
        assert all(n <= 2 * cfg.update_fit_samples for n in seen["fit"] + seen["model"])
        work = len(seen["fit"]) + len(seen["model"]) + bool(layout)
        if len(est.view_lines()) > cfg.layout_chunk_lines:
            stacked += work > 1
            pieces += work
        for v in seen.values():
            v.clear()
    assert e.ok and est.work.layouts >= 3 and pieces > 20     # boxes laid and models refitted late too
    assert stacked == 0
    assert est.work.postponed > 0                             # some work did wait for a later update


def test_the_default_streaming_estimate_is_the_offline_one():
    """The streamed estimate with the default settings (boxes laid over several updates, the
    error model over ``update_fit_samples``) against the batch one (every box at once, the model
    over ``fit_samples``): within a tenth of its sd, the sds within 10 %."""
    cfg = VoxelConfig(error_model=ErrorModel())
    samples = walkabout_samples(TARGET, np.random.default_rng(8), n=1500)
    est = VoxelEstimator(cfg)
    for i in range(len(samples)):
        e = est.update(samples.sample(i))
    off = _offline(samples, cfg)
    assert e.ok and off.ok
    d = e.position_mm - off.position_mm
    assert np.sqrt(d @ np.linalg.solve(off.covariance_mm2, d)) < 0.1
    sd, sd_off = np.sqrt(np.diag(e.covariance_mm2)), np.sqrt(np.diag(off.covariance_mm2))
    assert np.all(np.abs(sd / sd_off - 1) < 0.1)
