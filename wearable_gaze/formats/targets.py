"""The files of ``process``'s targets step: the targets it found, ``targets.json`` and
``targets.csv`` (docs/processing.md, docs/formats.md "Targets"), the target of every view line,
``target_labels.npy``, and the fixations' running estimates, ``estimates.csv``.

Every target is one record (``target_record``, the one function that makes it; docs/formats.md,
"The target record"): ``targets.json`` holds the records as they are, ``wearable-gaze estimate
--json --targets`` prints them (adding ``covariance_model``) and the live session's ``target``
messages carry them (adding ``version``, ``type``, ``fixation``, rounded). Keys, in this order:
``target`` (index), ``t_start``, ``t_end`` (s), ``position_mm`` ([x, y, z], world frame, mm, or
null: no usable estimate), ``ellipsoid95_radii_mm`` (the 95 % ellipsoid's semi-axes, increasing,
mm, or null: no covariance), ``n_samples``, ``method``, ``status``, ``covariance_mm2`` (3x3, mm^2,
or null), ``crb_mm`` (or null), ``fixations`` (list of fixation indices), on a moving target
only, ``moving: true``, and, where the error model gave the covariance, ``depth`` (its distance
from where it was seen and the 68 % and 95 % intervals of it, symmetric in inverse depth:
``DEPTH_KEYS``), and where an assumption fixes the depth (a kappa offset taken at a distance, a
still head: ``pipeline.steps.errorbudget.depth_assumption``), ``depth_assumption`` (it, in words).
targets.json is ``{"version": 2, "method": ..., "targets": [records]}`` with, from ``process``,
``error_model`` (the per-eye bias and where it came from: ``pipeline.steps.errorbudget.session_bias``)
(schema ``targets``); ``read_targets`` also reads version 1 files (flat rows, NaN for none) into
records. targets.csv holds the same records flattened (``TARGET_CSV_COLUMNS``: ``position_mm``
-> ``x_mm, y_mm, z_mm``; ``covariance_mm2`` -> ``cov_xx_mm2 .. cov_zz_mm2``, its six unique
terms; ``ellipsoid95_radii_mm`` -> ``ellipsoid95_r1_mm .. r3_mm``; ``fixations`` ``;``-joined;
``moving`` 1/0; ``depth`` -> ``distance_mm``, ``depth68_near_mm .. depth95_far_mm``, the 95 %
pair from ``direction`` when there is no ``depth``; ``direction`` -> ``direction_x .. _z``,
``cone95_deg``), an empty cell for null, rounded to 0.1 mm and 1 ms for spreadsheets.

``target_paths.csv`` holds the moving targets' paths, one row per knot: ``target``, ``t`` (s),
``x, y, z`` (world frame, mm) and the covariance terms ``cxx, cxy, cxz, cyy, cyz, czz`` (mm^2);
a header alone when no target moves. ``write_target_paths`` and ``read_target_paths``.

One writer, ``write_targets`` (both files), and one reader, ``read_targets`` (the records of
targets.json, exact). ``target_labels.npy`` has ``write_target_labels`` and
``read_target_labels``. ``estimates.csv`` has one row per usable estimate while a fixation's view
lines were fed in, as a live session would: ``t`` (s, the last line fed), ``segment`` (the
fixation), ``x, y, z`` (world frame, mm) and ``radius95_mm`` (empty: no covariance), a header
alone when no fixation gave an estimate; ``write_estimates`` and ``read_estimates``.
``device_comparison.csv`` (an imported session) sets each target beside the device's own 3D gaze:
``target``, ``n_samples``, ``ours_distance_mm`` (our estimate's distance from the head, median
over the target's samples), ``device_depth_mm`` (the device's gaze depth, median over the same
samples), ``ours_x_mm..z``; ``write_device_comparison`` and ``read_device_comparison``. The
records are plain dicts here; ``pipeline.types.Target`` converts (``Target.row`` /
``Target.from_row``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from estimator.direction import GazeDirection
from estimator.errormodel import FAR_SIDE_K
from estimator.errormodel_regions import Sight
from estimator.region import CredibleRegion, region_of_direction, region_of_point

from ..errors import UserError
from .atomic import atomic_path
from .jsonio import validate, write_json
from .tables import Checks, read_table, write_table

TARGET_KEYS = ("target", "t_start", "t_end", "position_mm", "ellipsoid95_radii_mm", "n_samples", "method", "status",
               "covariance_mm2", "crb_mm", "fixations")
"""The keys of a target record (``target_record``), in order; a moving target's adds ``moving``."""
COV_TERMS = ("xx", "xy", "xz", "yy", "yz", "zz")
TARGET_CSV_COLUMNS = ("target", "x_mm", "y_mm", "z_mm", *(f"cov_{k}_mm2" for k in COV_TERMS), "ellipsoid95_r1_mm",
                      "ellipsoid95_r2_mm", "ellipsoid95_r3_mm", "n_samples", "t_start", "t_end", "fixations", "method",
                      "status", "crb_mm", "moving", "distance_mm", "depth68_near_mm", "depth68_far_mm",
                      "depth95_near_mm", "depth95_far_mm", "direction_x", "direction_y", "direction_z",
                      "cone95_deg", "dwell_s")
