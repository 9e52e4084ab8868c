"""The processing report, report.html (docs/processing.md, "The report"): the targets' table
(beside the truth when the session is simulated), the 3D view (``view3d``), the overlay
(``overlay``) and the plots (``report_plots``), from the outputs of the earlier steps.

One numbering of the targets everywhere: target k is ``Target.index`` k of targets.json, drawn
in ``colour(k)`` in the table, the plots, the 3D view and the overlay's labels.
"""

from __future__ import annotations

import html
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator import BinocularSamples, fisher_information
from estimator.deprecation import module_getattr, renamed_kwargs
from estimator.errormodel import K95  # the 95 % ellipsoid's semi-axes over the standard deviations
from tracking.markermap import MarkerMap

from ...formats.atomic import write_text
from ...formats.poses import read_poses_csv
from ...formats.targets import (
    read_device_comparison,
    read_estimates,
    read_target_labels,
    read_target_paths,
    read_targets,
    record_region,
)
from ...formats.truth import read_truth_targets
from ...formats.viewlines import read_viewlines_csv
from ..steps.aoi import AOI_PLOTS
from ..steps.target_status import status_note
from ..types import Target
from . import plots as report_plots
from . import view3d
from .overlay import (
    PREVIEW_FPS,
    PREVIEW_NAME,
    PREVIEW_WIDTH,
    VIDEO_NAME,
    OverlayInputs,
    OverlayTargets,
    caption,
    write_overlays,
)
from .plots import _plt, _save  # noqa: F401  (maps/markers.py's map plot uses them)
from .regions import anchor_points, region_lines, scene_box
from .timeline import plot_depth_over_time
from .truth_match import match_positions

log = logging.getLogger(__name__)

PLOTS = report_plots.PLOTS
REPORT_FILES = ("report.html", *PLOTS, PREVIEW_NAME, VIDEO_NAME, "overlay_error.txt")   # all write_report writes
OPTIONAL_FILES = (PREVIEW_NAME, VIDEO_NAME, "overlay_error.txt")                        # ... not always
COLORS = report_plots.COLORS

__all__ = ["OverlayInputs", "ReportTruth", "write_report", "load_truth", "REPORT_FILES", "PLOTS"]


def session_title(root: Path) -> str:
    """The report's name of a session: its folder with its parent's ('study/P01', 'demo-.../session'),
    as a folder named 'session' or 's1' alone names nothing."""
    return "/".join(Path(root).resolve().parts[-2:])


def color(index: int) -> str:
    """Target ``index``'s colour, '#rrggbb', the same in every plot, the table and the 3D view."""
    return COLORS[int(index) % len(COLORS)]


@dataclass(frozen=True)
class ReportTruth:
    """A simulated session's truth, for the report (world frame, mm).

    Attributes:
        targets: truth/targets.json's targets (``formats.truth``): ``index``, ``position_mm``
            or, moving, ``path_t_s`` and ``path_mm``.
        head_mm: (M, 3) the true head (scene camera) positions, or None.
    """

    targets: list
    head_mm: np.ndarray | None = None


def load_truth(targets_path, head_poses_path=None) -> ReportTruth | None:
    """The truth of a simulated session from its truth/targets.json and truth/head_poses.csv
    (either None: not there); None without targets."""
    if targets_path is None or not Path(targets_path).is_file():
        return None
    head = None
    if head_poses_path is not None and Path(head_poses_path).is_file():
        T = read_poses_csv(head_poses_path, text_columns=())[2]
        head = T[np.isfinite(T[:, 0, 0]), :3, 3]
    return ReportTruth(read_truth_targets(targets_path), head)


