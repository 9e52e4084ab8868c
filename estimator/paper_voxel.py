"""The paper's stochastic voxel method (``paper``, Mitsugami et al. section 5) as written: an LSE
seed from the first samples; a fixed, axis-aligned cubic voxel space around it; per sample the
Gaussian sphere around ``P_n`` (the point nearest the two lines) times each eye's Gaussian cone,
added (or, as an option, multiplied) into the space; re-centring by ``d/2`` when the maximum
leaves the central half (density shifted out is dropped, as in the paper); the estimate is the
best voxel's centre.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .grid import DensityGrid
from .lines import BinocularSample, BinocularSamples
from .result import GazeEstimate, Status, failed
from .samplebuffer import _as_samples
from .triangulation import PairStatus, closest_point_two_lines, lse_point

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PaperVoxelConfig:
    """Settings of the paper's stochastic voxel method (``paper``); the paper leaves all open.

    Attributes:
        sigma_deg: cone width: angular std of each view line, degrees.
        voxel_mm: voxel edge, mm (the paper's estimates come in 10 mm steps).
        grid_size: voxels per axis of the cubic voxel space.
        seed_samples: binocular samples whose lines seed the LSE (the paper: "several").
        sphere_sigma_mm: std of the Gaussian sphere around ``P_n``, mm; ``None`` takes each
            pair's own triangulation depth uncertainty, ``sqrt(2) r^2 sigma / b`` (``r`` the
            distance of ``P_n``, ``b`` the eyes' separation), at least one voxel. The sphere is
            unnormalised (peak 1): normalising it would weight near pairs by ``r^-6``.
        update: ``add`` (densities summed: the paper's "integration") or ``multiply``
            (log-densities summed; a floor keeps one stray sample from zeroing a voxel).
    """

    sigma_deg: float = 1.0
    voxel_mm: float = 10.0
    grid_size: int = 32
    seed_samples: int = 20
    sphere_sigma_mm: float | None = None
    update: str = "add"

    def __post_init__(self) -> None:
        if not self.sigma_deg > 0 or not self.voxel_mm > 0:
            raise ValueError("sigma_deg and voxel_mm must be positive")
        if self.update not in ("add", "multiply"):
            raise ValueError(f"update must be 'add' or 'multiply', got {self.update!r}")
        if self.grid_size < 4 or self.seed_samples < 1:
            raise ValueError("grid_size must be at least 4 and seed_samples at least 1")


class PaperVoxelEstimator:
    """The paper's stochastic voxel method (method ``paper``), streaming with ``update``."""

    method = "paper"

    def __init__(self, config: PaperVoxelConfig = PaperVoxelConfig()):
        self.config = config
        self._sigma = np.deg2rad(config.sigma_deg)
        self._pending: list[BinocularSamples] = []
        self.grid: DensityGrid | None = None
        self.n_samples = 0
        self.n_lines = 0
        self.shifts = 0
        self._last: GazeEstimate | None = None

    def update(self, sample: BinocularSample) -> GazeEstimate:
        """Add one binocular sample (world frame) and return the current estimate."""
        return self.add(_as_samples(sample))

    def add(self, samples: BinocularSamples) -> GazeEstimate:
        """Add samples one after another (the method is sequential) and return the last estimate."""
        cfg = self.config
        for i in range(len(samples)):
            s = samples.select(slice(i, i + 1))
            self.n_samples += 1
            self.n_lines += int(s.left_valid[0]) + int(s.right_valid[0])
            if self.grid is None:
                self._pending.append(s)
                if len(self._pending) < cfg.seed_samples:
                    continue
                if not self._seed():
                    continue
            else:
                self._update_one(s)
            self._recenter()
        self._last = self._result()
        return self._last

    def estimate(self) -> GazeEstimate:
        return self._last if self._last is not None else failed(self.method, Status.INSUFFICIENT,
                                                                "no samples yet", 0, 0)

    def _seed(self) -> bool:
        pend = self._pending
        allv = BinocularSamples.concatenate(pend)
        seed = lse_point(allv.lines())
        if not seed.ok or seed.position_mm is None:     # (ok: never None)
            return False
        c = self.config
        # snap the space so that voxel centres sit on multiples of voxel_mm, as the paper's
        # estimates do (1010, 2010, ...)
        half = 0.5 * c.voxel_mm if c.grid_size % 2 == 0 else 0.0
        center = np.round((seed.position_mm - half) / c.voxel_mm) * c.voxel_mm + half
        self.grid = DensityGrid(center, np.eye(3), c.voxel_mm, c.grid_size)
        log.debug("paper: voxel space of %d^3 x %g mm centred on the LSE seed %s mm", c.grid_size, c.voxel_mm,
                  center.round(1).tolist())
        for p in pend:
            self._update_one(p)
            self._recenter()
        self._pending = []
        return True

    @property
    def _seeded_grid(self) -> DensityGrid:
        """The voxel space, laid once the seed is (``_seed``)."""
        assert self.grid is not None
        return self.grid

    def _update_one(self, s: BinocularSamples) -> None:
        c, g = self.config, self._seeded_grid
        if not (s.left_valid[0] and s.right_valid[0]):
            return                                   # the method needs both lines for P_n
        pair = closest_point_two_lines(s.left_origin_mm, s.left_direction, s.right_origin_mm, s.right_direction)
        if pair.status[0] == PairStatus.PARALLEL:   # no P_n
            return
        P = pair.point_mm[0]
        if c.sphere_sigma_mm is None:
            mid = 0.5 * (s.left_origin_mm[0] + s.right_origin_mm[0])
            base = max(np.linalg.norm(s.left_origin_mm[0] - s.right_origin_mm[0]), 1.0)
            r = np.linalg.norm(P - mid)
            sig_s = max(np.sqrt(2.0) * r * r * self._sigma / base, c.voxel_mm)
        else:
            sig_s = c.sphere_sigma_mm
        sphere = np.exp(-0.5 * g.sq_distance_to(P) / sig_s**2)
        cones = np.exp((-0.5 / self._sigma**2) * g.tan2_of_lines(
            np.vstack([s.left_origin_mm, s.right_origin_mm]), np.vstack([s.left_direction, s.right_direction])))
        contribution = sphere * (cones[0] + cones[1]).reshape(sphere.shape)
        if c.update == "add":
            g.values += contribution
        else:
            g.values += np.log(contribution + 1e-12 * contribution.max() + 1e-300)

    def _recenter(self) -> None:
        g = self._seeded_grid
        idx = g.argmax()
        d = (idx - (g.n - 1) / 2.0)                       # voxels from the centre to P_M
        if np.all(np.abs(d) <= g.n / 4):
            return
        shift = np.round(d / 2).astype(int)               # translate the space by d/2
        self.shifts += 1
        fill = 0.0 if self.config.update == "add" else float(g.values.min())
        new = np.full_like(g.values, fill)
        src = [slice(max(s, 0), g.n + min(s, 0)) for s in shift]
        dst = [slice(max(-s, 0), g.n + min(-s, 0)) for s in shift]
        new[tuple(dst)] = g.values[tuple(src)]
        g.values[:] = new
        g.center_mm = g.center_mm + shift * g.spacing_mm
        log.debug("paper: voxel space moved by %s voxels to %s mm", shift.tolist(), g.center_mm.round(1).tolist())

    def _result(self) -> GazeEstimate:
        if self.grid is None:
            return failed(self.method, Status.INSUFFICIENT,
                          f"gathering samples for the LSE seed: {len(self._pending)} of {self.config.seed_samples}",
                          self.n_samples, self.n_lines)
        g = self.grid
        if not np.any(g.values != g.values.flat[0]):
            return failed(self.method, Status.INSUFFICIENT, "no density yet", self.n_samples, self.n_lines)
        point = g.index_to_world(g.argmax())[0]
        info = {"voxel_mm": self.config.voxel_mm, "shifts": self.shifts, "center_mm": g.center_mm.tolist()}
        return GazeEstimate(self.method, Status.OK, point, None, self.n_samples, self.n_lines, "", info)
