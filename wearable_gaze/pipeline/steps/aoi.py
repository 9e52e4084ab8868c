"""Areas of interest in the room (issue 28; docs/aois.md): which area each fixation's gazed point
lies in, with what probability, and the measures researchers report per area.

The step is ``run(AoiConfig, AoiInputs) -> AoiResult`` over typed values; ``areas_of`` makes the
areas' geometry from an AOI file's specs (and the marker map, for marker areas), ``fixation_gaze``
each fixation's gaze distribution from fixations.csv and the view lines, and ``aoi_folder`` is what
``wearable-gaze aoi`` and ``process --aois`` run on a processed folder.

Definitions (after Holmqvist et al. 2011, *Eye Tracking: A comprehensive guide to methods and
measures*, ch. 6 "areas of interest"):

- a fixation's probability of an area: the share of its gazed-point distribution the area holds
  (``estimator.aoi.probabilities``); its assigned area: the most probable one, when that
  probability is at least ``AoiConfig.assign_probability``, else none;
- a fixation's duration: the time its samples stand for (``estimator.aoi.fixation_duration_s``:
  one sample interval each, a blink inside it left out), Tobii Pro's convention;
- dwell time: the sum of the durations of the fixations assigned to the area (Tobii Pro Lab's
  "total duration of fixations", Pupil Cloud's "total fixation duration"); the weighted dwell
  time: the sum of every fixation's duration times its probability of the area;
- a visit: a run of consecutive fixations assigned to the area (a fixation assigned elsewhere,
  or to none, ends it); revisits: visits after the first;
- time to first fixation: the start of the first assigned fixation, from the session's first
  sample; its duration: that fixation's;
- share: dwell time over the session's length (the time its samples stand for, as a fixation's:
  first to last sample plus one sample interval);
- transitions: from one visit to the next one of another area (counts), and, weighted, the sum over
  consecutive fixations of the probability of the one area times that of the other.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from estimator.aoi import (
    DEPTH_TOLERANCE_MM,
    SAMPLES,
    Box,
    GazeSpread,
    Mesh,
    Polygon,
    Sphere,
    fixation_durations_s,
    plane_normal,
    probabilities,
    sample_interval_s,
)
from estimator.deprecation import module_getattr
from estimator.frames import tangent_basis

from ...errors import UserError
from ...formats.aoi_tables import write_aoi_fixations, write_aoi_metrics, write_aoi_transitions
from ...formats.aois import AoiSpec, read_aois
from ...formats.fixations_table import COV_COLUMNS, COV_INDEX, read_fixations_csv
from ...formats.markermap import load_marker_map
from ...formats.targets import read_targets
from ...formats.viewlines import read_viewlines_csv
from ..report.aoi_plots import plot_dwell, plot_timeline

NONE = "none"
"""The name of "no area" in the tables."""


@dataclass(frozen=True)
class AoiConfig:
    """The AOI step's settings.

    Attributes:
        assign_probability: a fixation is assigned to its most probable area when that
            probability is at least this (0.5: more likely in it than not), else to none.
        samples: points drawn per fixation (``estimator.aoi.SAMPLES``).
    """

    assign_probability: float = 0.5
    samples: int = SAMPLES


@dataclass(frozen=True)
class Area:
    """An area's name, group and geometry (``estimator.aoi``: Box, Sphere, Polygon or Mesh)."""

    name: str
    group: str | None
    shape: Box | Sphere | Polygon | Mesh


@dataclass(frozen=True)
class FixationGaze:
    """One fixation: ``fixation_id``, ``start_s``, ``end_s`` (its first and last sample, session
    clock, s), the target it was merged into (``target_id``, -1 none), its gazed point's
    distribution (``spread``, None when its lines gave neither a point nor a direction) and the
    time its samples stand for (``time_s``, ``estimator.aoi.fixation_duration_s``; None: not
    known, ``end_s - start_s`` is taken: only for fixations made by hand, ``fixation_gaze``
    always gives it)."""

    fixation_id: int
    start_s: float
    end_s: float
    target_id: int
    spread: GazeSpread | None
    time_s: float | None = None

    @property
    def duration_s(self) -> float:
        """Its duration in the measures, s: ``time_s``, else first to last sample."""
        return self.end_s - self.start_s if self.time_s is None else self.time_s