"""The columns of targets.csv: a record flattened (``target_csv_columns``)."""
DEPTH_COLUMN = "depth"
DIRECTION_COLUMN = "direction"
"""A record's ``direction`` (``estimator.direction.GazeDirection.to_dict``): the cyclopean gaze
direction seen from the mean of its lines' cyclopean origins, its 95 % cone's half-angle, the 95 %
depth interval along it (far null: no far end); every target with enough lines has one (an
``ok`` target's toward its point, a moving one's toward its path's middle knot:
``pipeline.steps.estimate.static_direction``, ``estimator.direction.path_direction``), and it is a
``direction-only`` target's whole answer (its ``position_mm`` is null)."""
DEPTH_ASSUMPTION = "depth_assumption"
DWELL = "dwell_s"
"""A record's dwell time: the sum of its fixations' durations (each the time its samples stand for,
``estimator.aoi.fixation_duration_s``: fixations.csv's ``duration_s``), s."""
DEPTH_KEYS = ("seen_from_mm", "distance_mm", "relative_sd", "interval68_mm", "interval95_mm")
"""The keys of a record's ``depth``: where it was seen from (the mean origin of its view lines,
[x, y, z] world frame, mm), its distance from there (mm), the linearised relative sd of that
distance, and the 68 % and 95 % intervals of it ([near, far] mm, far null when the interval has no
far end), symmetric in inverse depth (``estimator.errormodel.depth_interval``); and ``scale_dof``
and ``depth_dof`` when the covariance's scale has few degrees of freedom (a bias sized from the
session's lines: its regions and intervals are Student's, ``estimator.errormodel_regions``)."""
TARGET_FORMATS = {k: ".1f" for k in ("x_mm", "y_mm", "z_mm", "ellipsoid95_r1_mm", "ellipsoid95_r2_mm",
                                     "ellipsoid95_r3_mm", "crb_mm", "distance_mm", "depth68_near_mm",
                                     "depth68_far_mm", "depth95_near_mm", "depth95_far_mm")} | {
    k: ".6f" for k in ("direction_x", "direction_y", "direction_z")} | {"cone95_deg": ".3f"} | {
    f"cov_{k}_mm2": ".6g" for k in COV_TERMS} | {"t_start": ".3f", "t_end": ".3f"}
TARGETS_VERSION = 2
MOVING_COLUMN = "moving"
PATH_COLUMNS = ("target", "t", "x", "y", "z", "cxx", "cxy", "cxz", "cyy", "cyz", "czz")
PATH_FORMATS = {"t": ".4f", "x": ".1f", "y": ".1f", "z": ".1f"} | {k: ".6g" for k in PATH_COLUMNS[5:]}
_COV_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
ESTIMATE_COLUMNS = ("t", "segment", "x", "y", "z", "radius95_mm")
ESTIMATE_FORMATS = {"t": ".4f", "x": ".1f", "y": ".1f", "z": ".1f", "radius95_mm": ".1f"}
TARGET_CSV_CHECKS = Checks(tuple(c for c in TARGET_CSV_COLUMNS if c not in ("fixations", "method", "status")),
                           tuple(c for c in TARGET_CSV_COLUMNS if c.endswith("_mm") or c.endswith("_mm2")
                                 or c.startswith("direction_") or c in ("t_start", "t_end", "cone95_deg", "dwell_s")),
                           tuple(f"cov_{k}_mm2" for k in COV_TERMS), "targets table (targets.csv)")