@renamed_kwargs({"centre": "center"})
@dataclass(frozen=True)
class ReportData:
    """What the report reads from the processing outputs (world frame, mm).

    Attributes:
        targets: the targets of targets.json.
        samples: the view lines (N,), sorted by time; tlabels (N,): target index, -1 none;
            flabels (N,): fixation index, -1 none.
        head: (M, 3) head positions with a pose; centre (3,): their mean.
        est: the running estimates (estimates.csv columns).
        orig, cyc: (N, 3) each sample's origin and direction (left eye, else right).
        paths: the moving targets' paths (target_paths.csv): {index: (t (K,), positions (K, 3),
            covariances (K, 3, 3))}; {} without the file.
        truth: {target index: its truth entry} for the targets matched with a true one.
        unmatched: the true targets no estimate matched.
        regions: {target index: its 95 % credible region (``estimator.region.CredibleRegion``,
            from its record: ``formats.targets.record_region``)} for the static targets that
            have one.
    """

    targets: list
    samples: BinocularSamples
    tlabels: np.ndarray
    flabels: np.ndarray
    head: np.ndarray
    center: np.ndarray
    est: dict
    orig: np.ndarray
    cyc: np.ndarray
    paths: dict
    truth: dict
    unmatched: list
    regions: dict = field(default_factory=dict)

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo (3,), hi (3,)) mm, the box the views are scaled to (``regions.scene_box``): the
        head path, the static targets' points, the moving ones' paths, the truth, and the near
        end of each region that has no point; never the regions' far ends nor the ellipsoids."""
        static = [t.position_mm for t in self.targets if t.index not in self.paths]
        truth = [np.asarray(tt[k], float) for tt in [*self.truth.values(), *self.unmatched]
                 for k in ("position_mm", "path_mm") if k in tt]
        pointless = [r for k, r in self.regions.items()
                     if not any(t.index == k and np.all(np.isfinite(t.position_mm)) for t in self.targets)]
        return scene_box(self.head, np.reshape(static, (-1, 3)), *(p[1] for p in self.paths.values()), *truth,
                         anchor_points(pointless))

    def head_travel_mm(self, tg) -> list[float]:
        """How far the head moved during each of target ``tg``'s fixations, mm: the largest
        distance of the eyes' origin from where it was at the fixation's first sample (the
        baseline a 2D-only tracker's depth comes from)."""
        out = []
        for f in tg.fixations:
            o = self.orig[self.flabels == f]
            o = o[np.all(np.isfinite(o), axis=1)]
            if len(o):
                out.append(float(np.max(np.linalg.norm(o - o[0], axis=1))))
        return out

    def distance_m(self, tg) -> float:
        """Target ``tg``'s distance from the eyes while it was looked at, m: the median over its own
        samples' origins (the head's mean position when it has none). The mean position over a
        walking session is no place the person looked from (the real Aria sample: 0.76 m, against
        2.1 m from where the target was looked at)."""
        o = self.orig[self.tlabels == tg.index]
        o = o if len(o) else self.center[None]
        return float(np.median(np.linalg.norm(np.asarray(tg.position_mm) - o, axis=1)) / 1000)

    def ellipsoid(self, tg) -> np.ndarray | None:
        """(3, 3) target ``tg``'s 95 % ellipsoid semi-axes as rows (vectors, mm, ascending
        length), or None. The lengths are targets.json's; the directions the covariance's when
        the target has one, else those of its view lines' Fisher information (the estimators'
        covariances share them: long along the lines, short across)."""
        a = np.asarray(tg.axes95_mm, float)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(tg.position_mm))):
            return None
        if tg.covariance_mm2 is not None:
            w, V = np.linalg.eigh(np.asarray(tg.covariance_mm2, float))
            return (V * (K95 * np.sqrt(np.clip(w, 0, None)))).T
        origins = self.orig[self.tlabels == tg.index]
        if len(origins) < 2:
            return None
        V = np.linalg.eigh(fisher_information(tg.position_mm, origins, 1.0))[1][:, ::-1]   # ascending variance
        return (V * a).T