@dataclass(frozen=True)
class AoiInputs:
    """The areas, the fixations in time order, and the session's start and end, s: its first
    sample's time and its last's plus one sample interval (as a fixation's duration counts)."""

    areas: tuple
    fixations: tuple
    session_start_s: float
    session_end_s: float


@dataclass(frozen=True)
class AoiResult:
    """What the step finds.

    Attributes:
        names: the areas' names, in the file's order.
        probabilities: (n_fixations, n_areas + 1) each fixation's probability of each area and,
            last, of none (NaN rows: a fixation without a spread).
        assigned: (n_fixations,) the assigned area's index, -1 none.
        metrics: one dict per area (docs/aois.md, aoi_metrics.csv).
        transitions: one dict per (from, to) pair of areas with a count or a weight above zero.
    """

    names: tuple
    probabilities: np.ndarray
    assigned: np.ndarray
    metrics: list
    transitions: list


def run(conf: AoiConfig, inputs: AoiInputs) -> AoiResult:
    """Each fixation's probability of each area, its assignment, and the per-area measures."""
    k = len(inputs.areas)
    shapes = [a.shape for a in inputs.areas]
    P = np.full((len(inputs.fixations), k + 1), np.nan)
    for i, f in enumerate(inputs.fixations):
        if f.spread is not None:
            P[i] = probabilities(f.spread, shapes, conf.samples)
    best = np.argmax(np.nan_to_num(P[:, :k], nan=-1.0), axis=1) if k else np.zeros(len(P), int)
    top = P[np.arange(len(P)), best] if len(P) else np.zeros(0)
    assigned = np.where(np.nan_to_num(top, nan=0.0) >= conf.assign_probability, best, -1)
    names = tuple(a.name for a in inputs.areas)
    return AoiResult(names, P, assigned, _metrics(inputs, P, assigned),
                     _transitions(names, P, assigned))


def _visits(assigned: np.ndarray) -> list[tuple[int, int]]:
    """[(area, first fixation index)] for each run of equal assignments other than none."""
    out, prev = [], -2
    for i, a in enumerate(assigned):
        if a != prev and a >= 0:
            out.append((int(a), i))
        prev = a
    return out


def _metrics(inputs: AoiInputs, P: np.ndarray, assigned: np.ndarray) -> list[dict]:
    dur = np.array([f.duration_s for f in inputs.fixations], float)
    length = max(inputs.session_end_s - inputs.session_start_s, 1e-9)
    visits = _visits(assigned)
    rows = []
    for j, area in enumerate(inputs.areas):
        mine = np.flatnonzero(assigned == j)
        first = inputs.fixations[mine[0]] if len(mine) else None
        n_visits = sum(1 for a, _ in visits if a == j)
        dwell = float(dur[mine].sum())
        rows.append({"aoi": area.name, "group": area.group or "", "dwell_s": dwell,
                     "dwell_weighted_s": float(np.nansum(P[:, j] * dur)) if len(P) else 0.0,
                     "visits": n_visits, "revisits": max(n_visits - 1, 0), "fixations": len(mine),
                     "first_fixation_s": first.start_s - inputs.session_start_s if first else float("nan"),
                     "first_fixation_duration_s": first.duration_s if first else float("nan"),
                     "share": dwell / length})
    return rows