PATH_CHECKS = Checks(PATH_COLUMNS, (), PATH_COLUMNS[5:], "target-path CSV (target_paths.csv)")
"""What target_paths.csv may hold, checked by its writer and its reader: the covariances in mm^2
(a path's end seen by nearly parallel lines has a depth variance of 1e12 mm^2)."""
ESTIMATE_CHECKS = Checks(ESTIMATE_COLUMNS, ("radius95_mm",), (), "running-estimate CSV (estimates.csv)")

log = logging.getLogger(__name__)


def _finite_list(value, shape, decimals: int | None):
    """``value`` as nested lists of floats (``shape``), rounded to ``decimals``; None when it is
    None or holds a value that is not finite (no such value)."""
    if value is None:
        return None
    a = np.asarray(value, float).reshape(shape)
    if not np.all(np.isfinite(a)):
        return None
    return (np.round(a, decimals) if decimals is not None else a).tolist()


def _finite(value, decimals: int | None = None):
    v = float(value)
    return None if not np.isfinite(v) else (round(v, decimals) if decimals is not None else v)


def target_record(index: int, t_start: float, t_end: float, position_mm, radii95_mm, n_samples: int, method: str,
                  status: str, covariance_mm2=None, crb_mm: float = float("nan"), fixations=(), moving: bool = False,
                  rounded: bool = False, sight: Sight | None = None, direction: GazeDirection | None = None,
                  depth_assumption: str | None = None, dwell_s: float = float("nan")) -> dict:
    """The record of one target (keys ``TARGET_KEYS``, plain JSON values): the one function that
    makes the rows of targets.json, the objects of ``estimate --json --targets`` and the body of
    the live ``target`` message, so that they cannot drift apart.

    Args:
        index: the target's number.
        t_start, t_end: its first and last sample's time, s.
        position_mm: (3,) world frame, mm; NaN where there is no usable estimate (then null).
        radii95_mm: (3,) the 95 % ellipsoid's semi-axes, increasing, mm (null when NaN).
        covariance_mm2: (3, 3) mm^2, or None.
        crb_mm: the Cramér-Rao bound's root trace, mm (null when NaN).
        fixations: the fixation indices merged into it.
        moving: a moving target: the record gets ``moving: true`` (a static one has no such key).
        rounded: round to 0.1 mm and 0.1 ms (a 6-digit covariance), as the live messages are sent.
        sight: where it was seen from and how the error model shaped its covariance
            (``estimator.errormodel.Sight``; ``pipeline.types.Target.sight``): the record gets
            ``depth``.
        direction: where its lines looked (``estimator.direction.GazeDirection``): the record
            gets ``direction`` (``GazeDirection.to_dict``: ``seen_from_mm``, ``unit``,
            ``cone95_deg``, ``depth95_mm`` [near, far or null], ``spread_deg``, ``n_samples``).
        depth_assumption: the assumption that fixes its depth, in words (the record gets
            ``depth_assumption``), or None.
        dwell_s: the sum of its fixations' durations, s (the record gets ``dwell_s`` when finite).
    """
    mm, s = (1, 4) if rounded else (None, None)
    cov = _finite_list(covariance_mm2, (3, 3), None)
    if cov is not None and rounded:
        cov = [[float(f"{v:.6g}") for v in row] for row in cov]
    rec = {"target": int(index), "t_start": _finite(t_start, s), "t_end": _finite(t_end, s),
           "position_mm": _finite_list(position_mm, (3,), mm),
           "ellipsoid95_radii_mm": _finite_list(radii95_mm, (3,), mm),
           "n_samples": int(n_samples), "method": str(method), "status": str(status), "covariance_mm2": cov,
           "crb_mm": _finite(crb_mm, mm), "fixations": [int(f) for f in fixations]}
    if moving:
        rec[MOVING_COLUMN] = True
    if sight is not None and rec["position_mm"] is not None and np.isfinite(sight.depth_rel_sd):
        rec[DEPTH_COLUMN] = _depth(position_mm, sight, mm)
    if direction is not None:
        rec[DIRECTION_COLUMN] = direction.to_dict(mm)
    if depth_assumption:
        rec[DEPTH_ASSUMPTION] = str(depth_assumption)
    if np.isfinite(dwell_s):
        rec[DWELL] = _finite(dwell_s, s if rounded else 4)
    return rec