def report_data(out: Path, T_p: np.ndarray, truth: ReportTruth | None = None) -> ReportData:
    """The outputs in ``out`` read for the report; ``T_p`` (M, 4, 4) the head poses."""
    records = read_targets(out / "targets.json")
    targets = [Target.from_row(r) for r in records]
    segments = read_viewlines_csv(out / "viewlines.csv")
    samples = BinocularSamples.concatenate([s.samples for s in segments])
    flabels = np.concatenate([np.full(len(s.samples), s.key if isinstance(s.key, int) else -1) for s in segments])
    order = np.argsort(samples.t_s, kind="stable")
    samples, flabels = samples.select(order), flabels[order]
    labels = out / "target_labels.npy"
    tlabels = read_target_labels(labels) if labels.is_file() else np.full(len(samples), -1)
    head = T_p[np.isfinite(T_p[:, 0, 0]), :3, 3]
    est = read_estimates(out / "estimates.csv")
    cyc = samples.left_direction.copy()
    cyc[~samples.left_valid] = samples.right_direction[~samples.left_valid]
    orig = np.where(samples.left_valid[:, None], samples.left_origin_mm, samples.right_origin_mm)
    paths = read_target_paths(out / "target_paths.csv") if (out / "target_paths.csv").is_file() else {}
    matched, unmatched = match_truth(targets, paths, truth)
    regions = {t.index: record_region(r) for t, r in zip(targets, records, strict=True) if t.index not in paths}
    return ReportData(targets, samples, tlabels, flabels, head, head.mean(axis=0) if len(head) else np.zeros(3), est,
                      orig, cyc, paths, matched, unmatched, {k: r for k, r in regions.items() if r is not None})


def match_truth(targets: list, paths: dict, truth: ReportTruth | None) -> tuple[dict, list]:
    """({target index: truth entry}, [unmatched truth entries]): each true fixed target paired
    with the nearest static estimate as the demo pairs them (``truth_match.match_positions``); each
    true moving target with the moving target whose time overlaps its fixations most."""
    if truth is None:
        return {}, []

    static = [t for t in targets if t.index not in paths and np.all(np.isfinite(t.position_mm))]
    matched, unmatched = {}, []
    for tt, k in match_positions([t.position_mm for t in static], truth.targets, [t.index for t in static]):
        if k is None:
            unmatched.append(tt)
        else:
            matched[static[k].index] = tt
    for tt in truth.targets:
        if "position_mm" in tt or "path_mm" not in tt:
            continue
        overlap = {t.index: sum(max(0.0, min(b, t.t_end) - max(a, t.t_start)) for a, b in tt["fixations_s"])
                   for t in targets if t.index in paths and t.index not in matched}
        best = max(overlap, key=lambda i: overlap[i], default=None)
        if best is not None and overlap[best] > 0:
            matched[best] = tt
        else:
            unmatched.append(tt)
    return matched, unmatched


def truth_error(d: ReportData, tg) -> tuple[np.ndarray | None, float]:
    """(the true position (3,) or None, the error, mm): a static target's distance from its
    true point; a moving one's RMS distance from the true path at its path's knots."""
    tt = d.truth.get(tg.index)
    if tt is None:
        return None, float("nan")
    if "position_mm" in tt:
        X = np.asarray(tt["position_mm"], float)
        return X, float(np.linalg.norm(tg.position_mm - X))
    t, P, _ = d.paths[tg.index]
    tp, Pt = np.asarray(tt["path_t_s"], float), np.asarray(tt["path_mm"], float)
    true_at = np.column_stack([np.interp(t, tp, Pt[:, m]) for m in range(3)])
    mid = np.array([np.interp(0.5 * (tg.t_start + tg.t_end), tp, Pt[:, m]) for m in range(3)])
    return mid, float(np.sqrt(np.mean(np.sum((P - true_at) ** 2, axis=1))))


