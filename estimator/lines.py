"""View lines: the paper's eq. 3-8 and the containers the estimators take.

A view line is an origin (an eye's rotation centre, mm) and a unit direction, in a named frame.
``ViewLines`` holds N of them batch-first; ``BinocularSamples`` holds N samples of a left and a
right line each, either of which may be missing (blink, lost pupil: a monocular sample).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from ._checks import check_points, check_same_rows, check_vector, normalize_directions
from .frames import invert, rotate_directions, transform_points


@dataclass(frozen=True)
class ViewLines:
    """N view lines in one frame.

    Attributes:
        origins_mm: (N, 3) line origins (eye rotation centres), mm, in ``frame``.
        directions: (N, 3) unit directions, in ``frame``.
        frame: name of the frame, e.g. ``"world"`` or ``"cam"``.
        sample_index: (N,) int, the binocular sample each line belongs to (lines of one sample
            share noise sources such as blinks); defaults to one sample per line.
    """

    origins_mm: np.ndarray
    directions: np.ndarray
    frame: str = "world"
    sample_index: np.ndarray | None = None

    def __post_init__(self) -> None:
        o = check_points(self.origins_mm, "origins_mm")
        d = normalize_directions(self.directions, "directions")
        check_same_rows(o, d, "origins_mm", "directions")
        if not np.all(np.isfinite(o)):
            raise ValueError("origins_mm must be finite")
        idx = np.arange(len(o)) if self.sample_index is None else np.asarray(self.sample_index)
        if idx.shape != (len(o),):
            raise ValueError(f"sample_index must have shape ({len(o)},), got {idx.shape}")
        object.__setattr__(self, "origins_mm", o)
        object.__setattr__(self, "directions", d)
        object.__setattr__(self, "sample_index", idx.astype(np.int64))

    def __len__(self) -> int:
        return len(self.origins_mm)

    def point_at(self, distance_mm: ArrayLike) -> np.ndarray:
        """Points (N, 3) at ``distance_mm`` (scalar or (N,)) along each line, mm."""
        return self.origins_mm + np.asarray(distance_mm, dtype=np.float64).reshape(-1, 1) * self.directions


class BinocularSample(NamedTuple):
    """One binocular eye sample as view lines in the world frame (the streaming unit).

    A missing eye (blink, lost pupil) has ``None`` for both its origin and direction.
    """

    t_s: float
    """Sample time, seconds."""
    left_origin_mm: np.ndarray | None
    """(3,) left eye rotation centre, world frame, mm."""
    left_direction: np.ndarray | None
    """(3,) left view direction, world frame (need not be unit)."""
    right_origin_mm: np.ndarray | None
    """(3,) right eye rotation centre, world frame, mm."""
    right_direction: np.ndarray | None
    """(3,) right view direction, world frame (need not be unit)."""


@dataclass(frozen=True)
class BinocularSamples:
    """N binocular samples, batch-first, world frame unless ``frame`` says otherwise.

    Attributes:
        t_s: (N,) sample times, seconds.
        left_origin_mm, right_origin_mm: (N, 3) eye rotation centres, mm (NaN where invalid).
        left_direction, right_direction: (N, 3) unit view directions (NaN where invalid).
        left_valid, right_valid: (N,) bool, which eyes carry a line.
        frame: frame name.
    """

    t_s: np.ndarray
    left_origin_mm: np.ndarray
    left_direction: np.ndarray
    right_origin_mm: np.ndarray
    right_direction: np.ndarray
    left_valid: np.ndarray
    right_valid: np.ndarray
    frame: str = "world"

    @classmethod
    def from_arrays(cls, t_s: ArrayLike, left_origin_mm: ArrayLike, left_direction: ArrayLike,
                    right_origin_mm: ArrayLike, right_direction: ArrayLike,
                    left_valid: ArrayLike | None = None, right_valid: ArrayLike | None = None,
                    frame: str = "world") -> BinocularSamples:
        """Validate and normalise; an eye is valid where its origin and direction are all finite
        (unless masks are given). A valid eye with a zero direction raises ``ValueError``."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        n = len(t)
        arrays = {}
        for side, o, d, v in (("left", left_origin_mm, left_direction, left_valid),
                              ("right", right_origin_mm, right_direction, right_valid)):
            o = check_points(o, f"{side}_origin_mm") if n else np.zeros((0, 3))
            d = check_points(d, f"{side}_direction") if n else np.zeros((0, 3))
            check_same_rows(o, t, f"{side}_origin_mm", "t_s")
            check_same_rows(d, t, f"{side}_direction", "t_s")
            finite = np.all(np.isfinite(o), axis=1) & np.all(np.isfinite(d), axis=1)
            valid = finite if v is None else np.asarray(v, dtype=bool).reshape(-1) & finite
            dn = np.full((n, 3), np.nan)
            on = np.full((n, 3), np.nan)
            if np.any(valid):
                dn[valid] = normalize_directions(d[valid], f"{side}_direction")
                on[valid] = o[valid]
            arrays[side] = (on, dn, valid)
        return cls(t, *arrays["left"][:2], *arrays["right"][:2], arrays["left"][2],
                   arrays["right"][2], frame)

    @classmethod
    def from_lines(cls, t_s: ArrayLike, left: ViewLines, right: ViewLines) -> BinocularSamples:
        """Pair two equally long ``ViewLines`` (left, right) into binocular samples."""
        return cls.from_arrays(t_s, left.origins_mm, left.directions, right.origins_mm,
                               right.directions, frame=left.frame)

    @classmethod
    def concatenate(cls, parts: Iterable[BinocularSamples]) -> BinocularSamples:
        """Join ``BinocularSamples`` (same frame) end to end."""
        parts = list(parts)
        if not parts:
            raise ValueError("nothing to concatenate")
        frames = {p.frame for p in parts}
        if len(frames) != 1:
            raise ValueError(f"cannot concatenate samples in different frames: {sorted(frames)}")
        def joined(name: str) -> np.ndarray:
            return np.concatenate([getattr(p, name) for p in parts])
        return cls(joined("t_s"), joined("left_origin_mm"), joined("left_direction"),
                   joined("right_origin_mm"), joined("right_direction"), joined("left_valid"),
                   joined("right_valid"), parts[0].frame)

    def __len__(self) -> int:
        return len(self.t_s)

    def select(self, index: slice | np.ndarray) -> BinocularSamples:
        """The samples at ``index`` (a slice, boolean mask or integer array)."""
        return BinocularSamples(self.t_s[index], self.left_origin_mm[index], self.left_direction[index],
                                self.right_origin_mm[index], self.right_direction[index],
                                self.left_valid[index], self.right_valid[index], self.frame)

    def sample(self, i: int) -> BinocularSample:
        """Sample ``i`` as a streaming ``BinocularSample``."""
        lv, rv = bool(self.left_valid[i]), bool(self.right_valid[i])
        return BinocularSample(float(self.t_s[i]),
                               self.left_origin_mm[i] if lv else None, self.left_direction[i] if lv else None,
                               self.right_origin_mm[i] if rv else None, self.right_direction[i] if rv else None)

    def origin_mm(self, i: int) -> np.ndarray:
        """(3,) an eye's origin at sample ``i``: the left's when it is valid, else the right's."""
        return self.left_origin_mm[i] if self.left_valid[i] else self.right_origin_mm[i]

    def lines(self) -> ViewLines:
        """All valid lines, left then right per sample, with ``sample_index`` set."""
        idx = np.arange(len(self))
        o = np.concatenate([self.left_origin_mm[self.left_valid], self.right_origin_mm[self.right_valid]])
        d = np.concatenate([self.left_direction[self.left_valid], self.right_direction[self.right_valid]])
        si = np.concatenate([idx[self.left_valid], idx[self.right_valid]])
        order = np.argsort(si, kind="stable")
        return ViewLines(o[order], d[order], self.frame, si[order])

    @property
    def binocular(self) -> np.ndarray:
        """(N,) bool: both eyes valid."""
        return self.left_valid & self.right_valid