def _depth(position_mm, sight: Sight, mm: int | None) -> dict:
    """A record's ``depth`` (``DEPTH_KEYS``) of the point ``position_mm`` seen from ``sight``."""
    def interval(p):
        return [_finite(v, mm) for v in sight.depth_interval(position_mm, p)]

    return {"seen_from_mm": _finite_list(sight.origin_mm, (3,), mm),
            "distance_mm": _finite(sight.distance_mm(position_mm), mm),
            "relative_sd": _finite(sight.depth_rel_sd, None if mm is None else 4), "interval68_mm": interval(0.68),
            "interval95_mm": interval(0.95),
            **{key: round(float(v), 3) for key, v in (("scale_dof", sight.scale_dof), ("depth_dof", sight.depth_dof))
               if np.isfinite(v)}}


def record_sight(rec: dict) -> Sight | None:
    """The sight of a record with ``depth`` (targets.json's covariances are the error model's,
    stretched for the 95 % level), else None."""
    d = rec.get(DEPTH_COLUMN)
    if not d or d.get("seen_from_mm") is None or d.get("relative_sd") is None:
        return None
    return Sight(np.asarray(d["seen_from_mm"], float), FAR_SIDE_K, float(d["relative_sd"]),
                 float(d.get("scale_dof") or np.inf), float(d.get("depth_dof") or np.inf))


def target_csv_columns(records: list[dict]) -> dict:
    """The columns of targets.csv (``TARGET_CSV_COLUMNS``, (N,) each) of ``records``: arrays
    flattened, null as NaN (an empty cell), ``fixations`` joined with ``;``, ``moving`` 1/0."""
    def vec(key, n):
        return np.array([r[key] if r[key] is not None else [np.nan] * n for r in records], float).reshape(-1, n)

    pos, radii = vec("position_mm", 3), vec("ellipsoid95_radii_mm", 3)
    cov = np.array([r["covariance_mm2"] if r["covariance_mm2"] is not None else np.full((3, 3), np.nan)
                    for r in records], float).reshape(-1, 3, 3)
    cols = {"target": np.array([r["target"] for r in records], int)}
    cols |= {f"{k}_mm": pos[:, j] for j, k in enumerate("xyz")}
    cols |= {f"cov_{k}_mm2": cov[:, "xyz".index(k[0]), "xyz".index(k[1])] for k in COV_TERMS}
    cols |= {f"ellipsoid95_r{j + 1}_mm": radii[:, j] for j in range(3)}
    cols |= {"n_samples": np.array([r["n_samples"] for r in records], int)}
    cols |= {k: np.array([np.nan if r[k] is None else r[k] for r in records], float) for k in ("t_start", "t_end")}
    cols |= {"fixations": np.array([";".join(str(f) for f in r["fixations"]) for r in records], object)}
    cols |= {k: np.array([r[k] for r in records], object) for k in ("method", "status")}
    cols |= {"crb_mm": np.array([np.nan if r["crb_mm"] is None else r["crb_mm"] for r in records], float),
             "moving": np.array([int(bool(r.get(MOVING_COLUMN))) for r in records], int)}

    def depth(r, key, j=None):
        d = r.get(DEPTH_COLUMN)
        v = None if not d else (d[key] if j is None else d[key][j])
        return np.nan if v is None else v

    cols |= {"distance_mm": np.array([depth(r, "distance_mm") for r in records], float)}
    cols |= {f"depth{p}_{side}_mm": np.array([depth(r, f"interval{p}_mm", j) for r in records], float)
             for p in (68, 95) for j, side in enumerate(("near", "far"))}
    no_depth = np.array([not r.get(DEPTH_COLUMN) for r in records], bool)
    for j, side in enumerate(("near", "far")):          # a direction-only target's interval, from its direction
        along = np.array([direction(r, "depth95_mm", j) for r in records], float)
        cols[f"depth95_{side}_mm"] = np.where(no_depth, along, cols[f"depth95_{side}_mm"])
    cols |= {f"direction_{a}": np.array([direction(r, "unit", j) for r in records], float) for j, a in enumerate("xyz")}
    cols |= {"cone95_deg": np.array([direction(r, "cone95_deg") for r in records], float)}
    cols |= {DWELL: np.array([r.get(DWELL, np.nan) if r.get(DWELL) is not None else np.nan for r in records], float)}
    return cols


