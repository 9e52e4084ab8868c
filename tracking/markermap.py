"""Marker maps: where each printed marker is in the world (the file is read and written by
``wearable_gaze.formats.markermap``; docs/session.md, "Marker map").

A marker's frame has its origin at the centre of its black square, x to the right and y down
along the printed marker, z into the wall. Its corners in ``cv2.aruco`` order (top-left,
top-right, bottom-right, bottom-left) are ``(-s/2, -s/2), (s/2, -s/2), (s/2, s/2), (-s/2, s/2)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike


class MarkerMapError(ValueError):
    """A marker map that cannot be used; the message names the marker or field."""


def square_corners(side_mm: float) -> np.ndarray:
    """(4, 3) corners of a marker in its own frame, cv2.aruco order."""
    s = side_mm / 2
    return np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0.0]])


def marker_corners_world(side_mm: float, T_world_from_marker: ArrayLike) -> np.ndarray:
    """(4, 3) world corners, mm, of a marker of side ``side_mm`` placed at ``T_world_from_marker``
    (4, 4), cv2.aruco order: top-left, top-right, bottom-right, bottom-left."""
    T = np.asarray(T_world_from_marker, float)
    return square_corners(side_mm) @ T[:3, :3].T + T[:3, 3]


@dataclass
class MarkerMap:
    """Attributes:
        dictionary: ``cv2.aruco`` dictionary name.
        marker_size_mm: side of the black square (of every marker ``sizes`` does not name).
        poses: id -> (4, 4) ``T_world_from_marker``.
        labels: id -> label.
        sizes: id -> side, mm, of the markers printed at another size.
    """

    dictionary: str
    marker_size_mm: float
    poses: dict
    labels: dict
    sizes: dict = field(default_factory=dict)

    def size_of(self, marker_id: int) -> float:
        """The printed side of a marker, mm."""
        return float(self.sizes.get(int(marker_id), self.marker_size_mm))

    def corners(self, marker_id: int) -> np.ndarray:
        """(4, 3) world corners of a marker, mm, cv2.aruco order."""
        return marker_corners_world(self.size_of(marker_id), self.poses[int(marker_id)])


def pose_from_corners(C: np.ndarray, size: float, i: int) -> np.ndarray:
    """(4, 4) ``T_world_from_marker`` of marker ``i`` from its (4, 3) world corners ``C``, mm,
    cv2.aruco order, for a black square of side ``size`` mm.

    Raises:
        MarkerMapError: not 4 finite corners of 3 numbers, corners in metres, or corners that
            are not a square of side ``size``.
    """
    if C.shape != (4, 3) or not np.all(np.isfinite(C)):
        raise MarkerMapError(f"marker {i}: corners_mm must be 4 corners of 3 numbers (mm)")
    sides = np.linalg.norm(C - np.roll(C, -1, axis=0), axis=1)
    diag = np.linalg.norm(C[2] - C[0]), np.linalg.norm(C[3] - C[1])
    if np.mean(sides) < 5 and size >= 5:
        raise MarkerMapError(f"marker {i}: corners are {np.mean(sides):.3g} apart; corners are in millimetres, "
                             "not metres")
    tol = max(0.02 * size, 1.0)
    if np.abs(sides - size).max() > tol or abs(diag[0] - diag[1]) > tol:
        raise MarkerMapError(f"marker {i}: its corners are not a square of side {size:g} mm (sides "
                             f"{', '.join(f'{s:.1f}' for s in sides)} mm)")
    center = C.mean(axis=0)
    x = (C[1] - C[0]) + (C[2] - C[3])
    y = (C[3] - C[0]) + (C[2] - C[1])
    x /= np.linalg.norm(x)
    y -= x * (x @ y)
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, np.cross(x, y), center
    return T
