"""The estimate of one gazed point from its view lines: a fixation's running estimate, a
target's estimate with its confidence and bound (``process``), and ``wearable-gaze estimate``
(view-line CSV in, one estimate per segment out)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimator import (
    BinocularSamples,
    GazeEstimate,
    batch_options,
    cramer_rao_bound,
    density_point_cloud,
    make_estimator,
    near_point_check,
    run_estimator,
)

from ..errors import UserError
from ..formats.atomic import atomic_path
from ..formats.viewlines import read_viewlines_csv
from .types import Target


def running_estimate(samples: BinocularSamples, method: str, sigma_deg: float,
                     chunks: int = 20) -> tuple[GazeEstimate | None, list]:
    """The estimator fed one fixation's samples (N,) in about ``chunks`` chunks, as a live session
    would. Returns the last estimate (None without samples) and the usable ones as (time of the
    chunk's last sample s, estimate) pairs."""
    stream = make_estimator(method, sigma_deg, **batch_options(method, len(samples)))
    bounds = np.unique(np.linspace(0, len(samples), min(chunks + 1, len(samples) + 1)).astype(int))
    e, usable = None, []
    lines = samples.lines()
    for j0, j1 in zip(bounds[:-1], bounds[1:], strict=True):
        e = stream.add(samples.select(slice(j0, j1)))
        if e.ok:                                  # nearer than the eyes fixate: not an answer
            used = lines.sample_index < j1
            e = near_point_check(e, lines.origins_mm[used], lines.directions[used])
        if e.ok:
            usable.append((float(samples.t_s[j1 - 1]), e))
    return e, usable


def radius95_mm(e: GazeEstimate) -> float:
    """The largest semi-axis of the 95 % confidence ellipsoid, mm; NaN without a covariance."""
    if e.covariance_mm2 is None:
        return float("nan")
    return float(e.ellipsoid(0.95).radii_mm.max())


def estimate_target(index: int, samples: BinocularSamples, idx: np.ndarray, fixations, e: GazeEstimate,
                    method: str, sigma_deg: float) -> Target:
    """The target made of the view lines ``samples[idx]`` (fixations ``fixations``) with their
    estimate ``e``: its 95 % semi-axes and the Cramér-Rao bound of those lines at the estimate."""
    pos = e.position_mm if e.ok else np.full(3, np.nan)
    radii = e.ellipsoid(0.95).radii_mm if e.covariance_mm2 is not None else np.full(3, np.nan)
    t = samples.t_s[idx]
    crb = _crb(samples.select(idx), e.position_mm, sigma_deg) if e.ok else None
    return Target(index=index, position_mm=np.asarray(pos, float), covariance_mm2=e.covariance_mm2,
                  axes95_mm=np.asarray(radii, float), status=e.status.value, n_samples=len(idx),
                  t_start=float(t.min()), t_end=float(t.max()),
                  fixations=tuple(int(f) for f in fixations), method=method,
                  crb_mm=float(np.sqrt(np.trace(crb))) if crb is not None else float("nan"), samples=idx)


def _crb(samples: BinocularSamples, point_mm, sigma_deg: float):
    """Cramér-Rao bound (3, 3) of the lines actually used, at the point; None if degenerate."""
    try:
        return cramer_rao_bound(samples.lines().origins_mm, point_mm, sigma_deg)
    except ValueError:
        return None


def _density_path(base: Path, key, n_segments: int) -> Path:
    if n_segments == 1:
        return base
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(key))
    return base.with_name(f"{base.stem}-{safe}{base.suffix}")


def estimate_file(path, method: str = "voxel", sigma_deg: float = 1.0, export_density=None) -> list[dict]:
    """Estimate each segment of a view-line CSV.

    Returns one dict per segment, in order of first appearance: ``segment`` (value or None),
    ``method``, ``status``, ``reason``, ``position_mm`` [x, y, z] or None, ``n_samples``,
    ``n_lines``, ``covariance_mm2`` (3x3 or None), ``ellipsoid95_radii_mm``, ``density_ply``.
    With ``export_density`` (a .ply path) the density of each segment is written there
    (``NAME-SEGMENT.ply`` when there are several segments).
    """
    segments = read_viewlines_csv(path)
    if export_density is not None:
        export_density = Path(export_density)
        if export_density.suffix.lower() != ".ply":
            raise UserError(f"--export-density {export_density}: the file name must end in .ply; give a .ply name")
    out = []
    for seg in segments:
        est, r = run_estimator(seg.samples, method, sigma_deg)
        d = {"segment": seg.key, **r.to_dict()}
        d["density_ply"] = None
        if export_density is not None and getattr(est, "grid", None) is not None:
            target = _density_path(export_density, seg.key, len(segments))
            pc = density_point_cloud(est)
            from estimator._open3d import import_open3d  # noqa: PLC0415
            o3d = import_open3d()
            with atomic_path(target) as tmp:
                if not o3d.t.io.write_point_cloud(str(tmp), pc):
                    raise UserError(f"could not write {target}; check the folder is writable")
            d["density_ply"] = str(target)
        out.append(d)
    return out


def format_table(results: list[dict]) -> str:
    """A readable table of ``estimate_file`` results."""
    head = (f"{'segment':>10} {'method':>9} {'status':>17} {'x mm':>9} {'y mm':>9} {'z mm':>9} {'95% radii mm':>22} "
            f"{'samples':>8}")
    rows = [head, "-" * len(head)]
    for r in results:
        seg = "-" if r["segment"] is None else str(r["segment"])
        if r["position_mm"] is None:
            rows.append(f"{seg:>10} {r['method']:>9} {r['status']:>17} {r['reason']}")
            continue
        x, y, z = r["position_mm"]
        radii = r["ellipsoid95_radii_mm"]
        rad = "-" if radii is None else " ".join(f"{v:.1f}" for v in np.sort(radii))
        rows.append(f"{seg:>10} {r['method']:>9} {r['status']:>17} {x:>9.1f} {y:>9.1f} {z:>9.1f} {rad:>22} "
                    f"{r['n_samples']:>8}")
        if r.get("density_ply"):
            rows.append(f"{'':>10} density written to {r['density_ply']}")
    return "\n".join(rows)
