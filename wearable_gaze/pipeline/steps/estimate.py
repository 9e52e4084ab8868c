"""The estimate of one gazed point from its view lines: a fixation's running estimate, a
target's estimate with its confidence and bound (``process``), and ``wearable-gaze estimate``
(view-line CSV in, one estimate per segment out)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimator import (
    BinocularSamples,
    GazeEstimate,
    PooledEstimate,
    batch_options,
    cramer_rao_bound,
    density_point_cloud,
    make_estimator,
    near_point_check,
    run_estimator,
)
from estimator.direction import GazeDirection, gaze_direction, point_direction, with_direction
from estimator.errormodel import ErrorModel
from estimator.merge import MERGE_POSE_DEG, TargetMerger

from ...errors import UserError
from ...formats.atomic import atomic_path
from ...formats.viewlines import read_viewlines_csv
from ..types import Target
from .segmentation import NO_FIXATION, measured_rate_hz, read_in_time_order, segment_config, segment_view_lines
from .target_status import OK, UNRESOLVED, estimate_status, target_status  # noqa: F401  (their home: target_status)

DEFAULT_ERROR_MODEL = ErrorModel(pose_offset_deg=MERGE_POSE_DEG)
"""The error model of ``estimate`` and of the live session: the defaults, with the merge test's
pose offset of head poses tracked in the scene video (as ``process`` gives a tracked session)."""
MODEL_METHODS = ("ml", "voxel")
"""The estimators whose covariance follows an ``ErrorModel`` (``estimator.errormodel``)."""


def target_merger(method: str, sigma_deg: float, error_model: ErrorModel | None,
                  within_s: float = float("inf")) -> TargetMerger:
    """The merge test's groups (``estimator.merge.TargetMerger``) as ``process`` and the live
    session run it: a joined group's pooled lines estimated by ``method`` with ``sigma_deg``
    (``estimator.api.PooledEstimate``: as ``run_estimator`` over all of them), its covariance
    following ``error_model`` (``model_options``), the pose offset ``error_model.pose_offset_deg``
    (0 without one); a revisit joins only a group seen ``within_s`` seconds before it
    (``estimator.merge.STILL_HEAD_MERGE_S`` for a session without head poses)."""
    options = model_options(method, error_model)
    return TargetMerger(lambda: PooledEstimate(method, sigma_deg, **options), sigma_deg,
                        error_model.pose_offset_deg if error_model is not None else 0.0, within_s)


def model_options(method: str, error_model: ErrorModel | None) -> dict:
    """The estimator options that give ``method`` the error model ``error_model`` (none for a
    method without one, or for None: the inverse Fisher information)."""
    return {"error_model": error_model} if error_model is not None and method in MODEL_METHODS else {}


def running_estimate(samples: BinocularSamples, method: str, sigma_deg: float,
                     chunks: int = 20, error_model: ErrorModel | None = None) -> tuple[GazeEstimate | None, list]:
    """The estimator fed one fixation's samples (N,) in about ``chunks`` chunks, as a live session
    would, its covariance from ``error_model`` (``model_options``). Returns the last estimate (None
    without samples; a direction-only one, ``estimator.direction.with_direction``, when the lines
    fix no point ahead of the eyes) and the usable ones as (time of the chunk's last sample s,
    estimate) pairs."""
    stream = make_estimator(method, sigma_deg, **batch_options(method, len(samples),
                                                               **model_options(method, error_model)))
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
    if e is not None:
        e = with_direction(e, samples, error_model)
    return e, usable


def radius95_mm(e: GazeEstimate) -> float:
    """The largest semi-axis of the 95 % confidence ellipsoid, mm; NaN without a covariance."""
    ellipsoid = e.ellipsoid(0.95) if e.covariance_mm2 is not None else None
    if ellipsoid is None:
        return float("nan")
    return float(ellipsoid.radii_mm.max())


def estimate_target(index: int, samples: BinocularSamples, idx: np.ndarray, fixations, e: GazeEstimate,
                    method: str, sigma_deg: float, error_model: ErrorModel | None = None) -> Target:
    """The target made of the view lines ``samples[idx]`` (fixations ``fixations``) with their
    estimate ``e``: its 95 % semi-axes, the Cramér-Rao bound of those lines at the estimate, its
    status (``target_status.estimate_status``) and its direction (``estimator.direction``: a
    direction-only estimate's own, else the lines' cyclopean direction with its cone from
    ``error_model``)."""
    pos = e.position_mm if e.ok else np.full(3, np.nan)
    ellipsoid = e.ellipsoid(0.95) if e.covariance_mm2 is not None else None
    radii = ellipsoid.radii_mm if ellipsoid is not None else np.full(3, np.nan)
    t = samples.t_s[idx]
    lines = samples.select(idx)
    crb = _crb(lines, e.position_mm, sigma_deg) if e.ok else None
    status = estimate_status(e, lines)
    return Target(index=index, position_mm=np.asarray(pos, float), covariance_mm2=e.covariance_mm2, sight=e.sight(),
                  axes95_mm=np.asarray(radii, float), status=status, n_samples=len(idx),
                  t_start=float(t.min()), t_end=float(t.max()),
                  fixations=tuple(int(f) for f in fixations), method=method,
                  crb_mm=float(np.sqrt(np.trace(crb))) if crb is not None else float("nan"), samples=idx,
                  direction=static_direction(e, lines, status, error_model))


def static_direction(e: GazeEstimate, samples: BinocularSamples, status: str,
                     error_model: ErrorModel | None = None) -> GazeDirection | None:
    """A static target's direction from its estimate ``e`` and view lines ``samples`` (N,), world
    frame: a direction-only estimate's own; an ``ok`` point's (``estimator.direction.
    point_direction``: toward the point from the lines' mean cyclopean origin, its cone and depth
    interval from the point's covariance); else the lines' mean cyclopean direction with its cone
    from ``error_model`` (``gaze_direction``). ``process`` and the live session both use it."""
    if e.direction is not None:
        return e.direction
    if status == OK and e.position_mm is not None and e.covariance_mm2 is not None:
        g = point_direction(samples, e.position_mm, e.covariance_mm2)
        if g is not None:
            return g
    return gaze_direction(samples, error_model)


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


def estimate_file(path, method: str = "voxel", sigma_deg: float = 1.0, export_density=None, one_point: bool = False,
                  targets: bool = False, error_model: ErrorModel | None = DEFAULT_ERROR_MODEL) -> list[dict]:
    """``wearable-gaze estimate``: estimate each segment of a view-line CSV (docs/processing.md).

    Rows of segment -1 (saccades, blinks, gaps: ``wearable-gaze fixations``) are never estimated;
    they are returned as one entry with status ``skipped``. A file without a ``segment`` column is
    one segment, but only if it holds at most one fixation (``segment_view_lines`` over it) or
    ``one_point`` is set: several fixations estimated as one point would be a meaningless average,
    so a ``UserError`` says how to segment it.

    Returns one dict per segment, in order of first appearance: ``segment`` (value or None),
    ``method``, ``status``, ``reason``, ``position_mm`` [x, y, z] or None, ``n_samples``,
    ``n_lines``, ``covariance_mm2`` (3x3 or None), ``ellipsoid95_radii_mm``, ``density_ply``,
    ``covariance_model`` (``covariance_model(method, error_model)``). The covariances of ``ml``
    and ``voxel`` follow ``error_model`` (default ``ErrorModel()``; None: the inverse Fisher
    information, the Cramér-Rao bound).
    With ``export_density`` (a .ply path) the density of each segment is written there
    (``NAME-SEGMENT.ply`` when there are several segments). With ``targets`` the segments are
    fixations merged into targets as ``process`` merges them (``targets_of_segments``).
    """
    if export_density is not None and Path(export_density).suffix.lower() != ".ply":
        raise UserError(f"--export-density {export_density}: the file name must end in .ply; give a .ply name")
    if one_point and targets:
        raise UserError("--one-point and --targets exclude each other (one point for the whole file, or the targets of "
                        "its fixations); drop one of them")
    if targets and export_density is not None:
        raise UserError("--export-density writes one density per segment, not per target; drop --targets or "
                        "--export-density")
    segments = read_viewlines_csv(path)
    _check_segmentation(path, segments, one_point, targets)
    if targets:
        return targets_of_segments(path, method, sigma_deg, error_model)
    out = []
    for seg in segments:
        if seg.key == NO_FIXATION:
            out.append(_skipped(method, len(seg.samples), len(seg.samples.lines().origins_mm)))
            continue
        est, r = run_estimator(seg.samples, method, sigma_deg, **model_options(method, error_model))
        d = {"segment": seg.key, **r.to_dict(), "covariance_model": covariance_model(method, error_model)}
        d["density_ply"] = None
        if export_density is not None and getattr(est, "grid", None) is not None:
            d["density_ply"] = str(_write_density(est, _density_path(Path(export_density), seg.key,
                                                                     len(segments))))
        out.append(d)
    return out


def covariance_model(method: str, error_model: ErrorModel | None) -> str:
    """What an estimate's covariance is: 'error-model' (``estimator.errormodel``: ``ml`` and
    ``voxel`` with a model), 'inverse-fisher' (``ml`` and ``voxel`` without: the Cramér-Rao bound
    at the estimate) or 'method' (another method's own)."""
    if method not in MODEL_METHODS:
        return "method"
    return "error-model" if error_model is not None else "inverse-fisher"


def _write_density(est, target: Path) -> Path:
    pc = density_point_cloud(est)
    from estimator._open3d import import_open3d
    o3d = import_open3d()
    with atomic_path(target) as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), pc):
            raise UserError(f"could not write {target}; check the folder is writable")
    return target