def samples_from_stream(samples: Iterable[BinocularSample]) -> BinocularSamples:
    """Stack an iterable of ``BinocularSample`` into ``BinocularSamples`` (world frame)."""
    samples = list(samples)
    nan3 = np.full(3, np.nan)

    def col(attr: str) -> np.ndarray:
        return np.array([nan3 if getattr(s, attr) is None else np.asarray(getattr(s, attr), float)
                         for s in samples]).reshape(-1, 3)

    return BinocularSamples.from_arrays([s.t_s for s in samples], col("left_origin_mm"),
                                        col("left_direction"), col("right_origin_mm"),
                                        col("right_direction"))


# --- The paper's eq. 3-8 ----------------------------------------------------------------------

def calibration_plane_points(px: ArrayLike, camera_matrix: ArrayLike, wall_distance_mm: float) -> np.ndarray:
    """Paper eq. 3: image points on the view-camera image -> points on the calibration plane.

    ``q_c`` is the gaze point on the image plane at focal length ``l_i``; the plane (wall) is
    perpendicular to the optical axis at ``l_c = wall_distance_mm``; ``p_c = (l_c / l_i) q_c``.
    With pixel coordinates and the camera matrix, ``q_c / l_i = K^-1 [u, v, 1]``.

    Args:
        px: (N, 2) undistorted pixel coordinates of the calibrated gaze points.
        camera_matrix: (3, 3) intrinsic matrix K, pixels.
        wall_distance_mm: distance ``l_c`` of the calibration plane along the optical axis, mm.

    Returns:
        (N, 3) points ``p_c`` in the camera frame, mm.
    """
    uv = check_points(px, "px", dim=2)
    K = np.asarray(camera_matrix, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"camera_matrix must have shape (3, 3), got {K.shape}")
    if not wall_distance_mm > 0:
        raise ValueError(f"wall_distance_mm must be positive, got {wall_distance_mm}")
    rays = np.linalg.solve(K, np.column_stack([uv, np.ones(len(uv))]).T).T
    return wall_distance_mm * rays / rays[:, 2:3]


