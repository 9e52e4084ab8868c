"""The paper's simulation protocol (section 6.1) and related synthetic view-line sets.

The head translates 200 mm to the right along the world x axis (from x = -100 to +99 mm), one
binocular sample per millimetre (200 samples); the eyes sit 32.5 mm either side of the head
centre (65 mm inter-pupil distance); the gazed point is (0, 0, Z); each view line has Gaussian
angular noise of 1 degree per tangent axis. World frame, mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator import BinocularSample, BinocularSamples, perturb_directions

PAPER_DEPTHS_MM = (1000.0, 2000.0, 3000.0, 4000.0, 5000.0)

# The paper's Table 1 (mm): true Z -> (proposed estimate, error, LSE estimate, error).
PAPER_TABLE1 = {
    1000: ((0, 0, 1010), 10, (5, 1, 951), 49),
    2000: ((0, 0, 2010), 10, (18, 5, 1653), 348),
    3000: ((0, 0, 3010), 10, (33, 11, 2031), 967),
    4000: ((0, 0, 3980), 20, (47, 16, 2156), 1844),
    5000: ((0, 0, 5010), 10, (58, 21, 2128), 2873),
}


@dataclass(frozen=True)
class Protocol:
    """A head path and eye geometry: the paper's defaults."""

    n_samples: int = 200
    step_mm: float = 1.0
    ipd_mm: float = 65.0
    sigma_deg: float = 1.0
    rate_hz: float = 30.0


def head_path(protocol: Protocol = Protocol()) -> np.ndarray:
    """Head centres (N, 3), world frame, mm: a straight translation to the right, centred on x=0."""
    x = (np.arange(protocol.n_samples) - protocol.n_samples // 2) * protocol.step_mm
    return np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])


def simulate_lines(target_mm, rng: np.random.Generator, protocol: Protocol = Protocol(),
                   heads_mm=None) -> BinocularSamples:
    """Noisy binocular view lines toward a fixed target (3,), world frame, mm.

    Args:
        target_mm: (3,) gazed point.
        rng: seeded generator.
        protocol: geometry and noise.
        heads_mm: optional (N, 3) head centres (default: the paper's translation); the eyes sit
            at +-ipd/2 along world x.
    """
    heads = head_path(protocol) if heads_mm is None else np.asarray(heads_mm, float)
    half = np.array([protocol.ipd_mm / 2, 0.0, 0.0])
    lo, ro = heads - half, heads + half
    X = np.asarray(target_mm, float)
    sig = np.deg2rad(protocol.sigma_deg)
    ld = perturb_directions(X - lo, sig, rng)
    rd = perturb_directions(X - ro, sig, rng)
    t = np.arange(len(heads)) / protocol.rate_hz
    return BinocularSamples.from_arrays(t, lo, ld, ro, rd)


def still_head_samples(n: int, rng: np.random.Generator, diverge_deg: float = 1.0, depth_mm: float = 5000.0,
                       sigma_deg: float = 1.0, ipd_mm: float = 65.0) -> list:
    """View lines that fix no point ahead: a still head (eyes at (+-ipd/2, 0, 0) mm, world frame)
    looking at (0, 0, ``depth_mm``) with the two eyes' lines turned apart by ``diverge_deg``
    (0: both straight ahead, parallel: a target at infinity), each with Gaussian angular noise of
    ``sigma_deg`` per tangent axis. Returns ``n`` ``BinocularSample``s at 60 Hz."""
    lo, ro = np.array([-ipd_mm / 2, 0, 0]), np.array([ipd_mm / 2, 0, 0])
    X = np.array([0, 0, depth_mm])
    half = np.deg2rad(diverge_deg) / 2

    def turn(v, a):
        return np.array([np.cos(a) * v[0] + np.sin(a) * v[2], v[1], -np.sin(a) * v[0] + np.cos(a) * v[2]])

    dl = turn((X - lo) / np.linalg.norm(X - lo), -half)
    dr = turn((X - ro) / np.linalg.norm(X - ro), half)
    if diverge_deg == 0:
        dl = dr = np.array([0, 0, 1.0])
    sigma_rad = np.deg2rad(sigma_deg)
    left_dirs = perturb_directions(np.tile(dl, (n, 1)), sigma_rad, rng)
    right_dirs = perturb_directions(np.tile(dr, (n, 1)), sigma_rad, rng)
    return [BinocularSample(i / 60, lo, left_dirs[i], ro, right_dirs[i]) for i in range(n)]
