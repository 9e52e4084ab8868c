"""``wearable-gaze estimate``: view-line CSV in, one estimate per segment out."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimator import density_point_cloud, run_estimator

from ..errors import UserError
from ..formats.atomic import atomic_path
from ..formats.viewlines import read_viewlines_csv


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
