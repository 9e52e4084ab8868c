"""Simulated worlds: a lab room with markers and posters, gaze-target cards, the calibration wall
and camera-calibration boards.

World frame (mm): origin at the head's starting position (the scene camera's centre), x right,
y down (gravity), z forward: the scene camera at the identity pose looks down +z, upright.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from calibration.camera import aruco_dictionary
from tracking.markermap import marker_corners_world

from .planes import Plane, marker_plane
from .textures import chessboard_texture, noise_texture, poster_texture, target_texture

MM_PER_TEXEL_WALL = 4.0


def frame(origin, x_axis, y_axis) -> np.ndarray:
    """(4, 4) transform with the given origin (3,) and x, y axes (z = x cross y)."""
    x = np.asarray(x_axis, float)
    y = np.asarray(y_axis, float)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, y, np.cross(x, y)
    T[:3, 3] = origin
    return T


def look_at(position, target, down=(0.0, 1.0, 0.0)) -> np.ndarray:
    """(4, 4) ``T_world_from_cam`` of a camera at ``position`` (3,) looking at ``target`` (3,),
    upright (its y axis as close to world ``down`` as the view direction allows)."""
    z = np.asarray(target, float) - np.asarray(position, float)
    z /= np.linalg.norm(z)
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    return frame(position, x, np.cross(z, x))


@dataclass
class Target:
    """A gaze target: a bullseye card whose centre is the gazed point.

    ``path(t)`` gives the centre (N, 3) at times t (N,), world frame, mm; a fixed target
    returns the same point. The card faces ``facing`` (a world point, default the origin)."""

    name: str
    path: Callable[[np.ndarray], np.ndarray]
    size_mm: float = 100.0
    facing: tuple = (0.0, 0.0, 0.0)
    moving: bool = False

    def at(self, t: float) -> np.ndarray:
        return self.path(np.array([t], float))[0]

    def plane(self, t: float) -> Plane:
        """The card at time t (a fixed card is built once; a moving one shares its texture
        pyramid between frames)."""
        cached = self.__dict__.get("_plane")
        if cached is not None and not self.moving:
            return cached
        c = self.at(t)
        T = look_at(c, 2 * c - np.asarray(self.facing, float))   # card normal points away from the viewer
        T[:3, 3] -= T[:3, 0] * self.size_mm / 2 + T[:3, 1] * self.size_mm / 2
        p = Plane(T, (self.size_mm, self.size_mm), _TARGET_TEX, self.name, supersample=1)
        if cached is not None:
            p._pyramid.extend(cached._pyramid)
            p._pyramid2.extend(cached._pyramid2)
        self.__dict__["_plane"] = p
        return p


_TARGET_TEX = target_texture(128)


def fixed_point(p) -> Callable[[np.ndarray], np.ndarray]:
    p = np.asarray(p, float)
    return lambda t: np.broadcast_to(p, (len(np.atleast_1d(t)), 3)).copy()


def waypoint_path(points, times) -> Callable[[np.ndarray], np.ndarray]:
    """Piecewise-linear path through ``points`` (K, 3) at ``times`` (K,), held at the ends."""
    P = np.asarray(points, float)
    T = np.asarray(times, float)
    return lambda t: np.column_stack([np.interp(np.atleast_1d(t), T, P[:, i]) for i in range(3)])


@dataclass(frozen=True)
class MarkerMove:
    """A marker taken down at ``at_s`` and put up again elsewhere at once (between two frames).

    Attributes:
        marker_id: the marker.
        at_s: the time of the move, s: frames at ``t >= at_s`` see it at its new pose.
        T_world_from_marker_before, T_world_from_marker_after: (4, 4) its poses, world frame, mm.
        plane_before, plane_after: its ``Plane`` at each pose.
    """

    marker_id: int
    at_s: float
    T_world_from_marker_before: np.ndarray
    T_world_from_marker_after: np.ndarray
    plane_before: Plane
    plane_after: Plane


def moved_pose(T_world_from_marker, shift_mm, turn_deg: float) -> np.ndarray:
    """(4, 4) a marker's pose after a move: shifted by ``shift_mm`` (3,) in its own frame (x right
    along the print, y down, z into the wall: [150, 0, 0] is 150 mm to its right along the wall)
    and turned ``turn_deg`` about its own z axis through its centre (clockwise as seen from the
    room: x toward y)."""
    a = np.deg2rad(float(turn_deg))
    T_old_from_new = np.eye(4)
    T_old_from_new[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T_old_from_new[:3, 3] = np.asarray(shift_mm, float)
    return np.asarray(T_world_from_marker, float) @ T_old_from_new


@dataclass
class World:
    """Static planes, moving target cards and the marker map.

    Attributes:
        planes: static ``Plane``s (walls carry ``shell=True``).
        targets: gaze targets.
        dictionary: ``cv2.aruco`` dictionary name of the markers.
        marker_size_mm: side of every marker's black square, mm.
        markers: id -> (4, 4) ``T_world_from_marker`` (x right, y down along the printed
            marker, z into the wall; origin at the marker's centre), at the session's start
            (a moved marker's pose before its move: ``moves``).
        moves: id -> ``MarkerMove``: markers that move during the session.
    """

    planes: list = field(default_factory=list)
    targets: list = field(default_factory=list)
    dictionary: str = "DICT_4X4_50"
    marker_size_mm: float = 150.0
    markers: dict = field(default_factory=dict)
    moves: dict = field(default_factory=dict)

    def planes_at(self, t: float) -> list:
        """The planes seen at time t, s: moved markers where they are then, and the cards."""
        planes = self.planes
        if self.moves:
            now = {id(m.plane_before): m.plane_after for m in self.moves.values() if t >= m.at_s}
            planes = [now.get(id(p), p) for p in planes]
        return planes + [tg.plane(t) for tg in self.targets]

    def add_marker(self, marker_id: int, T_world_from_marker) -> None:
        self.markers[int(marker_id)] = np.asarray(T_world_from_marker, float)
        self.planes.append(marker_plane(self.dictionary, marker_id, self.marker_size_mm, T_world_from_marker))

    def move_marker(self, marker_id: int, at_s: float, T_world_from_marker_after) -> MarkerMove:
        """Move marker ``marker_id`` (already added, not yet moved) to ``T_world_from_marker_after``
        (4, 4) at time ``at_s``, s. ``markers`` keeps its pose before the move."""
        i = int(marker_id)
        if i not in self.markers or i in self.moves:
            raise ValueError(f"marker {i} is not in the world, or already moves: one move per marker")
        before = next(p for p in self.planes if p.name == f"marker {i}")
        after = np.asarray(T_world_from_marker_after, float)
        move = MarkerMove(i, float(at_s), self.markers[i], after, before,
                          marker_plane(self.dictionary, i, self.marker_size_mm, after))
        self.moves[i] = move
        return move

    def markers_at(self, t: float) -> dict:
        """id -> (4, 4) ``T_world_from_marker`` at time t, s."""
        return {i: (self.moves[i].T_world_from_marker_after if i in self.moves and t >= self.moves[i].at_s else T)
                for i, T in self.markers.items()}

    def marker_corners(self, t: float | None = None) -> dict:
        """id -> (4, 3) world corners (cv2.aruco order), mm: at the session's start (``markers``),
        or at time ``t``, s."""
        poses = self.markers if t is None else self.markers_at(t)
        return {i: marker_corners_world(self.marker_size_mm, T) for i, T in poses.items()}


def lab_room(rng: np.random.Generator, size_mm=(4000.0, 2700.0, 5000.0), eye_height_mm: float = 1600.0,
             back_mm: float = 1500.0, markers_per_wall: int = 6, dictionary: str = "DICT_4X4_50",
             marker_size_mm: float = 200.0, posters_per_wall: int = 2) -> World:
    """A rectangular room around the origin with textured walls, floor and ceiling, posters
    and a row of markers on each wall around eye height.

    Args:
        size_mm: (width x, height y, depth z) of the room.
        eye_height_mm: the origin's height above the floor.
        back_mm: distance from the origin to the back wall (the front wall is at depth - back).
        markers_per_wall: markers on each of the four walls (ids run 0, 1, ... wall by wall:
            front, right, back, left).
    """
    W, H, D = size_mm
    y_ceil, y_floor = -(H - eye_height_mm), eye_height_mm
    z_back, z_front = -back_mm, D - back_mm
    x_l, x_r = -W / 2, W / 2
    ex, ey, ez = np.eye(3)
    walls = [  # name, origin (top-left), x axis, y axis, size
        ("front wall", (x_l, y_ceil, z_front), ex, ey, (W, H)),
        ("right wall", (x_r, y_ceil, z_front), -ez, ey, (D, H)),
        ("back wall", (x_r, y_ceil, z_back), -ex, ey, (W, H)),
        ("left wall", (x_l, y_ceil, z_back), ez, ey, (D, H)),
        ("floor", (x_l, y_floor, z_front), ex, -ez, (W, D)),
        ("ceiling", (x_l, y_ceil, z_back), ex, ez, (W, D)),
    ]
    world = World(dictionary=dictionary, marker_size_mm=marker_size_mm)
    aruco_dictionary(dictionary)                      # fail early on an unknown name
    next_id = 0
    for name, origin, xa, ya, size in walls:
        tex_size = (int(size[0] / MM_PER_TEXEL_WALL), int(size[1] / MM_PER_TEXEL_WALL))
        is_wall = "wall" in name
        tex = noise_texture(rng, tex_size, blob_px=24, contrast=14 if is_wall else 20,
                            mean=170 if is_wall else (90 if name == "floor" else 200))
        T_wall = frame(origin, xa, ya)
        if is_wall:
            for k in range(posters_per_wall):       # posters above the marker row
                pw, ph = int(rng.integers(120, 200)), int(rng.integers(150, 230))
                x0 = int((k + 0.5) * tex.shape[1] / posters_per_wall - pw / 2)
                y0 = int((H - eye_height_mm - 550) / MM_PER_TEXEL_WALL) - ph // 2
                y0 = max(y0, 5)
                tex[y0:y0 + ph, x0:x0 + pw] = poster_texture(rng, (pw, ph))
        world.planes.append(Plane(T_wall, size, tex, name, shell=True))
        if is_wall and markers_per_wall > 0:
            n = markers_per_wall
            for k in range(n):
                u = (k + 0.5) * size[0] / n + rng.uniform(-0.1, 0.1) * size[0] / n
                v = (H - eye_height_mm) + (-250.0 if k % 2 else 150.0) + rng.uniform(-60, 60)
                T_m = T_wall.copy()
                T_m[:3, 3] = T_wall[:3, 3] + u * T_wall[:3, 0] + v * T_wall[:3, 1]
                world.add_marker(next_id, T_m)
                next_id += 1
    return world


@dataclass
class CalibrationWall:
    """The nine-point calibration wall: a flat wall at ``distance_mm`` in front of the (still)
    head, turned ``tilt_deg`` about the vertical axis, with calibration dots and four reference
    markers at its corners.

    Wall frame (mm): origin at the wall point straight ahead of the camera, x right, y down,
    z into the wall. ``T_world_from_wall`` places it; the camera is at the world origin.
    """

    distance_mm: float
    tilt_deg: float
    spacing_mm: tuple = (400.0, 300.0)
    grid: tuple = (3, 3)
    dictionary: str = "DICT_4X4_50"
    marker_size_mm: float = 120.0
    marker_ids: tuple = (46, 47, 48, 49)

    @classmethod
    def spanning(cls, distance_mm: float, tilt_deg: float, grid=(3, 3), span_deg=(20.0, 15.0)) -> CalibrationWall:
        """A wall whose dot grid spans +-span_deg (horizontal, vertical) as seen from the camera,
        with reference markers scaled to the distance (120 mm at 1 m)."""
        nx, ny = int(grid[0]), int(grid[1])
        sx = distance_mm * np.tan(np.deg2rad(span_deg[0])) / ((nx - 1) / 2)
        sy = distance_mm * np.tan(np.deg2rad(span_deg[1])) / ((ny - 1) / 2)
        return cls(float(distance_mm), float(tilt_deg), (sx, sy), (nx, ny), marker_size_mm=120.0 * distance_mm / 1000)

    @property
    def T_world_from_wall(self) -> np.ndarray:
        a = np.deg2rad(self.tilt_deg)
        T = np.eye(4)
        T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        T[:3, 3] = [0, 0, self.distance_mm]
        return T

    def targets_wall(self) -> np.ndarray:
        """(K, 2) calibration dots in the wall frame, mm, row by row from the top left."""
        nx, ny = self.grid
        sx, sy = self.spacing_mm
        xs = (np.arange(nx) - (nx - 1) / 2) * sx
        ys = (np.arange(ny) - (ny - 1) / 2) * sy
        return np.array([[x, y] for y in ys for x in xs])

    def markers_wall(self) -> dict:
        """Reference marker id -> (2,) centre in the wall frame, mm (outside the dot grid)."""
        nx, ny = self.grid
        hx = (nx - 1) / 2 * self.spacing_mm[0] + 1.2 * self.marker_size_mm
        hy = (ny - 1) / 2 * self.spacing_mm[1] + 1.0 * self.marker_size_mm
        pos = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
        return {int(i): np.array(p) for i, p in zip(self.marker_ids, pos, strict=True)}

    def to_world(self, pts_wall) -> np.ndarray:
        """(N, 2) wall points -> (N, 3) world points, mm."""
        p = np.asarray(pts_wall, float).reshape(-1, 2)
        h = np.column_stack([p, np.zeros(len(p)), np.ones(len(p))])
        return (self.T_world_from_wall @ h.T).T[:, :3]

    def world(self) -> World:
        ext = np.abs(np.array(list(self.markers_wall().values()))).max(axis=0) + self.marker_size_mm
        size = tuple(float(v) for v in 2 * ext + 200.0)
        mm_per_px = max(size[0] / 1600, 0.5)
        tex = np.full((int(size[1] / mm_per_px), int(size[0] / mm_per_px)), 225, np.uint8)
        origin = np.array([-size[0] / 2, -size[1] / 2])
        for x, y in self.targets_wall():
            c = ((np.array([x, y]) - origin) / mm_per_px).astype(int)
            r = max(int(round(0.012 * self.distance_mm / mm_per_px)), 3)
            cv2.circle(tex, tuple(int(v) for v in c), r, 20, -1, cv2.LINE_AA)
            cv2.circle(tex, tuple(int(v) for v in c), max(r // 4, 1), 225, -1, cv2.LINE_AA)
        T_plane = self.T_world_from_wall @ frame((origin[0], origin[1], 0), (1, 0, 0), (0, 1, 0))
        w = World(planes=[Plane(T_plane, size, tex, "calibration wall", shell=True)],
                  dictionary=self.dictionary, marker_size_mm=self.marker_size_mm)
        for i, c in self.markers_wall().items():
            T_m = self.T_world_from_wall @ frame((c[0], c[1], 0), (1, 0, 0), (0, 1, 0))
            w.add_marker(i, T_m)
        return w

    def to_dict(self) -> dict:
        """The wall description a user writes for a real calibration (see docs/session.md)."""
        return {
            "distance_mm": self.distance_mm,
            "grid": list(self.grid),
            "targets_wall_mm": self.targets_wall().tolist(),
            "dictionary": self.dictionary,
            "marker_size_mm": self.marker_size_mm,
            "markers_wall_mm": {str(i): c.tolist() for i, c in self.markers_wall().items()},
        }


def board_plane(spec: dict, T_world_from_board) -> tuple[Plane, np.ndarray]:
    """A calibration board and its (N, 3) object points in the board frame, mm.

    ``spec``: ``{"type": "chessboard", "cols", "rows", "square_mm"}`` (inner corners) or
    ``{"type": "charuco", "cols", "rows", "square_mm", "marker_mm", "dictionary"}`` (squares).
    The board frame: origin at the first inner corner (chessboard) or the board's top-left
    corner (ChArUco, as ``cv2.aruco.CharucoBoard``), x along columns, y along rows, z into the
    board.
    """
    sq = float(spec["square_mm"])
    if spec["type"] == "chessboard":
        cols, rows = int(spec["cols"]), int(spec["rows"])
        tex = chessboard_texture(cols, rows, 40)
        size = ((cols + 3) * sq, (rows + 3) * sq)
        shift = frame((-2 * sq, -2 * sq, 0), (1, 0, 0), (0, 1, 0))
        obj = np.array([[c * sq, r * sq, 0] for r in range(rows) for c in range(cols)], float)
        return Plane(np.asarray(T_world_from_board, float) @ shift, size, tex, "chessboard", supersample=2), obj
    cols, rows = int(spec["cols"]), int(spec["rows"])
    board = cv2.aruco.CharucoBoard((cols, rows), sq, float(spec["marker_mm"]),
                                   aruco_dictionary(spec["dictionary"]))
    px = 60
    margin = px
    tex = board.generateImage((cols * px + 2 * margin, rows * px + 2 * margin), marginSize=margin, borderBits=1)
    size = ((cols + 2) * sq, (rows + 2) * sq)
    shift = frame((-sq, -sq, 0), (1, 0, 0), (0, 1, 0))
    obj = np.asarray(board.getChessboardCorners(), float)
    return Plane(np.asarray(T_world_from_board, float) @ shift, size, tex, "charuco", supersample=2), obj
