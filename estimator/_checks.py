"""Input checks shared by the libraries: convert to float64 and raise ``ValueError`` naming the
shape that was received and the shape that was expected."""

from __future__ import annotations

from collections.abc import Sized

import numpy as np
from numpy.typing import ArrayLike


def check_points(points: ArrayLike, name: str = "points", dim: int = 3) -> np.ndarray:
    """Return ``points`` as a float64 array of shape (N, dim); a single (dim,) point becomes (1, dim)."""
    a = np.asarray(points, dtype=np.float64)
    if a.ndim == 1 and a.shape[0] == dim:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {a.shape}")
    return a


def check_array(a: ArrayLike, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``a`` as a float64 array of ``shape``, where ``None`` stands for any length (``(None,
    4, 4)``: N transforms). Raises ``ValueError`` naming the expected and the received shape."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    return arr


def check_same_rows(a: Sized, b: Sized, name_a: str, name_b: str, want: str = "as many rows") -> None:
    """Raise ``ValueError`` unless ``a`` and ``b`` have as many rows (``len``): the message names
    both and their lengths; ``want`` says what is asked (``"one row per target"``)."""
    if len(a) != len(b):
        raise ValueError(f"{name_a} and {name_b} must have {want}, got {len(a)} and {len(b)}")


def check_vector(v: ArrayLike, name: str = "vector", dim: int = 3) -> np.ndarray:
    """Return ``v`` as a float64 array of shape (dim,)."""
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (dim,):
        raise ValueError(f"{name} must have shape ({dim},), got {a.shape}")
    return a


_EYE3 = np.eye(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def check_transform(T: ArrayLike, name: str = "transform") -> np.ndarray:
    """Return ``T`` as a (4, 4) float64 rigid transform; the rotation block must be orthonormal."""
    a = np.asarray(T, dtype=np.float64)
    if a.shape != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4), got {a.shape}")
    R = a[:3, :3]
    # np.allclose's tests written out (it costs 10x these; the live loop checks a pose per sample)
    if not np.all(np.abs(R @ R.T - _EYE3) <= 1e-6 + 1e-5 * _EYE3) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} must hold a proper rotation in its upper-left 3x3 block")
    if not np.all(np.abs(a[3] - _LAST_ROW) <= 1e-8 + 1e-5 * _LAST_ROW):
        raise ValueError(f"{name} must have [0, 0, 0, 1] as its last row, got {a[3].tolist()}")
    return a


def normalize_directions(directions: ArrayLike, name: str = "directions", min_norm: float = 1e-12) -> np.ndarray:
    """Return (N, 3) unit vectors; a zero or non-finite direction raises ``ValueError`` naming its row."""
    d = check_points(directions, name)
    n = np.linalg.norm(d, axis=1)
    bad = ~np.isfinite(n) | (n <= min_norm)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name}[{i}] is {d[i].tolist()}: a direction must be finite and non-zero")
    return d / n[:, None]