def _transitions(names: tuple, P: np.ndarray, assigned: np.ndarray) -> list[dict]:
    k = len(names)
    counts = np.zeros((k, k), int)
    v = _visits(assigned)
    for (a, _), (b, _) in zip(v, v[1:], strict=False):
        counts[a, b] += 1
    weight = np.zeros((k, k))
    for p, q in zip(P[:-1], P[1:], strict=False):
        if np.all(np.isfinite(p)) and np.all(np.isfinite(q)):
            w = np.outer(p[:k], q[:k])
            np.fill_diagonal(w, 0.0)
            weight += w
    return [{"from": names[a], "to": names[b], "count": int(counts[a, b]), "weighted": float(weight[a, b])}
            for a in range(k) for b in range(k) if a != b and (counts[a, b] or weight[a, b] > 0)]


def areas_of(specs: list[AoiSpec], marker_map=None) -> tuple:
    """The areas (``Area``) of an AOI file's specs; marker areas from ``marker_map``
    (``tracking.markermap.MarkerMap``).

    Raises:
        UserError: a marker area without a map, or with an id the map does not hold.
    """
    return tuple(Area(s.name, s.group, _shape(s, marker_map)) for s in specs)


def _shape(s: AoiSpec, marker_map) -> Box | Sphere | Polygon | Mesh:
    p = s.params
    tol = float(p.get("depth_tolerance_mm", DEPTH_TOLERANCE_MM))
    transparent = bool(p.get("transparent", False))
    if s.kind == "box":
        R = Rotation.from_euler("xyz", p.get("rotation_deg", [0, 0, 0]), degrees=True).as_matrix()
        return Box(np.asarray(p["center_mm"], float), np.asarray(p["size_mm"], float), R,
                   transparent=transparent, depth_tolerance_mm=tol)
    if s.kind == "sphere":
        return Sphere(np.asarray(p["center_mm"], float), float(p["radius_mm"]),
                      transparent=transparent, depth_tolerance_mm=tol)
    if s.kind == "mesh":
        if s.vertices_mm is None or s.faces is None:
            raise UserError(f"AOI {s.name!r}: a mesh area without its vertices and faces; "
                            "read the AOI file with read_aois")
        return Mesh(s.vertices_mm, s.faces, transparent=transparent, depth_tolerance_mm=tol)
    if s.kind == "polygon":
        try:
            return Polygon(np.asarray(p["corners_mm"], float), depth_tolerance_mm=tol)
        except ValueError as exc:
            raise UserError(f"AOI {s.name!r}: {exc}; give corners on one plane") from None
    ids = [p["id"]] if s.kind == "marker" else list(p["ids"])
    if marker_map is None:
        raise UserError(f"AOI {s.name!r} names marker(s) {ids} but there is no marker map; pass --markers map.json")
    missing = [i for i in ids if i not in marker_map.poses]
    if missing:
        raise UserError(f"AOI {s.name!r}: marker(s) {missing} are not in the marker map "
                        f"(it holds {sorted(marker_map.poses)}); fix the ids")
    corners = np.vstack([marker_map.corners(i) for i in ids])
    return Polygon(_grown_hull(corners, float(p.get("margin_mm", 0.0))), depth_tolerance_mm=tol)


AOI_COLOR = "#00838f"
"""The areas' colour in the report's 3D view (no target's: Kelly's colours hold no teal)."""
MAX_MESH_EDGES = 3000
"""A mesh area is outlined by at most this many of its edges in the 3D view."""


