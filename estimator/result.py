"""The result every estimator returns: a point with its uncertainty, or an explicit failure."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

from .errormodel_regions import Sight

if TYPE_CHECKING:
    from .direction import GazeDirection


class Status(str, Enum):
    """Why an estimate is (or is not) usable."""

    OK = "ok"
    INSUFFICIENT = "insufficient-data"   # too few lines or samples yet
    DEGENERATE = "degenerate"            # lines (nearly) parallel: the point is not determined
    BEHIND = "behind"                    # the best point lies behind the eyes
    TOO_NEAR = "too-near"                # nearer the eyes than anyone can fixate: the lines are wrong
    DIRECTION_ONLY = "direction-only"    # the lines fix a direction (with its cone), not a point: ``direction``


@dataclass(frozen=True)
class Ellipsoid:
    """A confidence or credible ellipsoid.

    Attributes:
        center_mm: (3,) centre, mm.
        radii_mm: (3,) semi-axis lengths, mm, ascending.
        axes: (3, 3) unit semi-axis directions as columns, matching ``radii_mm``.
        probability: the probability mass it holds (e.g. 0.95).
    """

    center_mm: np.ndarray
    radii_mm: np.ndarray
    axes: np.ndarray
    probability: float


@dataclass(frozen=True)
class GazeEstimate:
    """A 3D gazed-point estimate.

    Attributes:
        method: estimator name (``lse``, ``geometric``, ``ml``, ``voxel``, ``paper``).
        status: ``Status.OK`` or the reason there is no usable point.
        position_mm: (3,) the estimate in the lines' frame, mm; ``None`` unless a point was found.
        covariance_mm2: (3, 3) covariance, mm^2, where the method gives one, else ``None``.
        n_samples: binocular samples used.
        n_lines: view lines used.
        reason: a sentence for people when ``status`` is not OK (empty otherwise).
        info: method-specific diagnostics (iterations, residual RMS in degrees, voxel size...).
        direction: with ``Status.DIRECTION_ONLY``, where the lines looked
            (``estimator.direction.GazeDirection``: the cyclopean direction, its 95 % cone and the
            depth interval, which may have no far end); None otherwise.
    """

    method: str
    status: Status
    position_mm: np.ndarray | None
    covariance_mm2: np.ndarray | None
    n_samples: int
    n_lines: int
    reason: str = ""
    info: dict = field(default_factory=dict)
    direction: GazeDirection | None = None

    @property
    def ok(self) -> bool:
        return self.status is Status.OK

    def ellipsoid(self, probability: float = 0.95) -> Ellipsoid | None:
        """The ``probability`` region: the ellipsoid of ``N(position, covariance)``, or, when the
        error model shaped the covariance (its far side, ``estimator.errormodel.at_level``), that
        level's own. None without a covariance."""
        C = self.level_covariance(probability)
        if C is None or self.position_mm is None:   # (C is None without a point)
            return None
        return covariance_ellipsoid(self.position_mm, C, probability)

    def sight(self) -> Sight | None:
        """Where its lines were seen from and how the error model shaped its covariance
        (``estimator.errormodel.Sight``) when the error model gave it; None otherwise."""
        return Sight.from_info(self.info.get("error_model")) if self.ok else None

    def level_covariance(self, probability: float) -> np.ndarray | None:
        """(3, 3) mm^2: the covariance whose ``probability`` ellipsoid is the region of that level
        (``covariance_mm2`` itself without the error model's far side); None without one."""
        if self.position_mm is None or self.covariance_mm2 is None:
            return None
        sight = Sight.from_info(self.info.get("error_model"))
        if sight is None:
            return self.covariance_mm2
        return sight.level_covariance(self.covariance_mm2, self.position_mm, probability)

    def depth_interval(self, probability: float = 0.95) -> tuple[float, float]:
        """(near, far) mm: the ``probability`` interval of the point's distance from where its
        lines were seen (their mean origin), symmetric in inverse depth; far is ``inf`` when it
        has no far end. (NaN, NaN) without the error model's covariance."""
        sight = Sight.from_info(self.info.get("error_model"))
        if self.position_mm is None or self.covariance_mm2 is None or sight is None:
            return float("nan"), float("nan")
        return sight.depth_interval(self.position_mm, probability)

    def to_dict(self) -> dict:
        """JSON-ready dict (lists, not arrays); ``direction`` (``GazeDirection.to_dict``) only
        when the estimate has one."""
        ell = self.ellipsoid()
        out = {
            "method": self.method,
            "status": self.status.value,
            "reason": self.reason,
            "position_mm": None if self.position_mm is None else [float(v) for v in self.position_mm],
            "covariance_mm2": None if self.covariance_mm2 is None else self.covariance_mm2.tolist(),
            "ellipsoid95_radii_mm": None if ell is None else ell.radii_mm.tolist(),
            "n_samples": int(self.n_samples),
            "n_lines": int(self.n_lines),
        }
        if self.direction is not None:
            out["direction"] = self.direction.to_dict()
        return out


