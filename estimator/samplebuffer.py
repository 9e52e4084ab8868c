"""The voxel estimator's kept samples: growable per-sample arrays of both eyes' world lines, with
the running line count, the line statistics that the seed test reads in O(1) and the sum of the
samples' reliability weights; and the count of the work done over them (``VoxelWork``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lines import BinocularSample, BinocularSamples, ViewLines


@dataclass
class VoxelWork:
    """Work a ``VoxelEstimator`` did over all its kept lines (the part of the cost that grows with
    the stream); the rest of an update is O(1).

    Attributes:
        seed_fits: ML (or LSE) fits over every kept line.
        layouts: boxes laid, each re-evaluating every kept line.
        lines_refit: kept lines processed by those fits and layouts, summed.
        deferred: fits or layouts put off because the work bound was reached.
        postponed: in streaming, heavy steps (a seed fit, a part of a box's layout, an error-model
            refit) put off to a later update because this one had done its ``update_steps``.
    """

    seed_fits: int = 0
    layouts: int = 0
    lines_refit: int = 0
    deferred: int = 0
    postponed: int = 0


class _SampleBuffer:
    """Growable per-sample arrays: times, both eyes' lines (world), validity, reliability weight."""

    # set by _alloc, rows [:n] in use
    t: np.ndarray        # (cap,) s
    o: np.ndarray        # (cap, 2, 3) mm, world: each eye's origin
    d: np.ndarray        # (cap, 2, 3) unit directions, world
    valid: np.ndarray    # (cap, 2) bool
    weight: np.ndarray   # (cap,) reliability weights

    def __init__(self, capacity: int = 256):
        self.n = 0
        self.n_lines = 0
        self.weight_sum = 0.0   # the sum of weight[:n], kept in step by append and set_weights
        # running sums over the valid lines (origin o, unit direction d, P = I - d d^T): the
        # least-squares point solves sum_P x = sum_Po; sum_d . x - sum_do is the summed distance
        # of x ahead of the eyes along the lines
        self.sum_P = np.zeros((3, 3))
        self.sum_Po = np.zeros(3)
        self.sum_d = np.zeros(3)
        self.sum_do = 0.0
        self._alloc(capacity)

    def _alloc(self, cap: int) -> None:
        old = getattr(self, "t", None)
        new = {"t": np.zeros(cap), "o": np.zeros((cap, 2, 3)), "d": np.zeros((cap, 2, 3)),
               "valid": np.zeros((cap, 2), bool), "weight": np.ones(cap)}
        if old is not None:
            for k, arr in new.items():
                arr[:self.n] = getattr(self, k)[:self.n]
        for k, arr in new.items():
            setattr(self, k, arr)

    def _add_sums(self, o: np.ndarray, d: np.ndarray) -> None:
        """Add lines (L, 3) origins, (L, 3) unit directions to the running sums."""
        P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        self.sum_P += P.sum(axis=0)
        self.sum_Po += np.einsum("nij,nj->i", P, o)
        self.sum_d += d.sum(axis=0)
        self.sum_do += float(np.einsum("ij,ij->", d, o))
        self.n_lines += len(d)

    def append_one(self, sample: BinocularSample) -> int:
        """Append one streaming sample (validated here: the hot path skips ``BinocularSamples``)."""
        if self.n + 1 > len(self.t):
            self._alloc(2 * len(self.t))
        i = self.n
        self.t[i] = float(sample.t_s)
        for eye, (o, d) in enumerate(((sample.left_origin_mm, sample.left_direction),
                                      (sample.right_origin_mm, sample.right_direction))):
            if o is None or d is None:
                self.valid[i, eye] = False
                self.o[i, eye] = np.nan
                self.d[i, eye] = np.nan
                continue
            o = np.asarray(o, dtype=np.float64)
            d = np.asarray(d, dtype=np.float64)
            if o.shape != (3,) or d.shape != (3,):
                raise ValueError(f"sample origins and directions must have shape (3,), got {o.shape} and {d.shape}")
            nd = float(np.sqrt(d @ d))
            if not (np.isfinite(nd) and nd > 1e-12 and np.all(np.isfinite(o))):
                raise ValueError(f"sample at t={sample.t_s} has a zero or non-finite {('left', 'right')[eye]} line")
            self.o[i, eye] = o
            self.d[i, eye] = d / nd
            self.valid[i, eye] = True
        self.weight[i] = 1.0
        self.weight_sum += 1.0
        self.n += 1
        v = self.valid[i]
        if v.any():
            self._add_sums(self.o[i][v], self.d[i][v])
        return i

    def append(self, samples: BinocularSamples) -> slice:
        m = len(samples)
        if self.n + m > len(self.t):
            self._alloc(max(2 * len(self.t), self.n + m))
        sl = slice(self.n, self.n + m)
        self.t[sl] = samples.t_s
        self.o[sl, 0], self.o[sl, 1] = samples.left_origin_mm, samples.right_origin_mm
        self.d[sl, 0], self.d[sl, 1] = samples.left_direction, samples.right_direction
        self.valid[sl, 0], self.valid[sl, 1] = samples.left_valid, samples.right_valid
        self.weight[sl] = 1.0
        self.weight_sum += m
        self.n += m
        v = self.valid[sl]
        self._add_sums(self.o[sl][v], self.d[sl][v])
        return sl

    def set_weights(self, start: int, values: np.ndarray) -> None:
        """Set the reliability weights of samples ``start ...`` to ``values`` (M,), keeping
        ``weight_sum`` in step (O(M))."""
        stop = start + len(values)
        self.weight_sum += float(np.sum(values) - self.weight[start:stop].sum())
        self.weight[start:stop] = values

    def set_weight(self, i: int, value: float) -> None:
        """``set_weights`` for one sample, in scalar arithmetic (the streaming hot path)."""
        self.weight_sum += value - float(self.weight[i])
        self.weight[i] = value

    def lines(self, sl: slice | np.ndarray = slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(origins (L, 3), directions (L, 3), sample index (L,)) of the valid lines in ``sl`` (a
        slice, or sample indices (M,) in increasing order)."""
        if isinstance(sl, slice):
            idx = np.arange(*sl.indices(self.n))    # O(len(sl)), not O(n): the streaming path
        else:
            idx = np.asarray(sl, dtype=np.intp)
        valid = self.valid[idx]
        rows, eyes = np.nonzero(valid)
        return self.o[idx][rows, eyes], self.d[idx][rows, eyes], idx[rows]

    def view_lines(self) -> ViewLines:
        o, d, si = self.lines()
        return ViewLines(o, d, "world", si)


def spread_samples(n: int, most: int, runs: int = 16) -> slice | np.ndarray:
    """Indices of at most ``most`` of ``n`` samples standing for all of them: ``slice(0, n)`` when
    ``n <= most``, else (M,) increasing indices of ``runs`` runs of consecutive samples spread
    evenly over the ``n`` (consecutive, so that a fit over them still sees the residuals'
    correlation from one sample to the next; spread, so that it sees the head's whole motion)."""
    if n <= most:
        return slice(0, n)
    length = max(most // runs, 1)
    starts = np.linspace(0, n - length, runs).astype(np.intp)
    return np.unique((starts[:, None] + np.arange(length)[None, :]).ravel())


def _as_samples(sample: BinocularSample | BinocularSamples) -> BinocularSamples:
    if isinstance(sample, BinocularSamples):
        return sample
    if isinstance(sample, BinocularSample):
        from .lines import samples_from_stream
        return samples_from_stream([sample])
    raise TypeError(f"expected a BinocularSample or BinocularSamples, got {type(sample).__name__}")
