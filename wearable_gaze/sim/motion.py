"""Head motion: ``T_world_from_cam(t)`` of the head-worn scene camera, world frame, mm, seconds.

Every motion is tabulated at 240 Hz over the session and interpolated (linear translation,
SLERP rotation), so video frames and eye samples at any rate see one continuous trajectory.

- ``linear``: the paper's protocol: a straight translation (200 mm to the right by default),
  orientation fixed.
- ``sway``: natural head sway around a standing position: smooth random rotations and
  translations (sums of incommensurate sinusoids, 0.05-0.6 Hz) bounded by the amplitudes, on
  top of a heading that turns toward the fixated target (people turn the head part of the way).
- ``walk``: walking from the start toward a point at a given speed (with gait bob and sway),
  stopping at a distance, heading toward the fixated target.
- ``fixed``: a still head (chin rest); the paper's section 6.2 set-up, with a moving target.
- ``survey``: walking a loop around the room, inset from its walls, once per ``survey_loop_s``,
  looking at the walls: the heading follows the loop's outward normal (smoothed over the
  corners), scanning slowly left and right, so that every wall's markers are seen, each from a
  range of directions (the video a marker map is built from). It ignores the fixated target.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, Slerp

from .world import look_at

log = logging.getLogger(__name__)

RATE_HZ = 240.0

# survey: the heading's left-right scan about the loop's outward normal (amplitude, period), the
# normal's smoothing over the corners (s), the corners' radius (a fraction of the inset
# rectangle's smaller side). Measured on the survey scenario, seeds 0-7: every marker in view in
# 188 or more of the 1800 frames, from directions spanning 32 deg or more; under 30 deg/s
SURVEY_SCAN_DEG = 35.0
SURVEY_SCAN_S = 10.0
SURVEY_TURN_S = 1.5
SURVEY_CORNER = 0.3


@dataclass
class HeadMotion:
    """A tabulated trajectory.

    Attributes:
        t: (M,) times, s.
        rotations: scipy ``Rotation`` of ``T_world_from_cam`` at those times.
        positions: (M, 3) camera centres, world frame, mm.
    """

    t: np.ndarray
    rotations: Rotation
    positions: np.ndarray

    def __post_init__(self):
        self._slerp = Slerp(self.t, self.rotations)

    def poses(self, t) -> np.ndarray:
        """(N, 4, 4) ``T_world_from_cam`` at times t (N,), clamped to the tabulated span."""
        t = np.clip(np.atleast_1d(np.asarray(t, float)), self.t[0], self.t[-1])
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, :3] = self._slerp(t).as_matrix()
        for i in range(3):
            T[:, i, 3] = np.interp(t, self.t, self.positions[:, i])
        return T


def _smooth_noise(rng, t, n_dims, f_lo=0.05, f_hi=0.6, n_terms=5) -> np.ndarray:
    """(M, n_dims) smooth random signals in [-1, 1] (sums of sinusoids, normalised to peak 1)."""
    out = np.zeros((len(t), n_dims))
    for d in range(n_dims):
        f = rng.uniform(f_lo, f_hi, n_terms)
        ph = rng.uniform(0, 2 * np.pi, n_terms)
        a = rng.uniform(0.5, 1.0, n_terms) / f          # lower frequencies carry more motion
        s = (a[None] * np.sin(2 * np.pi * f[None] * t[:, None] + ph[None])).sum(axis=1)
        out[:, d] = s / max(np.abs(s).max(), 1e-12)
    return out


def _heading(t, gaze_target: Callable[[np.ndarray], np.ndarray], positions, follow: float,
             tau_s: float, forward=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(M, 3) unit headings: ``follow`` of the way from ``forward`` toward the fixated target,
    low-passed with time constant ``tau_s``."""
    fw = np.asarray(forward, float)
    goal = gaze_target(t) - positions
    goal /= np.linalg.norm(goal, axis=1, keepdims=True)
    want = (1 - follow) * fw + follow * goal
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    out = np.empty_like(want)
    out[0] = want[0]
    a = 1 - np.exp(-(t[1] - t[0]) / tau_s)
    for i in range(1, len(t)):
        v = out[i - 1] + a * (want[i] - out[i - 1])
        out[i] = v / np.linalg.norm(v)
    return out