def _skipped(method: str, n_samples: int, n_lines: int) -> dict:
    """The entry of the rows of segment -1, which no estimate uses."""
    return {"segment": NO_FIXATION, "method": method, "status": "skipped",
            "reason": "rows in no fixation (saccades, blinks, gaps): never estimated", "position_mm": None,
            "covariance_mm2": None, "ellipsoid95_radii_mm": None, "n_samples": n_samples, "n_lines": n_lines,
            "density_ply": None}


def _check_segmentation(path, segments: list, one_point: bool, targets: bool) -> None:
    """Refuse what would silently give a wrong answer: an unsegmented file holding several
    fixations (or any unsegmented file with ``targets``), ``one_point`` with a segmented file."""
    segmented = segments[0].key is not None
    fix = (f"run 'wearable-gaze fixations {path} -o SEGMENTED.csv' and estimate that file (--targets merges its "
           "fixations into targets as process does)")
    if one_point and segmented:
        raise UserError(f"--one-point: {path} has a segment column, so its rows are not one point; drop --one-point "
                        "to estimate each segment")
    if one_point:
        return
    if not segmented and targets:
        raise UserError(f"--targets: {path} has no segment column (no fixations to merge); {fix}")
    if not segmented:
        samples = segments[0].samples
        samples = samples.select(np.argsort(samples.t_s, kind="stable"))
        labels = segment_view_lines(samples, segment_config(measured_rate_hz(samples.t_s)))
        n = int(labels.max()) + 1
        if n >= 2:
            raise UserError(f"{path} has no segment column and its rows hold {n} fixations, which one estimate would "
                            f"average into a point none of them looked at; {fix}, or pass --one-point to estimate "
                            "every row as one point")