def area_outline(area: Area) -> np.ndarray:
    """(K, 2, 3) segments, world mm, that outline an area for the 3D view: a box's 12 edges, a
    ball's three great circles, a polygon's sides, a mesh's edges (at most ``MAX_MESH_EDGES``)."""
    g = area.shape
    if isinstance(g, Box):
        c = np.array(list(np.ndindex(2, 2, 2)), float) - 0.5
        corners = g.center_mm + (c * g.size_mm) @ g.R_world_from_box.T
        pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(c[i] != c[j]) == 1]
        return np.array([[corners[i], corners[j]] for i, j in pairs])
    if isinstance(g, Sphere):
        a = np.linspace(0, 2 * np.pi, 33)
        ring = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
        rings = [ring, ring[:, [0, 2, 1]], ring[:, [2, 0, 1]]]
        return np.concatenate([np.stack([g.center_mm + g.radius_mm * r[:-1], g.center_mm + g.radius_mm * r[1:]],
                                        axis=1) for r in rings])
    if isinstance(g, Polygon):
        c = np.asarray(g.corners_mm, float)
        return np.stack([c, np.roll(c, -1, axis=0)], axis=1)
    f = np.asarray(g.faces, int)
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    if len(edges) > MAX_MESH_EDGES:
        edges = edges[np.linspace(0, len(edges) - 1, MAX_MESH_EDGES).astype(int)]
    return np.asarray(g.vertices_mm, float)[edges]


def aoi_outlines(specs, marker_map=None) -> list:
    """[(name, colour, segments (K, 2, 3) mm)] of an AOI file's areas (``specs``: ``read_aois``'s)
    for the report's 3D view (``view3d.scene``'s ``aois``); [] without any."""
    return [(a.name, AOI_COLOR, area_outline(a)) for a in areas_of(list(specs or ()), marker_map)]


def _grown_hull(corners, margin_mm: float) -> np.ndarray:
    """(K, 3) the convex hull of ``corners`` (M, 3) on their best plane, each side moved
    ``margin_mm`` outward (a corner where its two moved sides meet), in order around it."""
    n = plane_normal(corners)
    b1, b2 = tangent_basis(n)
    E = np.column_stack([b1[0], b2[0]])
    c0 = corners.mean(axis=0)
    uv = (corners - c0) @ E
    hull = uv[ConvexHull(uv).vertices]                 # counter-clockwise
    edge = np.roll(hull, -1, axis=0) - hull
    out = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.linalg.norm(edge, axis=1, keepdims=True)
    grown = []
    for i in range(len(hull)):                         # sides i-1 and i, moved out, meet at corner i
        a, b = out[i - 1], out[i]
        grown.append(hull[i] + margin_mm * (a + b) / (1.0 + float(a @ b)))
    return c0 + np.asarray(grown) @ E.T


def lines_interval_s(segments) -> float:
    """The sample interval of view lines (``segments``: ``read_viewlines_csv``'s), s
    (``estimator.aoi.sample_interval_s`` of them all: NaN with fewer than two)."""
    return sample_interval_s(np.concatenate([np.asarray(seg.samples.t_s, float) for seg in segments] or [np.zeros(0)]))


def fixation_gaze(fixations: dict, segments, targets=()) -> tuple:
    """``FixationGaze`` of each row of fixations.csv (``read_fixations_csv``'s columns), in time
    order, seen from the mean origin of its view lines (``segments``: ``read_viewlines_csv``'s,
    keyed by fixation id), its duration the time its samples there stand for at the lines'
    sample interval (``estimator.aoi.fixation_durations_s``, as fixations.csv's ``duration_s``
    and the targets' dwell; that column when its lines are not there). Its gazed point's spread
    is its target's (``targets``: targets.json's records) when it was merged into an ``ok``
    target, which pools the lines of every fixation the merge test found on that point; else its
    own estimate's (point and covariance); a direction-only target's cone over its depth
    interval; None when it has none of them."""
    origins = {}
    for seg in segments:
        if isinstance(seg.key, (int, np.integer)) and seg.key >= 0:
            s = seg.samples
            o = np.vstack([s.left_origin_mm[s.left_valid], s.right_origin_mm[s.right_valid]])
            if len(o):
                origins[int(seg.key)] = o.mean(axis=0)
    times = _durations(fixations, segments)
    pooled = {int(t["target"]): (np.asarray(t["position_mm"], float), np.asarray(t["covariance_mm2"], float))
              for t in targets if t["status"] == "ok" and t.get("covariance_mm2") is not None}
    directions = {int(t["target"]): t["direction"] for t in targets
                  if t.get("position_mm") is None and t.get("direction") is not None}
    out = []
    for i in np.argsort(fixations["start_s"], kind="stable"):
        fid, tid = int(fixations["fixation_id"][i]), int(fixations["target_id"][i])
        p, C = pooled.get(tid, (_own_point(fixations, i), _own_covariance(fixations, i)))
        spread = None
        if fid in origins and np.all(np.isfinite(p)) and np.all(np.isfinite(C)):
            spread = GazeSpread.from_covariance(origins[fid], p, C)
        elif tid in directions:                     # direction-only: its cone over its depth interval
            g = directions[tid]
            near, far = g["depth95_mm"]
            spread = GazeSpread.direction_only(g["seen_from_mm"], g["unit"], g["cone95_deg"], near,
                                               math.inf if far is None else far)
        out.append(FixationGaze(fid, float(fixations["start_s"][i]), float(fixations["end_s"][i]), tid, spread,
                                times.get(fid)))
    return tuple(out)