def _assemble(t, positions, headings, extra_rotvec=None) -> HeadMotion:
    R = np.stack([look_at(p, p + h)[:3, :3] for p, h in zip(positions, headings, strict=True)])
    rot = Rotation.from_matrix(R)
    if extra_rotvec is not None:
        rot = rot * Rotation.from_rotvec(extra_rotvec)     # sway in the head's own frame
    return HeadMotion(t, rot, positions)


def make_motion(spec: dict, duration_s: float, rng: np.random.Generator,
                gaze_target: Callable[[np.ndarray], np.ndarray]) -> HeadMotion:
    """Build the head motion of a scenario's ``head`` section (see docs/scenarios.md).

    Args:
        spec: the ``head`` section, defaults filled in.
        duration_s: session length, s.
        rng: seeded generator.
        gaze_target: t (M,) -> (M, 3) the point being fixated (for the heading).
    """
    t = np.arange(int(np.ceil(duration_s * RATE_HZ)) + 2) / RATE_HZ
    start = np.asarray(spec["start_mm"], float)
    kind = spec["motion"]
    log.debug("head motion %s over %g s from %s mm", kind, duration_s, np.round(start, 1).tolist())
    forward = np.asarray(spec["forward"], float)
    forward = forward / np.linalg.norm(forward)
    if kind == "fixed":
        pos = np.tile(start, (len(t), 1))
        return _assemble(t, pos, np.tile(forward, (len(t), 1)))
    if kind == "linear":
        d = np.asarray(spec["translation_mm"], float)
        s = np.clip(t / duration_s, 0, 1)
        pos = start + s[:, None] * d
        return _assemble(t, pos, np.tile(forward, (len(t), 1)))
    amp_mm = float(spec["sway_mm"])
    amp_rad = np.deg2rad(float(spec["sway_deg"]))
    noise = _smooth_noise(rng, t, 6)
    if kind == "survey":
        pos, head = _survey(spec, t, start, amp_mm * noise[:, :3])
        return _assemble(t, pos, head, amp_rad * noise[:, 3:] * np.array([0.6, 1.0, 0.3]))
    if kind == "sway":
        pos = start + amp_mm * noise[:, :3] * np.array([1.0, 0.5, 0.7])
    elif kind == "walk":
        goal = np.asarray(spec["walk_to_mm"], float)
        path = goal - start
        dist = np.linalg.norm(path)
        traveled = np.minimum(t * float(spec["speed_mm_s"]), dist)
        pos = start + traveled[:, None] * path / max(dist, 1e-9)
        bob = 20.0 * np.sin(2 * np.pi * 1.8 * t) * (traveled < dist)
        pos = pos + np.column_stack([0.3 * amp_mm * noise[:, 0], bob, 0.0 * t])
    else:
        raise ValueError(f"unknown head motion {kind!r}")
    head = _heading(t, gaze_target, pos, float(spec["follow"]), 0.35, forward)
    return _assemble(t, pos, head, amp_rad * noise[:, 3:] * np.array([0.6, 1.0, 0.3]))