def write_report(out: Path, title: str, overlay=None, progress=None, notes=(), truth: ReportTruth | None = None,
                 marker_map: MarkerMap | None = None, overlay_video: bool = False, room_points_mm=None,
                 world: str = "the marker map's world", aois=()) -> None:
    """The plots (``PLOTS``), the overlay and report.html in ``out``, from the outputs of the
    earlier steps there. ``title``: the session's name. ``overlay``: None (no overlay),
    or a function returning its ``OverlayInputs`` (called here: a failure to load them, like any
    failure of the overlay, is written to overlay_error.txt and the report made without it);
    ``overlay_video``: also the full-resolution overlay_full.mp4. ``notes``: sentences the reader
    must see first (where the head poses came from, ...). ``truth``: a simulated session's
    truth, shown beside every estimate. ``marker_map``: the room's markers for the 3D view;
    ``room_points_mm``: (P, 3) its points (a markerless map's or the device's, world mm), or None.
    ``world``: what the positions are in, in words (``device.world_words``); ``aois``: the areas of
    interest's outlines for the 3D view (``aoi.aoi_outlines``)."""
    out = Path(out)
    t_p, frame_p, T_p, _ = read_poses_csv(out / "poses.csv")
    d = report_data(out, T_p, truth)
    images = report_plots.write_plots(d, out, color, truth) + [plot_depth_over_time(d, out, color)]
    images += [(n, c) for n, c in AOI_PLOTS.items() if (out / n).is_file()]
    if progress:
        progress(3, 5)
    names: tuple[str | None, str | None] = (None, None)
    for name in OPTIONAL_FILES:                 # an earlier run's: this report may have neither
        (out / name).unlink(missing_ok=True)
    if overlay is not None:
        try:
            targets = OverlayTargets(d.targets, d.samples.t_s, d.tlabels, d.paths)
            names = write_overlays(out, overlay(), targets, t_p, frame_p, T_p, overlay_video)
        except Exception as exc:  # a report without a video is still a report
            write_text(out / "overlay_error.txt", f"{type(exc).__name__}: {exc}\n")
    if progress:
        progress(4, 5)
    block = view3d.html_block(_scene(d, truth, marker_map, room_points_mm, aois), bool(d.truth or d.unmatched),
                              world)
    _html(out, title, d, images, names, notes, _device_rows(out), block)


def _scene(d: ReportData, truth: ReportTruth | None, marker_map: MarkerMap | None, points_mm=None,
           aois=()) -> dict:
    """The 3D view's scene: the map's markers (and a markerless map's points), the head path, per
    target its lines, estimate, credible region (its ellipsoid when it has none), path and truth,
    and the box the view is scaled to."""
    from .plots import line_segments

    targets, (lo, hi) = [], d.box()
    for tg in d.targets:
        tt = d.truth.get(tg.index, {})
        lines = np.array([[a, b] for a, b in line_segments(tg, d, every=1)]).reshape(-1, 2, 3)
        if len(lines) > view3d.MAX_LINES:
            lines = lines[np.linspace(0, len(lines) - 1, view3d.MAX_LINES).round().astype(int)]
        targets.append(view3d.SceneTarget(
            tg.index, color(tg.index), tg.position_mm,
            None if tg.index in d.paths or tg.index in d.regions else d.ellipsoid(tg), lines,
            d.paths[tg.index][1] if tg.index in d.paths else None,
            np.asarray(tt["position_mm"], float) if "position_mm" in tt else None,
            np.asarray(tt["path_mm"], float) if "path_mm" in tt else None,
            region_lines(d.regions[tg.index], lo, hi) if tg.index in d.regions else None))
    corners = [marker_map.corners(i) for i in marker_map.poses] if marker_map is not None else None
    others = [(f"true target {tt['index']} (not found)", tt["position_mm"]) for tt in d.unmatched
              if "position_mm" in tt]
    return view3d.scene(targets, d.head, corners, truth.head_mm if truth is not None else None, others, points_mm,
                        (lo, hi), aois)


def _device_rows(out: Path) -> str:
    """The table of device_comparison.csv (an imported session's targets beside the device's own
    3D gaze), or '' without one."""
    path = out / "device_comparison.csv"
    if not path.is_file():
        return ""
    tab = read_device_comparison(path)
    rows = "".join(f"<tr><td>{int(k)}</td><td>{int(n)}</td><td>{a:.0f}</td><td>{b:.0f}</td></tr>"
                   for k, n, a, b in zip(tab["target"], tab["n_samples"], tab["ours_distance_mm"],
                                         tab["device_depth_mm"], strict=True))
    return ("<h2>Beside the device's own 3D gaze</h2><p>Distance from the head to each target: ours from the view "
            "lines integrated over the head's motion, the device's from its per-sample vergence depth (median over "
            "the target's samples).</p><table><tr><th>target</th><th>samples</th><th>ours (mm)</th>"
            f"<th>device (mm)</th></tr>{rows}</table>")


def _cells(*values, fmt: str = "{:.0f}") -> str:
    """Table cells of numbers ('&ndash;' for a missing one)."""
    return "".join(f"<td>{fmt.format(v)}</td>" if v is not None and np.isfinite(v) else "<td>&ndash;</td>"
                   for v in values)


