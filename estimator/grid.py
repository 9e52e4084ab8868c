"""The density grid shared by the voxel estimators: a box of voxels in an Open3D tensor, the
closed-form angle of every voxel to a batch of view lines, the sub-voxel quadratic peak fit,
and a box being laid over several streaming updates (``_PendingBox``).

World frame, mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ._open3d import import_open3d
from .likelihood import tan2_from_local


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

    def __init__(self, center_mm: ArrayLike, axes: ArrayLike, spacing_mm: float, n: int) -> None:
        o3d = import_open3d()
        self.center_mm = np.asarray(center_mm, dtype=np.float64).copy()
        self.axes = np.asarray(axes, dtype=np.float64).copy()
        self.spacing_mm = np.broadcast_to(np.asarray(spacing_mm, dtype=np.float64), (3,)).copy()
        self.n = int(n)
        self.tensor = o3d.core.Tensor.zeros((self.n, self.n, self.n), o3d.core.float64)
        self.values = self.tensor.numpy()
        base = np.arange(self.n) - (self.n - 1) / 2.0
        self.offsets = [base * s for s in self.spacing_mm]

    def index_to_world(self, ijk: ArrayLike) -> np.ndarray:
        """World points (M, 3), mm, of (possibly fractional) voxel indices (M, 3)."""
        ijk = np.atleast_2d(np.asarray(ijk, dtype=np.float64))
        local = (ijk - (self.n - 1) / 2.0) * self.spacing_mm
        return self.center_mm + local @ self.axes.T

    def centers(self) -> np.ndarray:
        """World centres (n^3, 3), mm, in the order of ``values.ravel()``."""
        ii = np.stack(np.meshgrid(*(np.arange(self.n),) * 3, indexing="ij"), -1).reshape(-1, 3)
        return self.index_to_world(ii)

    def _local_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Voxel centres relative to the box centre (3, n^3), world axes (voxels on the contiguous
        axis: numpy is fast only when the long axis is innermost), and their squared norms (n^3,);
        independent of ``center_mm``, so they survive translations of the box."""
        if not hasattr(self, "_PT"):
            ii = np.stack(np.meshgrid(*(np.arange(self.n),) * 3, indexing="ij"), -1).reshape(-1, 3)
            P = ((ii - (self.n - 1) / 2.0) * self.spacing_mm) @ self.axes.T
            self._PT = np.ascontiguousarray(P.T)
            self._Psq = np.einsum("ij,ij->i", P, P)
        return self._PT, self._Psq

    def tan2_of_lines(self, origins_mm: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """tan^2 of the angle (L, n^3) between each of L lines (origins (L, 3) mm, unit directions
        (L, 3), world) and the ray from its origin to every voxel centre (rows in the order of
        ``values.ravel()``); at most ``likelihood.MAX_TAN2`` (89.94 deg), also the value behind the
        origin. ``likelihood.tan2_from_local`` with the box centre as reference point."""
        PT, Psq = self._local_points()
        f = np.atleast_2d(np.asarray(origins_mm, float)) - self.center_mm
        return tan2_from_local(PT, Psq, f, directions)

    def add_lines(self, origins_mm: ArrayLike, directions: ArrayLike, coefficients: ArrayLike, chunk: int = 64) -> None:
        """``values += sum_l coefficients[l] * tan2_l`` for lines (L, 3) origins and (L, 3) unit
        directions, world frame (see ``tan2_of_lines``)."""
        o = np.atleast_2d(origins_mm)
        d = np.atleast_2d(directions)
        c = np.atleast_1d(np.asarray(coefficients, float))
        flat = self.values.reshape(-1)
        for i in range(0, len(o), chunk):
            flat += c[i:i + chunk] @ self.tan2_of_lines(o[i:i + chunk], d[i:i + chunk])

    def sq_distance_to(self, point_mm: ArrayLike) -> np.ndarray:
        """Squared distance (n, n, n), mm^2, from every voxel centre to ``point_mm`` (3,)."""
        p = ((np.asarray(point_mm, float) - self.center_mm) @ self.axes)
        w = [(self.offsets[k] - p[k]) ** 2 for k in range(3)]
        return w[0][:, None, None] + w[1][None, :, None] + w[2][None, None, :]

    def argmax(self) -> np.ndarray:
        """(3,) int index of the largest value."""
        return np.array(np.unravel_index(int(np.argmax(self.values)), self.values.shape))

    def to_point_cloud(self, log_values: bool = True) -> Any:          # open3d.t.geometry.PointCloud
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


@dataclass
class _PendingBox:
    """A box being laid over several streaming updates (``VoxelEstimator._advance``): its grid,
    design std (3,) mm, the posterior N(center (3,) mm, cov (3, 3) mm^2) it was laid for, and the
    kept samples evaluated into it so far (the first ``done``)."""

    grid: DensityGrid
    std: np.ndarray
    center: np.ndarray
    cov: np.ndarray
    done: int = 0


def _quadratic_fit_local(grid: DensityGrid, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
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
