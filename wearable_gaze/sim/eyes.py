"""The binocular eye tracker: eye rotation centres, a nonlinear sensor per eye, gaze behaviour
over time (fixations, saccades, smooth pursuit, blinks) and the raw (x, y) it reports.

Sensor model (per eye). The eye's view direction ``d`` in the scene-camera frame is written as
its tangent point ``p = (d_x / d_z, d_y / d_z)`` (the point it meets on a plane one unit in
front of the eye). The sensor reports, in counts,

    raw = offset + A (p + Q m(p) + c |p|^2 p),    m(p) = (p_x^2, p_x p_y, p_y^2)

with ``A`` a 2x2 gain and small rotation, ``Q`` a (2, 3) quadratic and ``c`` a cubic term. A point
on a wall is affine in ``p``, so the paper's second-order calibration (eq. 1-2) inverts the
quadratic part exactly and leaves the cubic part (~0.1 deg over +-25 deg): nearly, not exactly,
right. Angular noise (Gaussian, sigma per tangent axis) and an optional per-eye bias are applied
to the direction before the sensor.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from estimator import perturb_directions
from estimator.deprecation import renamed_kwargs
from estimator.frames import rotation_about_axis

log = logging.getLogger(__name__)

BLINK_S = 0.15
SACCADE_S = 0.045


@dataclass
class EyeSensor:
    """One eye's sensor response (see the module docstring).

    Attributes:
        offset: (2,) counts.
        A: (2, 2) counts per unit tangent.
        Q: (2, 3) quadratic coefficients (dimensionless).
        cubic: cubic coefficient (dimensionless).
    """

    offset: np.ndarray
    A: np.ndarray
    Q: np.ndarray
    cubic: float

    @classmethod
    def random(cls, rng: np.random.Generator) -> EyeSensor:
        g = rng.uniform(900, 1100, 2)
        a = np.deg2rad(rng.uniform(-3, 3))
        A = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ np.diag(g)
        return cls(rng.uniform(-60, 60, 2) + 2048.0, A, rng.uniform(-0.06, 0.06, (2, 3)),
                   float(rng.uniform(-0.05, -0.03)))

    def raw_from_tangent(self, p) -> np.ndarray:
        """(N, 2) raw counts of tangent points (N, 2)."""
        p = np.asarray(p, float).reshape(-1, 2)
        m = np.column_stack([p[:, 0] ** 2, p[:, 0] * p[:, 1], p[:, 1] ** 2])
        q = p + m @ self.Q.T + self.cubic * (p ** 2).sum(axis=1, keepdims=True) * p
        return self.offset + q @ self.A.T

    def raw_from_direction(self, d) -> np.ndarray:
        """(N, 2) raw counts of view directions (N, 3), scene-camera frame (d_z > 0)."""
        d = np.asarray(d, float).reshape(-1, 3)
        return self.raw_from_tangent(d[:, :2] / d[:, 2:3])

    def tangent_from_raw(self, raw, iterations: int = 20) -> np.ndarray:
        """The exact inverse (Newton): (N, 2) tangent points of raw counts (N, 2)."""
        raw = np.asarray(raw, float).reshape(-1, 2)
        target = np.linalg.solve(self.A, (raw - self.offset).T).T
        p = target.copy()
        for _ in range(iterations):
            x, y = p[:, 0], p[:, 1]
            r2 = x * x + y * y
            m = np.column_stack([x * x, x * y, y * y])
            f = p + m @ self.Q.T + self.cubic * r2[:, None] * p - target
            # Jacobian of p + Q m(p) + c r2 p
            dm_dx = np.column_stack([2 * x, y, 0 * x])
            dm_dy = np.column_stack([0 * x, x, 2 * y])
            J = np.empty((len(p), 2, 2))
            J[:, :, 0] = dm_dx @ self.Q.T + self.cubic * (2 * x[:, None] * p)
            J[:, :, 1] = dm_dy @ self.Q.T + self.cubic * (2 * y[:, None] * p)
            J[:, 0, 0] += 1 + self.cubic * r2
            J[:, 1, 1] += 1 + self.cubic * r2
            p = p - np.linalg.solve(J, f[..., None])[..., 0]
        return p

    def direction_from_raw(self, raw) -> np.ndarray:
        """(N, 3) unit view directions, scene-camera frame, of raw counts (N, 2)."""
        p = self.tangent_from_raw(raw)
        d = np.column_stack([p, np.ones(len(p))])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def to_dict(self) -> dict:
        return {"offset": self.offset.tolist(), "A": self.A.tolist(), "Q": self.Q.tolist(), "cubic": self.cubic}

    @classmethod
    def from_dict(cls, d: dict) -> EyeSensor:
        return cls(np.asarray(d["offset"], float), np.asarray(d["A"], float), np.asarray(d["Q"], float),
                   float(d["cubic"]))


@renamed_kwargs({"centres": "centers"})
@dataclass
class EyeModel:
    """Both eyes: rotation centres in the scene-camera frame, sensors, noise and bias.

    Attributes:
        centers: (2, 3) left and right eye rotation centres, scene-camera frame, mm (the
            left eye at negative x).
        sensors: (left, right) ``EyeSensor``.
        sigma_deg: angular noise per tangent axis, degrees.
        bias_deg: (2, 2) per eye a fixed (horizontal, vertical) rotation of the view direction,
            degrees, applied in the session but not during calibration (a headset that slipped,
            or a person's systematic offset the calibration did not see).
    """

    centers: np.ndarray
    sensors: tuple
    sigma_deg: float = 1.0
    bias_deg: np.ndarray = None

    @classmethod
    @renamed_kwargs({"centre_offset_mm": "center_offset_mm"})
    def make(cls, rng: np.random.Generator, ipd_mm: float = 64.0, center_offset_mm=(0.0, 30.0, -20.0),
             sigma_deg: float = 1.0, bias_deg=None) -> EyeModel:
        off = np.asarray(center_offset_mm, float)
        centers = np.array([[-ipd_mm / 2, 0, 0], [ipd_mm / 2, 0, 0]]) + off
        bias = np.zeros((2, 2)) if bias_deg is None else np.asarray(bias_deg, float).reshape(2, 2)
        return cls(centers, (EyeSensor.random(rng), EyeSensor.random(rng)), float(sigma_deg), bias)

    def measure(self, gaze_cam, rng: np.random.Generator, with_bias: bool = True):
        """Raw readings of both eyes looking at points.

        Args:
            gaze_cam: (N, 3) gazed points, scene-camera frame, mm.
            rng: noise generator.
            with_bias: apply ``bias_deg`` (off during calibration).

        Returns:
            raw: (N, 2, 2) counts, [sample, eye (left, right), (x, y)].
            true_dirs: (N, 2, 3) exact unit directions, camera frame.
            noisy_dirs: (N, 2, 3) the directions the sensor encoded (noise and bias applied).
        """
        gaze_cam = np.asarray(gaze_cam, float).reshape(-1, 3)
        n = len(gaze_cam)
        raw = np.empty((n, 2, 2))
        true = np.empty((n, 2, 3))
        noisy = np.empty((n, 2, 3))
        for e in range(2):
            d = gaze_cam - self.centers[e]
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            true[:, e] = d
            m = d
            if with_bias and np.any(self.bias_deg[e] != 0):
                h, v = np.deg2rad(self.bias_deg[e])
                R = rotation_about_axis([0, 1, 0], h) @ rotation_about_axis([1, 0, 0], -v)
                m = m @ R.T
            if self.sigma_deg > 0:
                m = perturb_directions(m, np.deg2rad(self.sigma_deg), rng)
            noisy[:, e] = m
            raw[:, e] = self.sensors[e].raw_from_direction(m)
        return raw, true, noisy

    def to_dict(self) -> dict:
        return {"centres_mm": self.centers.tolist(), "sigma_deg": self.sigma_deg,
                "bias_deg": self.bias_deg.tolist(),
                "sensors": [s.to_dict() for s in self.sensors]}


@dataclass
class GazePlan:
    """What the eyes do at each eye-sample time.

    Attributes:
        target: (N,) index of the fixated or pursued target, -1 in saccades.
        phase: (N,) 'fixation', 'pursuit', 'saccade' or 'blink'.
        valid: (N, 2) per eye whether the sensor gave a reading (blinks and dropouts are not).
    """

    target: np.ndarray
    phase: np.ndarray
    valid: np.ndarray


def plan_gaze(t, n_targets: int, moving, rng: np.random.Generator, fixation_s=(2.0, 4.0),
              blink_rate_hz: float = 0.2, dropout_rate: float = 0.01, order: str = "cycle") -> GazePlan:
    """Fixations on targets in turn with saccades between, pursuit of moving targets, blinks and
    short one-eye dropouts.

    Args:
        t: (N,) eye-sample times, s, increasing.
        n_targets: number of targets.
        moving: (n_targets,) bool, targets that move (followed by smooth pursuit).
        fixation_s: (min, max) dwell on a target, s.
        blink_rate_hz: mean blink rate (Poisson), each ``BLINK_S`` long.
        dropout_rate: per-eye probability per sample of a 1-3 sample dropout starting.
        order: 'cycle' (targets in order, repeated) or 'random'.
    """
    t = np.asarray(t, float)
    n = len(t)
    target = np.full(n, -1)
    phase = np.full(n, "saccade", dtype=object)
    start, k = t[0], 0
    seq = []
    while start <= t[-1]:
        idx = (k % n_targets) if order == "cycle" else int(rng.integers(n_targets))
        if order != "cycle" and seq and idx == seq[-1] and n_targets > 1:
            idx = (idx + 1) % n_targets
        seq.append(idx)
        dwell = rng.uniform(*fixation_s)
        fix_start = start + (SACCADE_S if k > 0 else 0.0)
        sel = (t >= fix_start) & (t < start + dwell)
        target[sel] = idx
        phase[sel] = "pursuit" if moving[idx] else "fixation"
        start += dwell
        k += 1
    # saccade samples take the next target's index for their gaze point, marked -1 for segments
    valid = np.ones((n, 2), bool)
    tb = t[0] + rng.exponential(1 / blink_rate_hz) if blink_rate_hz > 0 else np.inf
    while tb < t[-1]:
        sel = (t >= tb) & (t < tb + BLINK_S)
        valid[sel] = False
        phase[sel] = "blink"
        tb += BLINK_S + rng.exponential(1 / blink_rate_hz)
    for e in range(2):
        starts = np.flatnonzero(rng.random(n) < dropout_rate)
        for s in starts:
            valid[s:s + int(rng.integers(1, 4)), e] = False
    log.debug("gaze plan: %d fixations over %d samples, %d samples in blinks, %d eye samples lost", len(seq), n,
              int(np.sum(phase == "blink")), int(np.sum(~valid)))
    return GazePlan(target, phase.astype(str), valid)


def gaze_points(t, plan: GazePlan, targets, pursuit_lag_s: float = 0.08) -> np.ndarray:
    """(N, 3) world points the eyes converge on: the fixated target (a moving one with the
    pursuit lag), and in saccades a straight sweep from the previous target to the next."""
    t = np.asarray(t, float)
    n = len(t)
    out = np.empty((n, 3))
    idx = plan.target
    for k, tg in enumerate(targets):
        sel = idx == k
        if sel.any():
            out[sel] = tg.path(t[sel] - (pursuit_lag_s if tg.moving else 0.0))
    # saccades: interpolate between the last and next fixated points
    sac = np.flatnonzero(idx < 0)
    if len(sac):
        known = np.flatnonzero(idx >= 0)
        for j in sac:
            before = known[known < j]
            after = known[known > j]
            a = out[before[-1]] if len(before) else (out[after[0]] if len(after) else np.zeros(3))
            b = out[after[0]] if len(after) else a
            ta = t[before[-1]] if len(before) else t[j]
            tb = t[after[0]] if len(after) else t[j]
            w = 0.5 if tb <= ta else (t[j] - ta) / (tb - ta)
            out[j] = (1 - w) * a + w * b
    return out