def direction(r: dict, key: str, j: int | None = None) -> float:
    """A record's ``direction[key]`` (its ``j``-th entry), NaN when it has none (or it is null)."""
    d = r.get(DIRECTION_COLUMN)
    v = None if not d else (d[key] if j is None else d[key][j])
    return np.nan if v is None else float(v)


def write_targets_csv(path, records: list[dict], sessions=None) -> None:
    """Write ``records`` as a targets.csv table (``target_csv_columns``) at ``path``; with
    ``sessions`` ((N,) names), a ``session`` column in front (``batch``'s all_targets.csv)."""
    cols = target_csv_columns(records)
    if sessions is not None:
        cols = {"session": np.array(list(sessions), object), **cols}
    write_table(path, cols, TARGET_FORMATS, TARGET_CSV_CHECKS)


def write_targets(out, records: list[dict], method: str, error_model: dict | None = None) -> None:
    """Write ``records`` (``target_record``) as ``out``/targets.csv and ``out``/targets.json
    (with ``method``, the estimator, and ``error_model``, the bias's record, when given), each
    atomically."""
    out = Path(out)
    write_targets_csv(out / "targets.csv", records)
    obj = {"version": TARGETS_VERSION, "method": method, "targets": records}
    write_json(out / "targets.json", obj | ({"error_model": error_model} if error_model is not None else {}))


def _record_of_v1(row: dict) -> dict:
    """A version-1 row of targets.json (flat keys, NaN for none) as a record."""
    return target_record(row["target"], row["t_start"], row["t_end"], [row["x_mm"], row["y_mm"], row["z_mm"]],
                         [row["axis1_mm"], row["axis2_mm"], row["axis3_mm"]], row["n_samples"], row["method"],
                         row["status"], None, row["crb_mm"],
                         [int(f) for f in str(row["fixations"]).split(";") if f], bool(row.get(MOVING_COLUMN)))