def failed(method: str, status: Status, reason: str, n_samples: int, n_lines: int,
           info: dict | None = None) -> GazeEstimate:
    """A ``GazeEstimate`` with no point and a reason."""
    return GazeEstimate(method, status, None, None, n_samples, n_lines, reason, info or {})


@functools.lru_cache(maxsize=16)
def _chi2_3(probability: float) -> float:
    """The chi-square quantile at ``probability`` for 3 degrees of freedom (scipy's ``ppf`` takes
    about 0.3 ms a call: the live loop asks once a sample for the same few probabilities)."""
    return float(chi2.ppf(probability, df=3))


def covariance_ellipsoid(center_mm: ArrayLike, covariance_mm2: ArrayLike, probability: float = 0.95) -> Ellipsoid:
    """Ellipsoid holding ``probability`` of ``N(center, covariance)`` (3 degrees of freedom)."""
    C = np.asarray(covariance_mm2, dtype=np.float64)
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    k2 = _chi2_3(float(probability))
    return Ellipsoid(np.asarray(center_mm, float), np.sqrt(np.clip(w, 0, None) * k2), V, probability)


NEAR_POINT_MM = 70.0
"""The nearest distance from the eyes at which a person can fixate (the near point of
convergence is 5-10 cm in adults; Scheiman & Wick, Clinical Management of Binocular Vision):
an estimate nearer than this, or behind the eyes, comes from wrong view lines (an eye model not
fitted, optical instead of visual axes, swapped eyes), not from a gazed object."""


ONE_VIEWPOINT_MM = 12.0
"""View lines whose origins all lie within this distance of their mean were seen from one place:
one eye's lines from a still head (a fixation the other eye lost). An eye model's centre moves by
a millimetre or so as the eye turns, within the eyeball (radius about 12 mm: axial length 24 mm,
Bekerman et al. 2014, Variations in eyeball diameters of the healthy adults); that motion is all
the parallax such lines have, so where they meet says nothing about the scene or the lines, near or
far: ``near_point_check`` answers any point of such lines as lines that fix no point
(``Status.DEGENERATE``, then answered by their direction), and a near one not as wrong lines
(``Status.TOO_NEAR``)."""


def origin_spread_mm(origins_mm: np.ndarray) -> float:
    """The largest distance, mm, of the view lines' origins (N, 3) mm (N >= 1) from their mean;
    under ``ONE_VIEWPOINT_MM`` they were seen from one place."""
    return float(np.max(np.linalg.norm(origins_mm - origins_mm.mean(axis=0), axis=1)))


def near_point_check(e: GazeEstimate, origins_mm: np.ndarray, directions: np.ndarray,
                     near_mm: float = NEAR_POINT_MM) -> GazeEstimate:
    """``e`` unchanged, or, when its point lies less than ``near_mm`` in front of the view lines'
    origins (median over the lines of the distance along each line), the same estimate marked
    ``Status.TOO_NEAR`` (not usable) with the reason; or, when those lines come from one place
    (``ONE_VIEWPOINT_MM``), a failed estimate (``Status.DEGENERATE``: no point) saying so, wherever
    the point lies: such lines fix no depth, near or far (their crossing is the eye's own motion
    and the noise); and the same when the near point lies within ``ONE_VIEWPOINT_MM`` of most
    lines' origins (the centre of the eye they come from, where one eye's lines all meet: a
    fixation of mostly one eye's lines with a few of the other's that do not fit them).

    Args:
        e: an estimate.
        origins_mm, directions: (N, 3) the lines it came from (eye centres, unit directions).
    """
    if not e.ok or e.position_mm is None or len(origins_mm) == 0:
        return e
    along = np.einsum("ij,ij->i", np.asarray(e.position_mm, float) - origins_mm, directions)
    d = float(np.median(along))
    spread = origin_spread_mm(origins_mm)
    if spread < ONE_VIEWPOINT_MM:
        return failed(e.method, Status.DEGENERATE,
                      f"the lines meet {d:.0f} mm in front of the eyes, but they were seen from one place "
                      f"(origins within {spread:.1f} mm: one eye, a still head): no parallax fixes a depth",
                      e.n_samples, e.n_lines, e.info)
    if d >= near_mm:
        return e
    apex = float(np.median(np.linalg.norm(origins_mm - np.asarray(e.position_mm, float), axis=1)))
    if apex < ONE_VIEWPOINT_MM:         # most lines' own eye centre: where one eye's lines all meet
        return failed(e.method, Status.DEGENERATE,
                      f"the lines meet at the eye most of them come from ({apex:.1f} mm from their origins): "
                      "one eye's lines from a still head fix no depth, and the other eye's few do not fit them",
                      e.n_samples, e.n_lines, e.info)
    return GazeEstimate(e.method, Status.TOO_NEAR, e.position_mm, e.covariance_mm2, e.n_samples, e.n_lines,
                        f"the point lies {d:.0f} mm in front of the eyes, nearer than anyone fixates ({near_mm:g} mm): "
                        "the view lines are wrong (eye model, visual axes or eye labels)", e.info)
