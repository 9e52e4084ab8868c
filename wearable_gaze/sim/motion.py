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
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .world import look_at

log = logging.getLogger(__name__)

RATE_HZ = 240.0


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
    if kind == "sway":
        pos = start + amp_mm * noise[:, :3] * np.array([1.0, 0.5, 0.7])
    elif kind == "walk":
        goal = np.asarray(spec["walk_to_mm"], float)
        path = goal - start
        dist = np.linalg.norm(path)
        travelled = np.minimum(t * float(spec["speed_mm_s"]), dist)
        pos = start + travelled[:, None] * path / max(dist, 1e-9)
        bob = 20.0 * np.sin(2 * np.pi * 1.8 * t) * (travelled < dist)
        pos = pos + np.column_stack([0.3 * amp_mm * noise[:, 0], bob, 0.0 * t])
    else:
        raise ValueError(f"unknown head motion {kind!r}")
    head = _heading(t, gaze_target, pos, float(spec["follow"]), 0.35, forward)
    return _assemble(t, pos, head, amp_rad * noise[:, 3:] * np.array([0.6, 1.0, 0.3]))