def _target_rows(d: ReportData) -> tuple[str, str]:
    """(header, rows) of the targets' table: each estimate, and beside it the truth, the error
    and the error over the Cramér-Rao bound and over the predicted standard deviation when the
    session has a truth."""
    has_truth = bool(d.truth or d.unmatched)
    head = ("<tr><th>target</th><th>position x, y, z (mm)</th><th>distance from the head (m)</th>"
            "<th>distance from where it was seen (m): estimate (68 % / 95 % intervals)</th>"
            "<th>95 % semi-axes (mm)</th><th>samples</th>"
            "<th>time (s)</th><th>dwell (s)</th><th>fixations</th><th>head travel in each fixation (mm)</th>"
            "<th>Cramér-Rao bound (mm)</th><th>predicted sd (mm)</th>"
            + ("<th>true position x, y, z (mm)</th><th>error (mm)</th><th>error / bound</th>"
               "<th>error / predicted sd</th>" if has_truth else "") + "<th>status</th></tr>")
    rows = []
    for t in d.targets:
        sd = float(np.sqrt(np.sum(np.asarray(t.axes95_mm) ** 2)) / K95)
        dist = d.distance_m(t)
        cells = (f'<td><span class="swatch" style="background:{color(t.index)}"></span>{t.index}</td>'
                 f"<td>{_position(t)}</td>" + _cells(dist, fmt="{:.2f}") + f"<td>{_intervals(t)}</td>"
                 + f"<td>{_xyz(t.axes95_mm, ' / ')}</td><td>{t.n_samples}</td><td>{t.t_start:.1f}&ndash;{t.t_end:.1f}"
                 f"</td>" + _cells(t.dwell_s, fmt="{:.1f}")
                 + f"<td>{html.escape(', '.join(map(str, t.fixations)))}</td>"
                 f"<td>{', '.join(f'{v:.0f}' for v in d.head_travel_mm(t))}</td>" + _cells(t.crb_mm, sd))
        if has_truth:
            X, err = truth_error(d, t)
            what = "path's middle; error: RMS over the path" if t.index in d.paths else ""
            cells += (f"<td>{_xyz(X) if X is not None else 'no true target near'}"
                      f"{'<br><small>' + what + '</small>' if X is not None and what else ''}</td>"
                      + _cells(err, fmt="{:.1f}") + _cells(err / t.crb_mm if t.index not in d.paths else None,
                                                           err / sd if t.index not in d.paths else None,
                                                           fmt="{:.2f}"))
        note = status_note(t.status)
        rows.append(f'<tr>{cells}<td><span class="status">{html.escape(t.status)}</span>'
                    f"{'<br><small>' + html.escape(note) + '</small>' if note else ''}</td></tr>")
    for tt in d.unmatched:
        X = tt.get("position_mm")
        rows.append(f"<tr><td>&ndash;</td><td>not found</td>{'<td></td>' * 10}"
                    f"<td>{_xyz(X) if X is not None else 'a moving target'} (true target {tt['index']})</td>"
                    f"{'<td></td>' * 3}<td>not found</td></tr>")
    return head, "".join(rows)


def _position(t) -> str:
    """A target's position cell: its point, mm, or a direction-only target's direction (world
    frame) and 95 % cone."""
    if np.all(np.isfinite(t.position_mm)) or t.direction is None:
        return _xyz(t.position_mm)
    u = t.direction.unit
    return (f"direction {u[0]:.3f}, {u[1]:.3f}, {u[2]:.3f}<br><small>95 % cone {t.direction.cone95_deg:.2f}&deg;; "
            "no point</small>")


def _intervals(t) -> str:
    """A target's distance from where it was seen (its view lines' mean origin), m, and its 68 %
    and 95 % intervals, symmetric in inverse depth (``Target.depth_interval``; '&infin;': no far
    end); a direction-only target's 95 % interval along its direction; '&ndash;' without the
    error model's."""
    if t.sight is None and t.direction is not None and not np.all(np.isfinite(t.position_mm)):
        near, far = t.direction.depth95_mm
        return (f"no point; 95 %: {near / 1000:.2f}&ndash;" + (f"{far / 1000:.2f}" if np.isfinite(far) else "&infin;"))
    parts = []
    for p in (0.68, 0.95):
        near, far = t.depth_interval(p)
        if t.sight is None or not np.isfinite(near):
            return "&ndash;"
        parts.append(f"{near / 1000:.2f}&ndash;" + (f"{far / 1000:.2f}" if np.isfinite(far) else "&infin;"))
    assumed = f"<br><small>assumes: {html.escape(t.depth_assumption)}</small>" if t.depth_assumption else ""
    return f"{t.sight.distance_mm(t.position_mm) / 1000:.2f} ({' / '.join(parts)}){assumed}"


