"""Frames, units and rigid transforms: the one place they are defined.

Units
    Millimetres for lengths, seconds for time, radians inside the maths (degrees only at the
    user-facing boundary, always in names ending ``_deg``).

Camera axes
    OpenCV's: x right, y down, z forward (the viewing direction).

Frames
    ``world``  the marker map's frame (or the simulation's); fixed in the room.
    ``cam``    the scene (view) camera, between the eyes; the head frame of the paper.
    ``eye``    not a frame: eye rotation centres are points given in ``cam``.

Transforms
    A transform is a (4, 4) float64 matrix named by both frames, ``T_b_from_a``, mapping points in
    frame ``a`` to frame ``b``: ``p_b = T_b_from_a @ p_a``. They compose left to right:
    ``T_world_from_cam = T_world_from_head @ T_head_from_cam``. The paper's ``(R, T)`` with
    ``x_c = R x_g + T`` is ``T_cam_from_world``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ._checks import check_points, check_transform


def transform_from_rotation_translation(R: ArrayLike, t_mm: ArrayLike) -> np.ndarray:
    """Build ``T_b_from_a`` (4, 4) from a rotation (3, 3) and a translation (3,) in mm."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=np.float64)
    T[:3, 3] = np.asarray(t_mm, dtype=np.float64)
    return check_transform(T, "transform")


def invert(T_b_from_a: ArrayLike) -> np.ndarray:
    """Return ``T_a_from_b`` (4, 4), the inverse of a rigid transform ``T_b_from_a`` (4, 4)."""
    T = check_transform(T_b_from_a, "T_b_from_a")
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def _stack_transforms(T: ArrayLike, n: int, name: str) -> np.ndarray:
    a = np.asarray(T, dtype=np.float64)
    if a.shape == (4, 4):
        check_transform(a, name)
        return np.broadcast_to(a, (n, 4, 4))
    if a.shape != (n, 4, 4):
        raise ValueError(f"{name} must have shape (4, 4) or ({n}, 4, 4), got {a.shape}")
    return a


def transform_points(T_b_from_a: ArrayLike, pts_a: ArrayLike) -> np.ndarray:
    """Map points (N, 3) from frame a to frame b with one (4, 4) transform or one per point (N, 4, 4)."""
    p = check_points(pts_a, "pts_a")
    T = _stack_transforms(T_b_from_a, len(p), "T_b_from_a")
    return np.einsum("nij,nj->ni", T[:, :3, :3], p) + T[:, :3, 3]


def rotate_directions(T_b_from_a: ArrayLike, dirs_a: ArrayLike) -> np.ndarray:
    """Rotate directions (N, 3) from frame a to frame b (translation ignored)."""
    d = check_points(dirs_a, "dirs_a")
    T = _stack_transforms(T_b_from_a, len(d), "T_b_from_a")
    return np.einsum("nij,nj->ni", T[:, :3, :3], d)


def rotation_about_axis(axis: ArrayLike, angle_rad: float) -> np.ndarray:
    """Rotation matrix (3, 3) for a right-handed rotation of ``angle_rad`` about a unit ``axis`` (3,)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * (K @ K)


def angle_deg(a: ArrayLike, b: ArrayLike) -> Any:          # (...,) array, or a NumPy float
    """The angle between vectors ``a`` and ``b`` (..., 3), degrees (any lengths; ``atan2`` of the
    cross and dot products, accurate near 0 and 180)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1)))


def tangent_basis(directions: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (N, 3) each, orthogonal to each unit direction (N, 3) and to each other.

    ``(b1, b2, d)`` is right-handed; used to express angular residuals as two tangent components.
    """
    d = check_points(directions, "directions")
    helper = np.where(np.abs(d[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    b1 = np.cross(helper, d)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = np.cross(d, b1)
    return b1, b2


def similarity_transform(A: ArrayLike, B: ArrayLike) -> np.ndarray:
    """The similarity (4, 4) (scale times rotation, translation mm) that best maps points ``A``
    (N, 3) onto ``B`` (N, 3), N >= 3 not on one line, in least squares (Umeyama 1991):
    ``B ~ T[:3, :3] @ A + T[:3, 3]``; its scale is the cube root of the upper block's determinant.
    The one fit between two frames of the same points: a built or markerless map placed by known
    markers, a simulated truth moved into the world of the map a run used."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    ma, mb = A.mean(0), B.mean(0)
    Ac, Bc = A - ma, B - mb
    U, S, Vt = np.linalg.svd(Bc.T @ Ac / len(A))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    s = np.trace(np.diag(S) @ D) / (Ac ** 2).sum(1).mean()
    T = np.eye(4)
    T[:3, :3] = s * (U @ D @ Vt)
    T[:3, 3] = mb - T[:3, :3] @ ma
    return T