def read_targets(path) -> list[dict]:
    """The records of a targets.json written by ``write_targets`` (version 2, checked against
    the ``targets`` schema), in file order; a version-1 file's rows converted to records (no
    covariance: version 1 kept only the semi-axes).

    Raises:
        UserError: a missing file, or one that is not a targets.json.
    """
    path = Path(path)
    fix = "run the targets step of 'wearable-gaze process' again (--force)"
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))         # version 1 holds NaN
        if obj.get("version") == 1:
            return [_record_of_v1(r) for r in obj["targets"]]
    except FileNotFoundError:
        raise UserError(f"{path}: no such file; run the targets step of 'wearable-gaze process' again") from None
    except (ValueError, KeyError, TypeError, AttributeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a targets.json ({type(exc).__name__}: {exc}); {fix}") from None
    validate(obj, "targets", path)                  # one line: the file, the field, what was expected, the fix
    return obj["targets"]


def write_target_paths(path, paths: dict) -> None:
    """Write target_paths.csv, atomically: ``paths`` maps a target index to its path as
    (t (K,) s, positions (K, 3) world mm, covariances (K, 3, 3) mm^2); rows in target order."""
    cols = {k: [] for k in PATH_COLUMNS}
    for index in sorted(paths):
        t, pos, cov = (np.asarray(a, float) for a in paths[index])
        cols["target"].append(np.full(len(t), int(index)))
        cols["t"].append(t)
        for j, name in enumerate("xyz"):
            cols[name].append(pos[:, j])
        for name, (i, j) in zip(PATH_COLUMNS[5:], _COV_INDEX, strict=True):
            cols[name].append(cov[:, i, j])
    out = {k: np.concatenate(v) if v else np.zeros(0, int if k == "target" else float) for k, v in cols.items()}
    write_table(path, out, PATH_FORMATS, PATH_CHECKS)


def read_target_paths(path) -> dict:
    """The paths of a target_paths.csv: {target index: (t (K,), positions (K, 3), covariances
    (K, 3, 3))}; a header alone is no path, not an error.

    Raises:
        UserError: a missing file or column, a cell that is not a number (one line).
    """
    cols = read_table(path, list(PATH_COLUMNS), rows_required=False, checks=PATH_CHECKS)
    out = {}
    for index in dict.fromkeys(int(v) for v in cols["target"]):
        sel = cols["target"] == index
        cov = np.zeros((int(sel.sum()), 3, 3))
        for name, (i, j) in zip(PATH_COLUMNS[5:], _COV_INDEX, strict=True):
            cov[:, i, j] = cov[:, j, i] = cols[name][sel]
        out[index] = (cols["t"][sel], np.column_stack([cols[k][sel] for k in "xyz"]), cov)
    return out


def write_target_labels(path, labels: np.ndarray) -> None:
    """Write target_labels.npy: the target index of every view line of viewlines.csv (N,), -1
    none (NumPy's .npy format), atomically."""
    with atomic_path(path) as tmp:
        np.save(tmp, labels)


def read_target_labels(path) -> np.ndarray:
    """The (N,) target index of every view line, -1 none, of a target_labels.npy.

    Raises:
        UserError: a file that is not a NumPy array file.
    """
    try:
        return np.load(path)
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: not a target_labels.npy ({exc}); run the targets step of 'wearable-gaze process' "
                        "again (--force)") from None


def write_estimates(path, columns: dict) -> None:
    """Write the columns ``ESTIMATE_COLUMNS`` ((N,) each; N may be 0) as estimates.csv, atomically."""
    write_table(path, {k: np.asarray(columns[k]) for k in ESTIMATE_COLUMNS}, ESTIMATE_FORMATS, ESTIMATE_CHECKS)


def read_estimates(path) -> dict:
    """The columns of an estimates.csv, (N,) float each; a header alone (no fixation gave an
    estimate) is no estimate, not an error.

    Raises:
        UserError: a missing file, a missing column, a cell that is not a number (one line).
    """
    return read_table(path, list(ESTIMATE_COLUMNS), rows_required=False,
                      checks=ESTIMATE_CHECKS)          # radius95_mm empty: an estimate without a covariance (lse)


DEVICE_COLUMNS = ("target", "n_samples", "ours_distance_mm", "device_depth_mm", "ours_x_mm", "ours_y_mm", "ours_z_mm")
DEVICE_CHECKS = Checks(DEVICE_COLUMNS, tuple(k for k in DEVICE_COLUMNS if k.endswith("_mm")), (),
                       "device-comparison CSV")


def write_device_comparison(path, rows: list[dict]) -> None:
    """device_comparison.csv: one row per target with ``DEVICE_COLUMNS`` (mm; NaN: none)."""
    cols = {k: np.array([r[k] for r in rows], float if k.endswith("_mm") else int) for k in DEVICE_COLUMNS}
    write_table(path, cols, {k: ".1f" for k in DEVICE_COLUMNS if k.endswith("_mm")}, DEVICE_CHECKS)


def read_device_comparison(path) -> dict:
    """device_comparison.csv -> {column: (N,) array} (``DEVICE_COLUMNS``; NaN where empty)."""
    return read_table(path, list(DEVICE_COLUMNS), rows_required=False, checks=DEVICE_CHECKS)



DIRECTION_KEYS = ("unit", "direction_unit", "direction", "direction_world", "gaze_direction", "sight_direction")
"""Where a record without a point may keep its line of sight (a unit [x, y, z], world frame):
read in this order, at the top level, in ``depth`` or in a ``direction`` object (``record_region``;
a direction-only target's ``direction``: ``seen_from_mm``, ``unit``, ``cone95_deg``,
``depth95_mm``)."""
CONE_KEYS = ("cone95_deg", "cone95_half_angle_deg", "cone_half_angle95_deg", "half_angle95_deg", "direction95_deg",
             "cone_half_angle_deg", "cone_deg")