def _count(targets: list) -> str:
    """The sentence counting the fixated targets (``Target.fixated``) and the others listed."""
    n = sum(t.fixated for t in targets)
    rest = len(targets) - n
    return f"{n} fixated target(s)" + (f"; {rest} more listed that are no target (status)." if rest else ".")


def _xyz(v, sep: str = ", ") -> str:
    return sep.join(f"{x:.0f}" if np.isfinite(x) else "&ndash;" for x in np.asarray(v, float))


def _truth_summary(d: ReportData) -> str:
    """One sentence: how far the static estimates are from the truth, against their bounds."""
    pairs = [(truth_error(d, t)[1], t.crb_mm) for t in d.targets if t.index in d.truth and t.index not in d.paths]
    pairs = [(e, b) for e, b in pairs if np.isfinite(e) and np.isfinite(b)]
    if not pairs:
        return ""
    e, b = np.array(pairs).T
    return (f"<p>Simulated session: {len(pairs)} fixed target(s) beside the truth; RMS error "
            f"{np.sqrt(np.mean(e ** 2)):.1f} mm, RMS Cramér-Rao bound {np.sqrt(np.mean(b ** 2)):.1f} mm, their ratio "
            f"{np.sqrt(np.mean(e ** 2) / np.mean(b ** 2)):.2f} (1 is the best any unbiased estimator can do; the "
            f"bound counts only the eye noise, the predicted sd also the error model's bias and pose terms)."
            f"{' Not found: ' + str(len(d.unmatched)) + ' true target(s).' if d.unmatched else ''}</p>")


def _html(out: Path, name: str, d: ReportData, images, names, notes, device_table: str, block3d: str) -> None:
    head, rows = _target_rows(d)
    imgs = "".join(f'<figure><img src="{html.escape(n)}" alt="{html.escape(c)}"><figcaption>{html.escape(c)}'
                   f"</figcaption></figure>" for n, c in images)
    preview, video = names
    link = f'<p>Full resolution, every frame: <a href="{video}">{video}</a> (H.264).</p>' if video else ""
    overlay = (f'<h2>Overlay</h2><video id="overlay" src="{preview}" controls muted playsinline preload="auto" '
               f'width="{PREVIEW_WIDTH}"></video><p>{caption()} The whole session, {PREVIEW_FPS:g} frames a second '
               "(H.264).</p>" + link if preview else "<p>No overlay video.</p>" + link)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>wearable-gaze report: {html.escape(str(name))}</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em}}img{{max-width:100%}}
table{{border-collapse:collapse;font-size:90%}}td,th{{border:1px solid #ccc;padding:4px 8px}}figure{{margin:1em 0}}
.swatch{{display:inline-block;width:.9em;height:.9em;margin:0 .3em 0 .8em;vertical-align:middle}}
td .swatch{{margin-left:0}}</style></head>
<body><h1>Gaze targets: {html.escape(str(name))}</h1>
{"".join(f"<p><b>{html.escape(n)}</b></p>" for n in notes)}
<p>{_count(d.targets)} Positions in the world frame{"" if notes else " of the marker map"}, mm;
distances from the eyes while the target was looked at (median). Each target keeps its number and colour
in every table, plot and view.</p>
{_truth_summary(d)}
<table id="targets">{head}{rows}</table>
{device_table}
{block3d}
{overlay}
<h2>Plots</h2>{imgs}
<script>
// after loading, record how many images actually loaded (tests read it from a headless browser)
window.addEventListener("load", () => {{
  const im = Array.from(document.images);
  document.body.dataset.images = im.filter(i => i.complete && i.naturalWidth > 0).length + "/" + im.length;
}});
</script>
</body></html>
"""
    write_text(out / "report.html", page)


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"colour": "color", "COLOURS": "COLORS"})
