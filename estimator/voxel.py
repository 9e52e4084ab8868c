"""Voxel estimators of the gazed point: the Bayesian grid (``voxel``) and the paper's (``paper``).

Both keep a density over a box of voxels stored in an Open3D tensor (``DensityGrid``) and add
one binocular sample at a time.

``voxel`` (``VoxelEstimator``): the grid holds the log-likelihood of the angular noise model of
``estimator.likelihood``, each sample weighted by its reliability (the posterior probability that
it is no blink or saccade, from a Gaussian-plus-uniform mixture: the paper's "inaccurate gazes
spread thin", made a probability). Its maximum is the likelihood optimum; a quadratic fit of the
3x3x3 neighbourhood of the best voxel gives the sub-voxel peak and the Laplace covariance. The
grid is a box aligned with the posterior's principal axes, spanning +-``coverage_sigmas``
standard deviations. Every view line is kept, so when the peak leaves the central half of the box
or the posterior shrinks or grows by ``refine_factor``, a new box is laid and re-evaluated from all
kept lines: nothing is lost at a border, and precision is not limited by the voxel size.

``paper`` (``PaperVoxelEstimator``): Mitsugami et al. section 5 as written. An LSE seed from the
first samples; a fixed, axis-aligned cubic voxel space around it; per sample the Gaussian sphere
around ``P_n`` (the point nearest the two lines) times each eye's Gaussian cone, added (or, as an
option, multiplied) into the space; re-centring by ``d/2`` when the maximum leaves the central half
(density shifted out is dropped, as in the paper); the estimate is the best voxel's centre.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ._open3d import import_open3d
from .likelihood import MLConfig, fisher_information, ml_point, reliability_weight, reliability_weights
from .lines import BinocularSample, BinocularSamples, ViewLines
from .result import GazeEstimate, Status, failed
from .triangulation import PairStatus, closest_point_two_lines, lse_point

log = logging.getLogger(__name__)

_MAX_TAN2 = 1e6   # tan^2 of the angle for points behind an eye (about 89.94 degrees)


class DensityGrid:
    """A box of n x n x n voxels, values (float64) in an Open3D tensor with a zero-copy numpy view.

    Voxel ``(i, j, k)`` has its centre at ``center_mm + axes @ (offsets[0][i], offsets[1][j],
    offsets[2][k])``, world frame, mm.

    Attributes:
        center_mm: (3,) box centre, world frame, mm.
        axes: (3, 3) orthonormal box axes as columns, world frame (right-handed).
        spacing_mm: (3,) voxel edge lengths along the axes, mm.
        n: voxels per axis.
        values: (n, n, n) float64 numpy view of ``tensor``.
        tensor: the ``open3d.core.Tensor`` holding the values.
    """

    def __init__(self, center_mm, axes, spacing_mm, n: int):
        o3d = import_open3d()
        self.center_mm = np.asarray(center_mm, dtype=np.float64).copy()
        self.axes = np.asarray(axes, dtype=np.float64).copy()
        self.spacing_mm = np.broadcast_to(np.asarray(spacing_mm, dtype=np.float64), (3,)).copy()
        self.n = int(n)
        self.tensor = o3d.core.Tensor.zeros((self.n, self.n, self.n), o3d.core.float64)
        self.values = self.tensor.numpy()
        base = np.arange(self.n) - (self.n - 1) / 2.0
        self.offsets = [base * s for s in self.spacing_mm]

    def index_to_world(self, ijk) -> np.ndarray:
        """World points (M, 3), mm, of (possibly fractional) voxel indices (M, 3)."""
        ijk = np.atleast_2d(np.asarray(ijk, dtype=np.float64))
        local = (ijk - (self.n - 1) / 2.0) * self.spacing_mm
        return self.center_mm + local @ self.axes.T

    def centers(self) -> np.ndarray:
        """World centres (n^3, 3), mm, in the order of ``values.ravel()``."""
        ii = np.stack(np.meshgrid(*(np.arange(self.n),) * 3, indexing="ij"), -1).reshape(-1, 3)
        return self.index_to_world(ii)

    def _local_points(self):
        """Voxel centres relative to the box centre (3, n^3), world axes (voxels on the contiguous
        axis: numpy is fast only when the long axis is innermost), and their squared norms (n^3,);
        independent of ``center_mm``, so they survive translations of the box."""
        if not hasattr(self, "_PT"):
            ii = np.stack(np.meshgrid(*(np.arange(self.n),) * 3, indexing="ij"), -1).reshape(-1, 3)
            P = ((ii - (self.n - 1) / 2.0) * self.spacing_mm) @ self.axes.T
            self._PT = np.ascontiguousarray(P.T)
            self._Psq = np.einsum("ij,ij->i", P, P)
        return self._PT, self._Psq

    def tan2_of_lines(self, origins_mm, directions) -> np.ndarray:
        """tan^2 of the angle (L, n^3) between each of L lines (origins (L, 3) mm, unit directions
        (L, 3), world) and the ray from its origin to every voxel centre (rows in the order of
        ``values.ravel()``); at most ``1e6`` (89.94 deg), which is also the value behind the origin.

        With ``w = x - e = P - f`` (``f = e - center``): ``d . w = P d - f . d`` and
        ``|w|^2 = |P|^2 - 2 P f + |f|^2``, so one matrix product serves a whole batch of lines.
        """
        PT, Psq = self._local_points()
        d = np.atleast_2d(np.asarray(directions, float))
        f = np.atleast_2d(np.asarray(origins_mm, float)) - self.center_mm
        m = np.concatenate([d, f]) @ PT                        # (2L, n^3)
        L = len(d)
        a = m[:L]
        a -= (f * d).sum(1)[:, None]
        s = m[L:]
        s *= -2.0
        s += Psq
        s += (f * f).sum(1)[:, None]
        # cos^2 with the sign of d . w; clamping it bounds tan^2 and sends "behind" to the bound
        out = np.abs(a)
        out *= a
        out /= s
        np.maximum(out, 1.0 / (_MAX_TAN2 + 1.0), out=out)
        np.reciprocal(out, out=out)
        out -= 1.0
        return out

    def add_lines(self, origins_mm, directions, coefficients, chunk: int = 64) -> None:
        """``values += sum_l coefficients[l] * tan2_l`` for lines (L, 3) origins and (L, 3) unit
        directions, world frame (see ``tan2_of_lines``)."""
        o = np.atleast_2d(origins_mm)
        d = np.atleast_2d(directions)
        c = np.atleast_1d(np.asarray(coefficients, float))
        flat = self.values.reshape(-1)
        for i in range(0, len(o), chunk):
            flat += c[i:i + chunk] @ self.tan2_of_lines(o[i:i + chunk], d[i:i + chunk])

    def sq_distance_to(self, point_mm) -> np.ndarray:
        """Squared distance (n, n, n), mm^2, from every voxel centre to ``point_mm`` (3,)."""
        p = ((np.asarray(point_mm, float) - self.center_mm) @ self.axes)
        w = [(self.offsets[k] - p[k]) ** 2 for k in range(3)]
        return w[0][:, None, None] + w[1][None, :, None] + w[2][None, None, :]

    def argmax(self) -> np.ndarray:
        """(3,) int index of the largest value."""
        return np.array(np.unravel_index(int(np.argmax(self.values)), self.values.shape))

    def to_point_cloud(self, log_values: bool = True):
        """Voxel centres as an ``open3d.t.geometry.PointCloud`` (positions in mm, world frame) with
        per-point attributes ``density`` (probability mass per voxel, sums to 1 over the box) and
        ``log_density`` (relative to the maximum); ``log_values`` says whether ``values`` are logs."""
        o3d = import_open3d()
        v = self.values.ravel()
        if log_values:
            logd = v - v.max()
            p = np.exp(logd)
        else:
            p = np.clip(v, 0, None)
            with np.errstate(divide="ignore"):
                logd = np.log(p / max(p.max(), 1e-300))
            logd = np.maximum(logd, -1e30)
        p = p / max(p.sum(), 1e-300)
        pc = o3d.t.geometry.PointCloud(o3d.core.Tensor(self.centers()))
        pc.point["density"] = o3d.core.Tensor(p.astype(np.float32)[:, None])
        pc.point["log_density"] = o3d.core.Tensor(logd.astype(np.float32)[:, None])
        return pc


# 3x3x3 quadratic fit: f(delta) = c + g . delta + 1/2 delta^T H delta, delta in voxel units.
_STENCIL = np.stack(np.meshgrid(*(np.arange(-1, 2),) * 3, indexing="ij"), -1).reshape(-1, 3).astype(float)
_DESIGN = np.column_stack([
    np.ones(27), _STENCIL,
    0.5 * _STENCIL[:, 0] ** 2, 0.5 * _STENCIL[:, 1] ** 2, 0.5 * _STENCIL[:, 2] ** 2,
    _STENCIL[:, 0] * _STENCIL[:, 1], _STENCIL[:, 0] * _STENCIL[:, 2], _STENCIL[:, 1] * _STENCIL[:, 2]])
_FIT = np.linalg.pinv(_DESIGN)


def _quadratic_fit_local(grid: DensityGrid, idx):
    """3x3x3 quadratic fit around interior voxel ``idx``: ``(offset (3,), cov (3, 3))`` in the box
    frame, offset in mm from the box centre, covariance in mm^2; ``None`` if not a maximum within
    one voxel. (3x3 algebra in closed form: this runs once per streamed sample.)"""
    i, j, k = (int(x) for x in idx)
    v = grid.values[i - 1:i + 2, j - 1:j + 2, k - 1:k + 2].reshape(-1)
    _, gx, gy, gz, hxx, hyy, hzz, hxy, hxz, hyz = (_FIT @ (v - v[13])).tolist()
    # negative definite (Sylvester's criterion on -H)
    m2 = hxx * hyy - hxy * hxy
    det = hxx * (hyy * hzz - hyz * hyz) - hxy * (hxy * hzz - hyz * hxz) + hxz * (hxy * hyz - hyy * hxz)
    if not (hxx < 0 and m2 > 0 and det < 0):
        return None
    # inverse of the symmetric H by cofactors; Newton step -H^-1 g
    c00, c01, c02 = hyy * hzz - hyz * hyz, hxz * hyz - hxy * hzz, hxy * hyz - hxz * hyy
    c11, c12, c22 = hxx * hzz - hxz * hxz, hxy * hxz - hxx * hyz, m2
    dx = -(c00 * gx + c01 * gy + c02 * gz) / det
    dy = -(c01 * gx + c11 * gy + c12 * gz) / det
    dz = -(c02 * gx + c12 * gy + c22 * gz) / det
    if max(abs(dx), abs(dy), abs(dz)) > 1.0:
        return None
    s = grid.spacing_mm
    h = (grid.n - 1) / 2.0
    offset = np.array([i - h + dx, j - h + dy, k - h + dz]) * s
    cov = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) * (-1.0 / det) * np.outer(s, s)
    return offset, cov


class _SampleBuffer:
    """Growable per-sample arrays: times, both eyes' lines (world), validity, reliability weight."""

    def __init__(self, capacity: int = 256):
        self.n = 0
        self._alloc(capacity)

    def _alloc(self, cap):
        old = getattr(self, "t", None)
        new = {"t": np.zeros(cap), "o": np.zeros((cap, 2, 3)), "d": np.zeros((cap, 2, 3)),
               "valid": np.zeros((cap, 2), bool), "weight": np.ones(cap)}
        if old is not None:
            for k, arr in new.items():
                arr[:self.n] = getattr(self, k)[:self.n]
        for k, arr in new.items():
            setattr(self, k, arr)

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
        self.n += 1
        return i

    def append(self, samples: BinocularSamples):
        m = len(samples)
        if self.n + m > len(self.t):
            self._alloc(max(2 * len(self.t), self.n + m))
        sl = slice(self.n, self.n + m)
        self.t[sl] = samples.t_s
        self.o[sl, 0], self.o[sl, 1] = samples.left_origin_mm, samples.right_origin_mm
        self.d[sl, 0], self.d[sl, 1] = samples.left_direction, samples.right_direction
        self.valid[sl, 0], self.valid[sl, 1] = samples.left_valid, samples.right_valid
        self.weight[sl] = 1.0
        self.n += m
        return sl

    def lines(self, sl=slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(origins (L, 3), directions (L, 3), sample index (L,)) of the valid lines in ``sl``."""
        idx = np.arange(self.n)[sl]
        valid = self.valid[idx]
        rows, eyes = np.nonzero(valid)
        return self.o[idx][rows, eyes], self.d[idx][rows, eyes], idx[rows]

    def view_lines(self) -> ViewLines:
        o, d, si = self.lines()
        return ViewLines(o, d, "world", si)


def _as_samples(sample) -> BinocularSamples:
    if isinstance(sample, BinocularSamples):
        return sample
    if isinstance(sample, BinocularSample):
        from .lines import samples_from_stream  # noqa: PLC0415
        return samples_from_stream([sample])
    raise TypeError(f"expected a BinocularSample or BinocularSamples, got {type(sample).__name__}")


@dataclass(frozen=True)
class VoxelConfig:
    """Settings of the Bayesian voxel estimator (``voxel``).

    Attributes:
        sigma_deg: angular noise std per tangent axis, degrees.
        grid_size: voxels per box axis (n; the box has n^3 voxels).
        coverage_sigmas: the box spans +- this many posterior standard deviations per axis.
        refine_factor: re-lay the box when a posterior std along a box axis changed by this factor.
        seed_samples: binocular samples gathered before the first box is laid.
        seed_method: ``ml`` or ``lse`` (the paper's seed; biased toward the head at depth: the box
            then has to travel, which it does without losing anything).
        outlier_prob: prior probability that a sample is a blink or saccade (reliability
            weighting); 0 turns the weighting off.
        min_spacing_mm: smallest voxel edge, mm.
        max_extent_mm: largest box edge, mm (a bound on the search volume early on).
        max_relayouts: box re-layouts allowed within one update before the peak is declared
            unbounded (lines nearly parallel).
    """

    sigma_deg: float = 1.0
    grid_size: int = 12
    coverage_sigmas: float = 3.0
    refine_factor: float = 2.0
    seed_samples: int = 10
    seed_method: str = "ml"
    outlier_prob: float = 0.02
    min_spacing_mm: float = 1e-3
    max_extent_mm: float = 40000.0
    max_relayouts: int = 12

    def __post_init__(self):
        if not self.sigma_deg > 0:
            raise ValueError(f"sigma_deg must be positive, got {self.sigma_deg}")
        if self.grid_size < 5:
            raise ValueError(f"grid_size must be at least 5, got {self.grid_size}")
        if self.seed_method not in ("ml", "lse"):
            raise ValueError(f"seed_method must be 'ml' or 'lse', got {self.seed_method!r}")
        if self.seed_samples < 2:
            raise ValueError(f"seed_samples must be at least 2, got {self.seed_samples}")
        if not self.refine_factor > 1:
            raise ValueError(f"refine_factor must exceed 1, got {self.refine_factor}")
        if not 0 <= self.outlier_prob < 1:
            raise ValueError(f"outlier_prob must be in [0, 1), got {self.outlier_prob}")


class VoxelEstimator:
    """Bayesian voxel estimator (method ``voxel``); streaming with ``update``, batch with ``add``.

    Example:
        >>> est = VoxelEstimator(VoxelConfig(sigma_deg=1.0))
        >>> for s in stream:                      # BinocularSample, world frame
        ...     result = est.update(s)            # GazeEstimate after this sample
    """

    method = "voxel"

    def __init__(self, config: VoxelConfig = VoxelConfig()):
        self.config = config
        self._sigma = np.deg2rad(config.sigma_deg)
        self._buf = _SampleBuffer()
        self.grid: DensityGrid | None = None
        self._design_std = None
        self._last: GazeEstimate | None = None
        self.relayouts = 0

    def __len__(self) -> int:
        return self._buf.n

    def update(self, sample: BinocularSample) -> GazeEstimate:
        """Add one binocular sample (world frame) and return the current estimate."""
        i = self._buf.append_one(sample)
        if self.grid is not None:
            self._set_weights(slice(i, i + 1))
            self._accumulate(slice(i, i + 1))
        self._last = self._settle()
        return self._last

    def add(self, samples: BinocularSamples) -> GazeEstimate:
        """Add many samples at once (the batch API) and return the estimate after all of them."""
        if samples.frame != "world":
            raise ValueError(f"samples must be in the world frame, got {samples.frame!r}")
        sl = self._buf.append(samples)
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

    def view_lines(self) -> ViewLines:
        """All kept lines (world frame), with their sample indices."""
        return self._buf.view_lines()

    @property
    def weights(self) -> np.ndarray:
        """(N,) reliability weight of each kept sample."""
        return self._buf.weight[:self._buf.n].copy()

    def log_density_at(self, pts_mm) -> np.ndarray:
        """The weighted log-likelihood (M,) at world points (M, 3), evaluated from the kept lines."""
        pts = np.atleast_2d(np.asarray(pts_mm, float))
        o, d, si = self._buf.lines()
        w = self._buf.weight[si]
        out = np.zeros(len(pts))
        for start in range(0, len(pts), 4096):
            p = pts[start:start + 4096]
            v = p[:, None, :] - o[None]
            a = np.einsum("mlk,lk->ml", v, d)
            s = np.einsum("mlk,mlk->ml", v, v)
            tan2 = np.where(a > 0, s / np.maximum(a * a, 1e-300) - 1.0, _MAX_TAN2)
            out[start:start + 4096] = -0.5 * (np.minimum(tan2, _MAX_TAN2) @ w) / self._sigma**2
        return out

    # --- internals ----------------------------------------------------------------------------

    def _n_lines(self) -> int:
        return int(self._buf.valid[:self._buf.n].sum())

    def _fail(self, status, reason) -> GazeEstimate:
        return failed(self.method, status, reason, self._buf.n, self._n_lines())

    def _seed(self, x0=None):
        cfg = self.config
        lines = self._buf.view_lines()
        if x0 is not None or cfg.seed_method == "ml":
            # the same model as the grid's: Gaussian inliers, and blinks or saccades as a mixture
            loss = "mixture" if cfg.outlier_prob > 0 else "gaussian"
            est = ml_point(lines, MLConfig(sigma_deg=cfg.sigma_deg, loss=loss,
                                           outlier_prob=max(cfg.outlier_prob, 1e-9)), x0_mm=x0)
        else:
            est = lse_point(lines)
        if not est.ok:
            return None, est.reason
        F = fisher_information(est.position_mm, lines.origins_mm, self._sigma)
        if np.linalg.cond(F) > 1e14:
            return None, "the view lines do not yet fix a point"
        return (est.position_mm, np.linalg.inv(F)), ""

    def _layout(self, center, cov):
        """Lay a new box for posterior N(center, cov) and re-evaluate every kept sample into it."""
        cfg = self.config
        w, V = np.linalg.eigh(0.5 * (cov + cov.T))
        if np.linalg.det(V) < 0:
            V[:, 0] = -V[:, 0]
        std = np.sqrt(np.clip(w, 0, None))
        std = np.clip(std, cfg.min_spacing_mm * cfg.grid_size / (2 * cfg.coverage_sigmas),
                      cfg.max_extent_mm / (2 * cfg.coverage_sigmas))
        spacing = 2 * cfg.coverage_sigmas * std / cfg.grid_size
        self.grid = DensityGrid(center, V, spacing, cfg.grid_size)
        self._design_std = std
        self.relayouts += 1
        self._set_weights(slice(0, self._buf.n), center, cov)
        self._accumulate(slice(0, self._buf.n))

    def _set_weights(self, sl, center=None, cov=None):
        """Reliability weight of samples ``sl`` given the current posterior (center, cov)."""
        if self.config.outlier_prob <= 0:
            return
        if center is None:
            if self._last is None or self._last.position_mm is None:
                return
            center, cov = self._last.position_mm, self._last.covariance_mm2
        if isinstance(sl, slice) and sl.stop - sl.start == 1:
            self._set_weight_one(sl.start, center, cov)
            return
        o, d, si = self._buf.lines(sl)
        if len(si) == 0:
            return
        v = center - o
        s2 = np.einsum("ij,ij->i", v, v)
        a = np.maximum(np.einsum("ij,ij->i", v, d), 1e-6 * np.sqrt(s2))
        tan2 = np.minimum(s2 / (a * a) - 1.0, _MAX_TAN2)
        # predictive variance of each tangent residual: sigma^2 + the posterior's mean spread
        # across the line, over the squared distance
        lateral = 0.5 * (np.trace(cov) - np.einsum("ij,jk,ik->i", d, cov, d))
        chi2_line = tan2 / (self._sigma**2 + np.maximum(lateral, 0) / (a * a))
        first = si.min()
        local = si - first
        m = int(local.max()) + 1
        chi2_s = np.bincount(local, weights=chi2_line, minlength=m)
        dof = 2.0 * np.bincount(local, minlength=m)
        wts = reliability_weights(chi2_s, np.maximum(dof, 1), self._sigma, self.config.outlier_prob)
        self._buf.weight[first:first + m] = np.where(dof > 0, wts, 1.0)

    def _set_weight_one(self, i, center, cov):
        """``_set_weights`` for one sample, in scalar arithmetic (the streaming hot path)."""
        valid = self._buf.valid[i]
        if not (valid[0] or valid[1]):
            return
        cx, cy, cz = center.tolist()
        C = cov.tolist()
        tr = C[0][0] + C[1][1] + C[2][2]
        sig2 = self._sigma**2
        chi2 = 0.0
        dof = 0.0
        for eye in (0, 1):
            if not valid[eye]:
                continue
            ox, oy, oz = self._buf.o[i, eye].tolist()
            dx, dy, dz = self._buf.d[i, eye].tolist()
            vx, vy, vz = cx - ox, cy - oy, cz - oz
            s2 = vx * vx + vy * vy + vz * vz
            a = max(vx * dx + vy * dy + vz * dz, 1e-6 * math.sqrt(s2))
            tan2 = min(s2 / (a * a) - 1.0, _MAX_TAN2)
            dCd = (dx * (C[0][0] * dx + C[0][1] * dy + C[0][2] * dz) + dy * (C[1][0] * dx + C[1][1] * dy + C[1][2] * dz)
                   + dz * (C[2][0] * dx + C[2][1] * dy + C[2][2] * dz))
            lateral = max(0.5 * (tr - dCd), 0.0)
            chi2 += tan2 / (sig2 + lateral / (a * a))
            dof += 2.0
        self._buf.weight[i] = reliability_weight(chi2, dof, self._sigma, self.config.outlier_prob)

    def _accumulate(self, sl):
        o, d, si = self._buf.lines(sl)
        self.grid.add_lines(o, d, self._buf.weight[si] * (-0.5 / self._sigma**2))

    def _settle(self) -> GazeEstimate:
        cfg = self.config
        if self.grid is None:
            if self._buf.n < cfg.seed_samples:
                return self._fail(Status.INSUFFICIENT,
                                  f"gathering samples for the seed: {self._buf.n} of {cfg.seed_samples}")
            seed, reason = self._seed()
            if seed is None:
                return self._fail(Status.INSUFFICIENT, f"no seed yet: {reason}")
            self._layout(*seed)
        grid = self.grid
        for _ in range(cfg.max_relayouts):
            grid = self.grid
            idx = grid.argmax()
            fit = None
            if idx.min() > 0 and idx.max() < grid.n - 1:
                fit = _quadratic_fit_local(grid, idx)
            if fit is None:
                # the maximum is at the border, or not a peak at this voxel size: lay the box
                # anew from the continuous optimum over every kept line (nothing is lost)
                seed, reason = self._seed(x0=grid.index_to_world(idx)[0])
                if seed is None:
                    return self._fail(Status.INSUFFICIENT, f"the density has no clear peak yet: {reason}")
                self._layout(*seed)
                continue
            offset, cov_local = fit
            point = grid.center_mm + grid.axes @ offset
            cov = grid.axes @ cov_local @ grid.axes.T
            if self._needs_layout(offset, cov_local):
                self._layout(point, cov)
                continue
            return self._result(point, cov)
        return self._fail(Status.DEGENERATE, "the density has no bounded maximum: the view lines are "
                                             "nearly parallel (target too far for this head motion)")

    def _needs_layout(self, offset_mm, cov_local) -> bool:
        """Lay a new box when the peak (box frame, mm) left the central half, or the posterior
        std along a box axis changed by more than ``refine_factor``."""
        g = self.grid
        if np.max(np.abs(offset_mm / g.spacing_mm)) > g.n / 4:
            return True
        floor = self.config.min_spacing_mm * g.n / (2 * self.config.coverage_sigmas)
        ratio = np.maximum(np.sqrt(np.maximum(np.diag(cov_local), 0.0)), floor) / self._design_std
        return bool(ratio.max() > self.config.refine_factor or ratio.min() < 1 / self.config.refine_factor)

    def _result(self, point, cov) -> GazeEstimate:
        g = self.grid
        info = {"voxel_mm": g.spacing_mm.tolist(), "relayouts": self.relayouts}
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


@dataclass(frozen=True)
class PaperVoxelConfig:
    """Settings of the paper's stochastic voxel method (``paper``); the paper leaves all open.

    Attributes:
        sigma_deg: cone width: angular std of each view line, degrees.
        voxel_mm: voxel edge, mm (the paper's estimates come in 10 mm steps).
        grid_size: voxels per axis of the cubic voxel space.
        seed_samples: binocular samples whose lines seed the LSE (the paper: "several").
        sphere_sigma_mm: std of the Gaussian sphere around ``P_n``, mm; ``None`` takes each
            pair's own triangulation depth uncertainty, ``sqrt(2) r^2 sigma / b`` (``r`` the
            distance of ``P_n``, ``b`` the eyes' separation), at least one voxel. The sphere is
            unnormalised (peak 1): normalising it would weight near pairs by ``r^-6``.
        update: ``add`` (densities summed: the paper's "integration") or ``multiply``
            (log-densities summed; a floor keeps one stray sample from zeroing a voxel).
    """

    sigma_deg: float = 1.0
    voxel_mm: float = 10.0
    grid_size: int = 32
    seed_samples: int = 20
    sphere_sigma_mm: float | None = None
    update: str = "add"

    def __post_init__(self):
        if not self.sigma_deg > 0 or not self.voxel_mm > 0:
            raise ValueError("sigma_deg and voxel_mm must be positive")
        if self.update not in ("add", "multiply"):
            raise ValueError(f"update must be 'add' or 'multiply', got {self.update!r}")
        if self.grid_size < 4 or self.seed_samples < 1:
            raise ValueError("grid_size must be at least 4 and seed_samples at least 1")


class PaperVoxelEstimator:
    """The paper's stochastic voxel method (method ``paper``), streaming with ``update``."""

    method = "paper"

    def __init__(self, config: PaperVoxelConfig = PaperVoxelConfig()):
        self.config = config
        self._sigma = np.deg2rad(config.sigma_deg)
        self._pending: list[BinocularSamples] = []
        self.grid: DensityGrid | None = None
        self.n_samples = 0
        self.n_lines = 0
        self.shifts = 0
        self._last: GazeEstimate | None = None

    def update(self, sample: BinocularSample) -> GazeEstimate:
        """Add one binocular sample (world frame) and return the current estimate."""
        return self.add(_as_samples(sample))

    def add(self, samples: BinocularSamples) -> GazeEstimate:
        """Add samples one after another (the method is sequential) and return the last estimate."""
        cfg = self.config
        for i in range(len(samples)):
            s = samples.select(slice(i, i + 1))
            self.n_samples += 1
            self.n_lines += int(s.left_valid[0]) + int(s.right_valid[0])
            if self.grid is None:
                self._pending.append(s)
                if len(self._pending) < cfg.seed_samples:
                    continue
                if not self._seed():
                    continue
            else:
                self._update_one(s)
            self._recentre()
        self._last = self._result()
        return self._last

    def estimate(self) -> GazeEstimate:
        return self._last if self._last is not None else failed(self.method, Status.INSUFFICIENT,
                                                                "no samples yet", 0, 0)

    def _seed(self) -> bool:
        pend = self._pending
        allv = BinocularSamples.concatenate(pend)
        seed = lse_point(allv.lines())
        if not seed.ok:
            return False
        c = self.config
        # snap the space so that voxel centres sit on multiples of voxel_mm, as the paper's
        # estimates do (1010, 2010, ...)
        half = 0.5 * c.voxel_mm if c.grid_size % 2 == 0 else 0.0
        center = np.round((seed.position_mm - half) / c.voxel_mm) * c.voxel_mm + half
        self.grid = DensityGrid(center, np.eye(3), c.voxel_mm, c.grid_size)
        for p in pend:
            self._update_one(p)
            self._recentre()
        self._pending = []
        return True

    def _update_one(self, s: BinocularSamples):
        c, g = self.config, self.grid
        if not (s.left_valid[0] and s.right_valid[0]):
            return                                   # the method needs both lines for P_n
        pair = closest_point_two_lines(s.left_origin_mm, s.left_direction, s.right_origin_mm, s.right_direction)
        if pair.status[0] == PairStatus.PARALLEL:   # no P_n
            return
        P = pair.point_mm[0]
        if c.sphere_sigma_mm is None:
            mid = 0.5 * (s.left_origin_mm[0] + s.right_origin_mm[0])
            base = max(np.linalg.norm(s.left_origin_mm[0] - s.right_origin_mm[0]), 1.0)
            r = np.linalg.norm(P - mid)
            sig_s = max(np.sqrt(2.0) * r * r * self._sigma / base, c.voxel_mm)
        else:
            sig_s = c.sphere_sigma_mm
        sphere = np.exp(-0.5 * g.sq_distance_to(P) / sig_s**2)
        cones = np.exp((-0.5 / self._sigma**2) * g.tan2_of_lines(
            np.vstack([s.left_origin_mm, s.right_origin_mm]), np.vstack([s.left_direction, s.right_direction])))
        contribution = sphere * (cones[0] + cones[1]).reshape(sphere.shape)
        if c.update == "add":
            g.values += contribution
        else:
            g.values += np.log(contribution + 1e-12 * contribution.max() + 1e-300)

    def _recentre(self):
        g = self.grid
        idx = g.argmax()
        d = (idx - (g.n - 1) / 2.0)                       # voxels from the centre to P_M
        if np.all(np.abs(d) <= g.n / 4):
            return
        shift = np.round(d / 2).astype(int)               # translate the space by d/2
        self.shifts += 1
        fill = 0.0 if self.config.update == "add" else float(g.values.min())
        new = np.full_like(g.values, fill)
        src = [slice(max(s, 0), g.n + min(s, 0)) for s in shift]
        dst = [slice(max(-s, 0), g.n + min(-s, 0)) for s in shift]
        new[tuple(dst)] = g.values[tuple(src)]
        g.values[:] = new
        g.center_mm = g.center_mm + shift * g.spacing_mm

    def _result(self) -> GazeEstimate:
        if self.grid is None:
            return failed(self.method, Status.INSUFFICIENT,
                          f"gathering samples for the LSE seed: {len(self._pending)} of {self.config.seed_samples}",
                          self.n_samples, self.n_lines)
        g = self.grid
        if not np.any(g.values != g.values.flat[0]):
            return failed(self.method, Status.INSUFFICIENT, "no density yet", self.n_samples, self.n_lines)
        point = g.index_to_world(g.argmax())[0]
        info = {"voxel_mm": self.config.voxel_mm, "shifts": self.shifts, "center_mm": g.center_mm.tolist()}
        return GazeEstimate(self.method, Status.OK, point, None, self.n_samples, self.n_lines, "", info)