"""... and the 95 % cone's half-angle about it, degrees (then any key with 'cone' or 'half_angle'
ending in ``_deg``; ``_rad`` keys are read as radians)."""
INTERVAL_KEYS = ("interval95_mm", "depth95_mm", "depth_interval95_mm", "depth_interval_mm", "interval_mm")
ORIGIN_KEYS = ("seen_from_mm", "origin_mm", "sight_origin_mm", "apex_mm", "head_mm")


def _places(rec: dict) -> list[dict]:
    """The record and the objects in it where a region's values may be: ``depth``, ``direction``."""
    inner = [rec.get(k) for k in (DEPTH_COLUMN, "direction", "cone", "region")]
    return [rec, *(d for d in inner if isinstance(d, dict))]


def _vector(places: list[dict], keys) -> np.ndarray | None:
    """The first finite 3-vector under one of ``keys`` in ``places``, or None."""
    for k in keys:
        for d in places:
            v = d.get(k)
            if isinstance(v, dict):           # an object: its own keys are among the places
                continue
            try:
                a = np.asarray(v, float).reshape(3) if v is not None else None
            except (TypeError, ValueError):
                continue
            if a is not None and np.all(np.isfinite(a)):
                return a
    return None


def _cone_rad(places: list[dict]) -> float:
    """The 95 % cone's half-angle, radians, from ``CONE_KEYS`` or a key like them; NaN: none."""
    for d in places:
        named = [k for k in CONE_KEYS if k in d]
        named += [k for k in d if ("cone" in k or "half_angle" in k) and k.endswith(("_deg", "_rad"))]
        for k in named:
            try:
                v = float(d[k])
            except (TypeError, ValueError):
                continue
            if np.isfinite(v) and v >= 0:
                return v if k.endswith("_rad") else float(np.deg2rad(v))
    return float("nan")


def _interval(places: list[dict]) -> tuple[float, float]:
    """(near, far) mm of the first interval of ``INTERVAL_KEYS``; None or a missing far end is
    inf, a missing near end NaN; (NaN, inf) without one."""
    for k in INTERVAL_KEYS:
        for d in places:
            v = d.get(k)
            if isinstance(v, list | tuple) and len(v) == 2:
                near = np.nan if v[0] is None else float(v[0])
                far = np.inf if v[1] is None or not np.isfinite(float(v[1])) else float(v[1])
                return near, far
    return float("nan"), float("inf")


def record_region(rec: dict) -> CredibleRegion | None:
    """The 95 % credible region of a target record (``estimator.region``), or None (no sight:
    e.g. ``lse``, no error model, a version-1 file). A record with a point, a covariance and
    ``depth``: the point's interval along its line of sight and its lateral extent
    (``region_of_point``). A record without a point (or without a covariance) but with a
    direction (``DIRECTION_KEYS``), where it was seen from (``ORIGIN_KEYS``) and perhaps a
    cone (``CONE_KEYS``, 0 without) and an interval (``INTERVAL_KEYS``: a null or missing far
    end is open, a missing near end 0): a cone (``region_of_direction``). Read tolerantly: keys
    it does not know are left alone, a value that is not a number is no value."""
    places = _places(rec)
    origin = _vector(places, ORIGIN_KEYS)
    if origin is None:
        return None
    near, far = _interval(places)
    pos, cov = rec.get("position_mm"), rec.get("covariance_mm2")
    if pos is not None and cov is not None and np.isfinite(near):
        region = region_of_point(pos, cov, origin, near, far, 0.95)
        if region is not None:
            return region
    direction = _vector(places, DIRECTION_KEYS)
    if direction is None and pos is not None:
        direction = np.asarray(pos, float) - origin
    if direction is None:
        return None
    cone = _cone_rad(places)
    return region_of_direction(origin, direction, cone if np.isfinite(cone) else 0.0, near, far, 0.95)