def _durations(fixations: dict, segments) -> dict:
    """{fixation id: duration s} of fixations.csv's rows (``fixations``): the time its view lines
    (``segments``) stand for (``estimator.aoi.fixation_durations_s``), else its ``duration_s``."""
    keys = [int(seg.key) if isinstance(seg.key, (int, np.integer)) and seg.key >= 0 else -1 for seg in segments]
    t = np.concatenate([np.asarray(seg.samples.t_s, float) for seg in segments] or [np.zeros(0)])
    labels = np.concatenate([np.full(len(seg.samples.t_s), k) for k, seg in zip(keys, segments, strict=True)]
                            or [np.zeros(0, int)])
    ids = sorted({k for k, seg in zip(keys, segments, strict=True) if k >= 0 and len(seg.samples.t_s)})
    times = dict(zip(ids, fixation_durations_s(t, labels, ids), strict=True)) if len(t) > 1 else {}
    given = fixations.get("duration_s")
    if given is not None:
        for fid, d in zip(fixations["fixation_id"], given, strict=True):
            if int(fid) not in times and np.isfinite(d):
                times[int(fid)] = float(d)
    return times


def _own_point(fixations: dict, i: int) -> np.ndarray:
    return np.array([fixations[k][i] for k in ("x_mm", "y_mm", "z_mm")], float)


def _own_covariance(fixations: dict, i: int) -> np.ndarray:
    C = np.empty((3, 3))
    for name, (a, b) in zip(COV_COLUMNS, COV_INDEX, strict=True):
        C[a, b] = C[b, a] = fixations[name][i]
    return C


AOI_PLOTS = {"aoi_dwell.png": "Dwell time per area of interest: over the fixations assigned to it, and weighted "
                              "by each fixation's probability of it (docs/aois.md)",
             "aoi_timeline.png": "Which area of interest when: each fixation in the row of each area it may lie in, "
                                 "as dark as its probability of it; outlined where it is assigned"}
"""The AOI step's plots, with the captions the report gives them."""
AOI_OUTPUTS = ("aoi_fixations.csv", "aoi_metrics.csv", "aoi_transitions.csv", *AOI_PLOTS)
"""What ``aoi_folder`` writes."""


def check_aois(specs, aois_path, has_marker_map: bool) -> None:
    """Refuse marker areas (``specs``: ``read_aois``'s of ``aois_path``) for a session tracked in
    no marker map.

    Raises:
        UserError: marker areas without a map to place them.
    """
    named = [s.name for s in specs if s.kind in ("marker", "markers")]
    if named and not has_marker_map:
        raise UserError(f"--aois {aois_path}: area(s) {', '.join(named)} name markers, but this session's head "
                        "poses come from no marker map; give those areas as boxes or polygons in its world")


def mesh_paths(specs) -> list[Path]:
    """The mesh files of an AOI file's areas (``specs``), what their geometry also depends on."""
    return [s.mesh_path for s in specs if s.mesh_path is not None]