def view_lines_in_camera(points_cam_mm: ArrayLike, eye_center_cam_mm: ArrayLike) -> ViewLines:
    """Paper eq. 4: the view line of an eye through gazed points.

    Args:
        points_cam_mm: (N, 3) gazed points ``p_c`` in the camera frame, mm.
        eye_center_cam_mm: (3,) the eye's rotation centre ``e_c`` in the camera frame, mm.

    Returns:
        ``ViewLines`` in frame ``"cam"`` with origin ``e_c`` and direction ``(p_c - e_c)/|p_c - e_c|``.
    """
    p = check_points(points_cam_mm, "points_cam_mm")
    e = check_vector(eye_center_cam_mm, "eye_center_cam_mm")
    return ViewLines(np.broadcast_to(e, p.shape).copy(), p - e, frame="cam")


def view_lines_to_world(lines_cam: ViewLines, T_cam_from_world: ArrayLike | None = None, *,
                        T_world_from_cam: ArrayLike | None = None) -> ViewLines:
    """Paper eq. 7-8: ``e_g = R^-1 (e_c - T)``, ``d_g = R^-1 d_c``.

    Args:
        lines_cam: ``ViewLines`` in the camera frame.
        T_cam_from_world: (4, 4), or (N, 4, 4) one per line: the head pose (the paper's R, T).
        T_world_from_cam: the same pose the other way round, as tracking gives it (keyword only;
            pass one of the two): used as it is, with no inversion.

    Returns:
        ``ViewLines`` in frame ``"world"``.
    """
    if lines_cam.frame != "cam":
        raise ValueError(f"lines_cam must be in frame 'cam', got {lines_cam.frame!r}")
    if (T_cam_from_world is None) == (T_world_from_cam is None):
        raise ValueError("pass exactly one of T_cam_from_world and T_world_from_cam")
    if T_world_from_cam is not None:
        T_wc = np.asarray(T_world_from_cam, dtype=np.float64)
    else:
        T = np.asarray(T_cam_from_world, dtype=np.float64)
        T_wc = invert(T) if T.shape == (4, 4) else np.stack([invert(t) for t in T])
    return ViewLines(transform_points(T_wc, lines_cam.origins_mm),
                     rotate_directions(T_wc, lines_cam.directions), "world", lines_cam.sample_index)


def view_lines_to_camera(lines_world: ViewLines, T_cam_from_world: ArrayLike) -> ViewLines:
    """Paper eq. 5-6: ``e_c = R e_g + T``, ``d_c = R d_g``; the inverse of ``view_lines_to_world``."""
    if lines_world.frame != "world":
        raise ValueError(f"lines_world must be in frame 'world', got {lines_world.frame!r}")
    return ViewLines(transform_points(T_cam_from_world, lines_world.origins_mm),
                     rotate_directions(T_cam_from_world, lines_world.directions), "cam",
                     lines_world.sample_index)