def targets_of_segments(path, method: str, sigma_deg: float, error_model: ErrorModel | None = None) -> list[dict]:
    """The targets of a view-line CSV whose ``segment`` column holds fixation labels (integers,
    -1 for none; ``wearable-gaze fixations``): each fixation estimated and fixations of one target
    merged exactly as ``process`` does (``fixations.find_targets``), so on the same view lines
    the positions are the same as process's targets.json. Returns one dict per target (the
    target record of targets.json, ``formats.targets.target_record``, with ``fixations`` as the
    file's segment labels, and ``covariance_model``), then the skipped entry of the rows of
    segment -1 if any. ``error_model``: as in ``find_targets``."""
    from .fixations import find_targets  # fixations imports this module

    samples, keys = read_in_time_order(path)
    bad = next((k for k in keys if isinstance(k, bool) or not isinstance(k, int) or k < NO_FIXATION), None)
    if bad is not None:
        raise UserError(f"--targets: {path} has segment '{bad}', not a fixation label (an integer, -1 for no "
                        "fixation); run 'wearable-gaze fixations' on it first")
    order = list(dict.fromkeys(k for k in keys if k != NO_FIXATION))      # the fixations by first row
    number = {k: i for i, k in enumerate(order)}
    labels = np.array([number.get(k, NO_FIXATION) for k in keys], dtype=int)
    result = find_targets(samples, labels, method, sigma_deg, error_model=error_model)
    out = []
    for tg in result.targets:
        row = tg.row()                          # the target record of targets.json and the live messages
        row["fixations"] = [order[f] for f in tg.fixations]
        row["covariance_model"] = "smoothed-path" if tg.moving else covariance_model(method, error_model)
        out.append(row)
    n_none = int((labels == NO_FIXATION).sum())
    if n_none:
        none = samples.select(np.flatnonzero(labels == NO_FIXATION))
        out.append(_skipped(method, n_none, len(none.lines().origins_mm)))
    return out