def session_marker_map(processed: Path, markers=None):
    """The marker map for marker areas: ``markers`` when given, else the processed session's own
    (``summary.json``'s session folder's markers.json), else None."""
    if markers is not None:
        return load_marker_map(markers)
    summary = Path(processed) / "summary.json"
    if summary.is_file():
        session = json.loads(summary.read_text(encoding="utf-8")).get("session")
        if session and (Path(session) / "markers.json").is_file():
            return load_marker_map(Path(session) / "markers.json")
    return None


def aoi_folder(processed, aois_path, out=None, markers=None, conf: AoiConfig = AoiConfig()) -> AoiResult:
    """The AOI step on a processed folder (fixations.csv, viewlines.csv, targets.json): reads the areas of
    ``aois_path`` (marker areas placed by ``markers`` or the session's map), writes
    ``AOI_OUTPUTS`` into ``out`` (default: the processed folder) and returns the result."""
    return aoi_step(processed, read_aois(aois_path), out, markers, conf)


def aoi_step(processed, specs, out=None, markers=None, conf: AoiConfig = AoiConfig()) -> AoiResult:
    """``aoi_folder`` with the AOI file's areas already read (``specs``: ``read_aois``'s)."""
    processed = Path(processed)
    out = Path(out) if out is not None else processed
    needs_map = any(s.kind in ("marker", "markers") for s in specs)
    areas = areas_of(list(specs), session_marker_map(processed, markers) if needs_map else None)
    segments = read_viewlines_csv(processed / "viewlines.csv")
    t = np.concatenate([s.samples.t_s for s in segments])
    fixations = fixation_gaze(read_fixations_csv(processed / "fixations.csv"), segments,
                              read_targets(processed / "targets.json"))
    interval = lines_interval_s(segments)
    end = float(t.max()) + (interval if np.isfinite(interval) else 0.0)
    res = run(conf, AoiInputs(areas, fixations, float(t.min()), end))
    out.mkdir(parents=True, exist_ok=True)
    names = [res.names[a] if a >= 0 else NONE for a in res.assigned]
    write_aoi_fixations(out / "aoi_fixations.csv", {
        "fixation_id": [f.fixation_id for f in fixations], "start_s": [f.start_s for f in fixations],
        "end_s": [f.end_s for f in fixations], "duration_s": [f.duration_s for f in fixations],
        "target_id": [f.target_id for f in fixations], "aoi": names,
        "probabilities": res.probabilities}, res.names)
    write_aoi_metrics(out / "aoi_metrics.csv", res.metrics)
    write_aoi_transitions(out / "aoi_transitions.csv", res.transitions)
    plot_dwell(res.metrics, out / "aoi_dwell.png")
    plot_timeline([*res.names, NONE], res, fixations, out / "aoi_timeline.png")
    return res


def format_metrics(res: AoiResult, conf: AoiConfig = AoiConfig()) -> str:
    """The per-area table ``wearable-gaze aoi`` prints (``conf``: the settings it was found with)."""
    lines = [f"{'aoi':<16} {'dwell s':>8} {'weighted':>8} {'visits':>6} {'fix':>4} {'first s':>8} {'share':>6}"]
    for m in res.metrics:
        first = f"{m['first_fixation_s']:.2f}" if np.isfinite(m["first_fixation_s"]) else "-"
        lines.append(f"{m['aoi'][:16]:<16} {m['dwell_s']:>8.2f} {m['dwell_weighted_s']:>8.2f} {m['visits']:>6} "
                     f"{m['fixations']:>4} {first:>8} {m['share']:>6.1%}")
    unassigned = int(np.sum(res.assigned < 0))
    lines.append(f"{len(res.assigned)} fixations, {unassigned} in no area (below "
                 f"{conf.assign_probability:.0%} in any)")
    return "\n".join(lines)


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"AOI_COLOUR": "AOI_COLOR"})
