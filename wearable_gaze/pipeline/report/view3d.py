"""The report's 3D view the reader can turn (docs/processing.md, "The report"): the room's
marker map, the head path, each target's fan of view lines, its estimate with its 95 % credible
region (``regions``: its depth interval along the line of sight and its lateral extent, cut at
the box of the head path and the targets with an arrow, dashed where it has no far end; the 95 %
ellipsoid only for a target without one) and, for a simulated session, the truth. One HTML
block, self-contained: the scene as JSON and the viewer (``view3d.js``, package data: canvas 2D,
no library, no network, no GPU) inlined. World frame of the marker map, mm.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass
from importlib import resources

import numpy as np

from estimator.deprecation import renamed_kwargs

from .regions import RegionLines

MAX_HEAD_POINTS = 1500       # the head path is thinned to at most this many points
MAX_LINES = 40               # view lines drawn per target
MAX_ROOM_POINTS = 3000       # a markerless map's points are thinned to at most this many


@renamed_kwargs({"colour": "color"})
@dataclass(frozen=True)
class SceneTarget:
    """One target as the 3D view draws it (world frame, mm).

    Attributes:
        index: the target's number (as in the table and the plots).
        color: its colour, '#rrggbb' (as in the plots' legends).
        position_mm: (3,) the estimate; NaN none.
        ellipsoid_mm: (3, 3) the 95 % ellipsoid's semi-axes as rows (vectors, mm), or None.
        lines_mm: (K, 2, 3) view lines drawn, each from the eye to the target's distance.
        path_mm: (K, 3) a moving target's path, or None.
        truth_mm: (3,) the true position (simulated session), or None.
        truth_path_mm: (K, 3) the true path of a moving target, or None.
        region: its 95 % credible region as lines in the view's box (``regions.RegionLines``), or
            None (then its ellipsoid is drawn).
    """

    index: int
    color: str
    position_mm: np.ndarray
    ellipsoid_mm: np.ndarray | None
    lines_mm: np.ndarray
    path_mm: np.ndarray | None = None
    truth_mm: np.ndarray | None = None
    truth_path_mm: np.ndarray | None = None
    region: RegionLines | None = None


def _mm(a) -> list | None:
    """A JSON-ready array rounded to 1 mm (None stays None, NaN rows become None)."""
    if a is None:
        return None
    a = np.asarray(a, float)
    if a.ndim == 1:
        return [round(float(v)) for v in a] if np.all(np.isfinite(a)) else None
    return [_mm(r) for r in a if np.all(np.isfinite(r))]


def _thin(P, n: int) -> np.ndarray:
    """At most ``n`` of the rows of ``P``, evenly spaced, the last included."""
    P = np.asarray(P, float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) <= n:
        return P
    return P[np.unique(np.linspace(0, len(P) - 1, n).round().astype(int))]


def _region(r: RegionLines | None) -> dict | None:
    """A region's lines, JSON-ready (mm): ``rings`` (closed polylines), ``sides`` and ``axis``
    (segments), ``open`` (no far end: dashed), ``cut`` (an arrow at the axis's end: it runs on past
    the box), the interval ``near_mm``, ``far_mm`` (null: none) and the drawn end ``end_mm``."""
    if r is None:
        return None
    return {"rings": [_mm(p) for p in r.rings], "sides": [_mm(s) for s in r.sides], "axis": _mm(r.axis),
            "open": bool(r.open), "cut": bool(r.cut), "near_mm": round(r.near_mm),
            "far_mm": round(r.far_mm) if np.isfinite(r.far_mm) else None, "end_mm": round(r.end_mm)}


def scene(targets: list, head_mm, markers_mm=None, truth_head_mm=None, other_truth=(), points_mm=None,
          box=None, aois=()) -> dict:
    """The 3D view's scene (JSON-ready, mm).

    Args:
        targets: ``SceneTarget``s.
        head_mm: (M, 3) the head (scene camera) positions over time.
        markers_mm: (K, 4, 3) the map's markers' corners, or None.
        truth_head_mm: (M', 3) the true head path (simulated session), or None.
        other_truth: (label, position (3,)) true targets no estimate matched.
        points_mm: (P, 3) the room's points (a markerless map's, ``process --map``), or None.
        box: (lo (3,), hi (3,)) mm, what the view is scaled to (``regions.scene_box``), or None
            (the viewer takes the head path and the targets).
        aois: (name, colour, segments (K, 2, 3) mm) the areas of interest's outlines.
    """
    markers = [] if markers_mm is None else [{"corners": _mm(c)} for c in np.asarray(markers_mm, float)]
    return {
        "units": "mm", "up": [0.0, -1.0, 0.0], "origin": [0.0, 0.0, 0.0], "markers": markers,
        "box": None if box is None else [_mm(box[0]), _mm(box[1])],
        "head": _mm(_thin(head_mm, MAX_HEAD_POINTS)),
        "truth_head": None if truth_head_mm is None else _mm(_thin(truth_head_mm, MAX_HEAD_POINTS)),
        "targets": [{
            "index": int(t.index), "colour": t.color, "label": f"target {t.index}",
            "position": _mm(t.position_mm),
            "ellipsoid": None if t.ellipsoid_mm is None or not np.all(np.isfinite(t.ellipsoid_mm))
            else [[round(float(v), 1) for v in r] for r in t.ellipsoid_mm],
            "lines": [[_mm(a), _mm(b)] for a, b in np.asarray(t.lines_mm, float).reshape(-1, 2, 3)[:MAX_LINES]
                      if np.all(np.isfinite(a)) and np.all(np.isfinite(b))],
            "path": None if t.path_mm is None else _mm(_thin(t.path_mm, 300)),
            "truth": _mm(t.truth_mm),
            "truth_path": None if t.truth_path_mm is None else _mm(_thin(t.truth_path_mm, 300)),
            "region": _region(t.region),
        } for t in targets],
        "other_truth": [{"label": label, "position": _mm(p)} for label, p in other_truth],
        "points": [] if points_mm is None else _mm(_thin(points_mm, MAX_ROOM_POINTS)),
        "aois": [{"name": name, "colour": color, "segments": [[_mm(a), _mm(b)] for a, b in segs]}
                 for name, color, segs in aois],
    }


def viewer_script() -> str:
    """The viewer, ``view3d.js`` (package data)."""
    return resources.files("wearable_gaze.pipeline.report").joinpath("view3d.js").read_text(encoding="utf-8")


def html_block(scene_data: dict, has_truth: bool, world: str = "the marker map's world") -> str:
    """The 3D view as an HTML block: a canvas (id ``view3d``), layer switches, a legend in the
    targets' colours, the scene as JSON and the viewer inlined (``</`` escaped so no string in
    the data can end the script). ``world``: what its frame is, in words."""
    data = json.dumps(scene_data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    layers = [("markers", "the room (markers, map points)"), ("head", "head path"), ("lines", "view lines"),
              ("regions", "95 % credible regions")] + ([("truth", "truth")] if has_truth else []) \
        + ([("aois", "areas of interest")] if scene_data.get("aois") else [])
    boxes = " ".join(f'<label><input type="checkbox" data-layer="{k}" checked> {html.escape(v)}</label>'
                     for k, v in layers)
    legend = " ".join(f'<span class="swatch" style="background:{t["colour"]}"></span>{html.escape(t["label"])}'
                      for t in scene_data["targets"])
    aois = (" Teal outlines: the areas of interest (docs/aois.md), each with its name." if scene_data.get("aois")
            else "")
    truth = (" Squares: the true targets, a dashed line to each one's estimate; dashed black: the true head path."
             if has_truth else "")
    return f"""<h2>3D view</h2>
<p>Drag to turn, shift-drag (or drag with the right button) to pan, wheel to zoom, double-click to reset.
Positions in {html.escape(world)}, mm; up is &minus;y. Black: the head path; thin lines:
view lines (every few), from the eye to the target's distance; dots: each target's estimate; cones: its 95 %
credible region, its 95 % interval of distance along the line of sight (symmetric in inverse depth: longer
on the far side) by its 95 % lateral extent, its near end's and far end's cross-sections and four edges;
dashed: no far end; an arrow: it runs on past the box of the head path and the targets the view is scaled
to (the table gives its ends; a target without a region: its 95 % ellipsoid, three principal sections); the
axes x, y, z (dark grey), 300 mm long, at the world's origin.{aois}{truth}</p>
<p class="legend">{legend}</p>
<p>{boxes}</p>
<canvas id="view3d" style="width:100%;height:560px;border:1px solid #ccc;touch-action:none"></canvas>
<script type="application/json" id="view3d-data">{data}</script>
<script>
{viewer_script()}
</script>
"""
