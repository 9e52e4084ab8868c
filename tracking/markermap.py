"""Marker maps: where each printed marker is in the world (docs/formats.md, "Marker map").

A marker's frame has its origin at the centre of its black square, x to the right and y down
along the printed marker, z into the wall. Its corners in ``cv2.aruco`` order (top-left,
top-right, bottom-right, bottom-left) are ``(-s/2, -s/2), (s/2, -s/2), (s/2, s/2), (-s/2, s/2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.camera import aruco_dictionary

FORMAT = "wearable-gaze-marker-map"


class MarkerMapError(ValueError):
    """A marker map that cannot be used; the message names the marker or field."""


def square_corners(side_mm: float) -> np.ndarray:
    """(4, 3) corners of a marker in its own frame, cv2.aruco order."""
    s = side_mm / 2
    return np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0.0]])


@dataclass
class MarkerMap:
    """Attributes:
        dictionary: ``cv2.aruco`` dictionary name.
        marker_size_mm: side of the black square.
        poses: id -> (4, 4) ``T_world_from_marker``.
        labels: id -> label.
    """

    dictionary: str
    marker_size_mm: float
    poses: dict
    labels: dict

    def corners(self, marker_id: int) -> np.ndarray:
        """(4, 3) world corners of a marker, mm, cv2.aruco order."""
        T = self.poses[int(marker_id)]
        return square_corners(self.marker_size_mm) @ T[:3, :3].T + T[:3, 3]

    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": 1, "dictionary": self.dictionary,
                "marker_size_mm": float(self.marker_size_mm),
                "markers": [{"id": int(i), "T_world_from_marker": np.round(T, 9).tolist(),
                             **({"label": self.labels[i]} if i in self.labels else {})}
                            for i, T in sorted(self.poses.items())]}

    @classmethod
    def from_dict(cls, d: dict) -> MarkerMap:
        """Validate and load. Each marker gives ``T_world_from_marker`` (4x4) or ``corners_mm``
        (4x3, cv2.aruco order).

        Raises:
            MarkerMapError: unknown dictionary, duplicate ids, ids beyond the dictionary, a
                pose that is not a rigid transform, corners that are not a square of the
                stated size, sizes that look like metres.
        """
        if not isinstance(d, dict):
            raise MarkerMapError("expected a JSON object")
        if d.get("format", FORMAT) != FORMAT:
            raise MarkerMapError(f"'format' is {d.get('format')!r}, expected {FORMAT!r}")
        name = d.get("dictionary")
        try:
            dic = aruco_dictionary(str(name))
        except ValueError as exc:
            raise MarkerMapError(str(exc)) from None
        size = d.get("marker_size_mm")
        if not isinstance(size, (int, float)) or not size > 0:
            raise MarkerMapError(f"'marker_size_mm' must be a positive number of millimetres, got {size!r}")
        if size < 5:
            raise MarkerMapError(f"'marker_size_mm' is {size}: that is a marker smaller than 5 mm; sizes are in "
                                 f"millimetres (a {size * 1000:g} mm marker is written {size * 1000:g}, not {size})")
        markers = d.get("markers")
        if not isinstance(markers, list) or not markers:
            raise MarkerMapError("'markers' must be a non-empty list")
        n_ids = dic.bytesList.shape[0]
        poses, labels = {}, {}
        for k, m in enumerate(markers):
            if not isinstance(m, dict) or "id" not in m:
                raise MarkerMapError(f"markers[{k}]: needs an 'id'")
            i = m["id"]
            if not isinstance(i, int) or not 0 <= i < n_ids:
                raise MarkerMapError(f"markers[{k}]: id {i!r} is not in {name} (0-{n_ids - 1})")
            if i in poses:
                raise MarkerMapError(f"marker {i} appears twice; each id may be placed once")
            if "T_world_from_marker" in m:
                T = np.asarray(m["T_world_from_marker"], float)
                if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                    raise MarkerMapError(f"marker {i}: T_world_from_marker must be a 4x4 matrix")
                R = T[:3, :3]
                if (np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0
                        or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9):
                    raise MarkerMapError(f"marker {i}: T_world_from_marker is not a rigid transform (rotation "
                                         "part must be orthonormal, last row 0 0 0 1)")
            elif "corners_mm" in m:
                T = _pose_from_corners(np.asarray(m["corners_mm"], float), float(size), i)
            else:
                raise MarkerMapError(f"marker {i}: give T_world_from_marker or corners_mm")
            poses[i] = T
            if "label" in m:
                labels[i] = str(m["label"])
        return cls(str(name), float(size), poses, labels)


def _pose_from_corners(C: np.ndarray, size: float, i: int) -> np.ndarray:
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
    centre = C.mean(axis=0)
    x = (C[1] - C[0]) + (C[2] - C[3])
    y = (C[3] - C[0]) + (C[2] - C[1])
    x /= np.linalg.norm(x)
    y -= x * (x @ y)
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, np.cross(x, y), centre
    return T