def survey_loop(walls_mm, inset_mm: float, s_mm) -> tuple[np.ndarray, np.ndarray, float]:
    """The survey's loop: a rectangle with rounded corners, ``inset_mm`` inside the walls.

    Args:
        walls_mm: (left x, back z, right x, front z) of the room's walls, world frame, mm.
        inset_mm: distance of the loop's straight sides from the walls; the corners (radius
            ``SURVEY_CORNER`` of the inset rectangle's smaller side) keep further away.
        s_mm: (M,) arc lengths from the middle of the back side, toward +x (right), then the
            right side toward +z, any real value (laps continue).

    Returns:
        (M, 2) (x, z) points, mm; (M,) angle of the outward normal (x, z) = (cos, sin), rad,
        continuous (one lap adds 2 pi); the loop's length, mm.
    """
    x0, z0, x1, z1 = (float(v) for v in walls_mm)
    a0, b0, a1, b1 = x0 + inset_mm, z0 + inset_mm, x1 - inset_mm, z1 - inset_mm
    if not (a1 > a0 and b1 > b0):
        raise ValueError(f"a survey loop {inset_mm:g} mm inside walls {list(walls_mm)} is empty")
    r = SURVEY_CORNER * min(a1 - a0, b1 - b0)
    xi0, zi0, xi1, zi1 = a0 + r, b0 + r, a1 - r, b1 - r            # the corners' centres
    cx, q = (xi0 + xi1) / 2, np.pi * r / 2
    inner = np.array([(cx, zi0), (xi1, zi0), (xi1, zi0), (xi1, zi1), (xi1, zi1), (xi0, zi1), (xi0, zi1),
                      (xi0, zi0), (xi0, zi0), (cx, zi0)])
    phi = np.pi / 2 * (np.array([0, 0, 1, 1, 2, 2, 3, 3, 4, 4]) - 1)
    knots = np.concatenate([[0.0], np.cumsum([(xi1 - xi0) / 2, q, zi1 - zi0, q, xi1 - xi0, q, zi1 - zi0, q,
                                              (xi1 - xi0) / 2])])
    length = float(knots[-1])
    s = np.asarray(s_mm, float)
    u, laps = np.mod(s, length), np.floor(s / length)
    ang = np.interp(u, knots, phi)
    pts = np.column_stack([np.interp(u, knots, inner[:, 0]), np.interp(u, knots, inner[:, 1])])
    return pts + r * np.column_stack([np.cos(ang), np.sin(ang)]), ang + 2 * np.pi * laps, length


def _survey(spec: dict, t, start, sway_mm) -> tuple[np.ndarray, np.ndarray]:
    """Positions (M, 3) and headings (M, 3) of the survey walk at times t (M,); ``sway_mm`` (M, 3)
    is the smooth random sway (scaled down here: the walk is the motion)."""
    walls = spec.get("survey_walls_mm")
    if walls is None:
        raise ValueError("survey motion needs head.survey_walls_mm (scenario.resolve takes them from the room)")
    inset = float(spec["survey_inset_mm"])
    _, _, length = survey_loop(walls, inset, [0.0])
    grid = np.linspace(0, length, 4000, endpoint=False)
    pts, _, _ = survey_loop(walls, inset, grid)
    s0 = grid[np.argmin(np.linalg.norm(pts - start[[0, 2]], axis=1))]     # nearest the start
    speed = length / float(spec["survey_loop_s"])
    pad = int(4 * SURVEY_TURN_S * RATE_HZ)
    tp = np.arange(-pad, len(t) + pad) / RATE_HZ
    pts, ang, _ = survey_loop(walls, inset, s0 + speed * tp)
    ang = gaussian_filter1d(ang, SURVEY_TURN_S * RATE_HZ)[pad:pad + len(t)]
    pts = pts[pad:pad + len(t)]
    yaw = ang + np.deg2rad(SURVEY_SCAN_DEG) * np.sin(2 * np.pi * t / SURVEY_SCAN_S)
    bob = 10.0 * np.sin(2 * np.pi * 1.2 * t)
    pos = np.column_stack([pts[:, 0], start[1] + bob, pts[:, 1]]) + sway_mm * np.array([0.3, 0.15, 0.3])
    return pos, np.column_stack([np.cos(yaw), 0 * yaw, np.sin(yaw)])