def nothing_estimated(path, results: list[dict]) -> UserError | None:
    """The error for an ``estimate_file`` result in which no segment (or target) got a position
    or a direction (``direction-only``): every row in segment -1, or every estimate failed (too
    few rows); None when at least one has either."""
    tried = [r for r in results if r.get("status") != "skipped"]
    if any(r.get("position_mm") is not None or r.get("status") == "direction-only" for r in tried):
        return None
    if not tried and not results:                 # --targets: no fixation gave a target
        return UserError(f"{path}: nothing could be estimated: no fixation gave a target (too few rows, or view lines "
                         "that do not converge); check the view lines, or estimate the segments without --targets")
    if not tried:
        return UserError(f"{path}: nothing to estimate: every row is in segment {NO_FIXATION} (saccades, blinks, "
                         "gaps); segment the view lines again (wearable-gaze fixations, docs/processing.md)")
    first = tried[0]
    which = f"target {first['target']}" if "target" in first else f"segment {first.get('segment')}"
    return UserError(f"{path}: nothing could be estimated: all {len(tried)} failed ({which}: {first['status']}, "
                     f"{first['reason']}); check that the view lines converge on the gazed point and each segment "
                     "has enough rows, or try another --method")


def skipped_note(results: list[dict]) -> str | None:
    """The line saying how many rows of segment -1 were not estimated (None: none)."""
    n = sum(r["n_samples"] for r in results if r.get("status") == "skipped")
    return (f"{n} row(s) of segment {NO_FIXATION} (saccades, blinks, gaps) not estimated" if n else None)


def format_table(results: list[dict]) -> str:
    """A readable table of ``estimate_file`` results (per segment, or per target with
    ``targets``); the skipped rows of segment -1 are left out (``skipped_note`` says them)."""
    results = [r for r in results if r.get("status") != "skipped"]
    if results and "target" in results[0]:
        return _targets_table(results)
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


def _targets_table(results: list[dict]) -> str:
    head = (f"{'target':>6} {'status':>17} {'x mm':>9} {'y mm':>9} {'z mm':>9} {'95% semi-axes mm':>22} "
            f"{'samples':>8} {'time s':>12} fixations")
    rows = [head, "-" * len(head)]
    for r in results:
        axes = " ".join(f"{v:.1f}" for v in (r["ellipsoid95_radii_mm"] or [np.nan] * 3))
        x, y, z = r["position_mm"] or [np.nan] * 3
        g = r.get("direction") if r["position_mm"] is None else None
        rows.append(f"{r['target']:>6} {r['status']:>17} {x:>9.1f} {y:>9.1f} {z:>9.1f} "
                    f"{axes:>22} {r['n_samples']:>8} {r['t_start']:>5.1f}-{r['t_end']:<6.1f} "
                    + ";".join(str(f) for f in r["fixations"])
                    + (f" (direction {' '.join(f'{v:.3f}' for v in g['unit'])}, 95 % cone {g['cone95_deg']:.2f} deg)"
                       if g else ""))
    return "\n".join(rows)
