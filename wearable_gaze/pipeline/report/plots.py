"""The report's plots (matplotlib, no display needed): the running estimates' depth, the
likelihood around each target, a 3D and a top view; each target in its colour and number, the
truth beside it when the session has one. ``d`` is the report's ``report.ReportData``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator import angular_log_likelihood
from estimator.deprecation import module_getattr, renamed_kwargs
from estimator.errormodel import K95

from ...formats.atomic import atomic_path
from .regions import region_lines

PLOTS = ("plot_depth_vs_observations.png", "plot_density_slices.png", "plot_3d.png", "plot_top_view.png",
         "plot_depth_over_time.png")
COLORS = ["#be0032", "#0067a5", "#008856", "#f38400", "#875692", "#882d17", "#e68fac", "#2b3d26", "#f3c300",
           "#a1caf1", "#8db600", "#604e97", "#f99379", "#654522", "#dcd300", "#b3446c", "#e25822", "#c2b280",
           "#848482", "#f6a600"]
"""The targets' colours: Kelly's 20 colours of maximum contrast (K. L. Kelly, "Twenty-two colors of
maximum contrast", Color Engineering 3(6), 1965; without his white and black), the strongest first;
distinct for 20 targets, repeated after."""
TRUTH_STYLE = {"marker": "s", "mfc": "none", "mew": 1.5, "ms": 8, "ls": "none"}
MAX_LEGEND_TARGETS = 12
"""Up to this many targets the 3D and top views' legends name each; beyond it each target's number
is written beside it instead and the legend says what the marks are (a legend of 54 targets, a
real G2 recording's, was taller than the axes: matplotlib's constrained layout collapsed them)."""
NUMBER_STYLE = {"fontsize": 7, "fontweight": "bold"}


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path, fixed: bool = False):
    """Write ``fig`` (PNG, 110 dpi) and close it; a figure with a layout engine is laid out by it
    (measuring every artist's extent again for a tight box doubled the plots' time), one laid out
    by hand (``fixed``: ``_grid``'s) as it is, else it is cut to its tight box."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches=None if fixed or fig.get_layout_engine() is not None else "tight")
    _plt().close(fig)


@renamed_kwargs({"colour": "color"})
def write_plots(d, out: Path, color, truth) -> list:
    """Write the first four ``PLOTS`` into ``out``; [(file name, caption)]. ``colour(index)``: a
    target's colour."""
    return [_plot_depth(d, out, color), _plot_density(d, out), _plot_3d(d, out, color),
            _plot_top(d, out, color)]


def _truth_point(d, tg):
    tt = d.truth.get(tg.index, {})
    return np.asarray(tt["position_mm"], float) if "position_mm" in tt else None


def _truth_path(d, tg):
    tt = d.truth.get(tg.index, {})
    return np.asarray(tt["path_mm"], float).reshape(-1, 3) if "path_mm" in tt else None


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9, color="#555555")


PANELS_PER_ROW = 4
"""The running-estimate and likelihood plots draw one small panel per target, this many a row."""
MAX_PANELS = 24
"""... and at most this many (the first, by number); the caption says when some are left out."""


GRID_MARGINS_IN = (0.75, 0.15, 0.6, 0.3)
"""The panel grids' margins (left, right, bottom, top), inches: room for the shared axis labels."""
GRID_GAPS_IN = (0.75, 0.7)
"""... and the gaps between their panels (across, down), inches: a panel's tick labels, axis label and title."""


def _grid(plt, n: int, w: float, h: float):
    """A figure of ``n`` panels (at least one) of ``w`` x ``h`` inches each, ``PANELS_PER_ROW`` a row,
    laid out by hand (``GRID_MARGINS_IN``, ``GRID_GAPS_IN``; save it with ``_save(..., fixed=True)``)
    with at most 4 ticks an axis: a layout engine measured every panel's text twice, which with 12
    or 24 panels was most of the report's time; (fig, flat axes)."""
    from matplotlib.ticker import MaxNLocator

    cols = min(max(n, 1), PANELS_PER_ROW)
    rows = -(-max(n, 1) // cols)
    left, right, bottom, top = GRID_MARGINS_IN
    W, H = w * cols + left + right, h * rows + bottom + top
    fig, axes = plt.subplots(rows, cols, figsize=(W, H), squeeze=False)
    panel_w = (W - left - right - (cols - 1) * GRID_GAPS_IN[0]) / cols
    panel_h = (H - bottom - top - (rows - 1) * GRID_GAPS_IN[1]) / rows
    fig.subplots_adjust(left=left / W, right=1 - right / W, bottom=bottom / H, top=1 - top / H,
                        wspace=GRID_GAPS_IN[0] / panel_w, hspace=GRID_GAPS_IN[1] / panel_h)
    for ax in axes.ravel():
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.yaxis.set_major_locator(MaxNLocator(4))
    for ax in axes.ravel()[n:]:
        ax.set_visible(n == 0 and ax is axes.ravel()[0])
    return fig, axes.ravel()


def _left_out(shown: int, total: int, what: str) -> str:
    return f" ({shown} of {total} {what} shown: the first by number)" if shown < total else ""


def _plot_depth(d, out: Path, color) -> tuple[str, str]:
    """Distance from the head against the view lines fed in: one panel per target (its fixations,
    in its colour, 95 % band clipped at 0; the true distance dashed), then one for the fixations
    merged into no target."""
    plt = _plt()
    groups = [(f"target {tg.index}", color(tg.index), tg, list(tg.fixations)) for tg in d.targets]
    merged = {f for tg in d.targets for f in tg.fixations}
    alone = [int(k) for k in np.unique(d.est["segment"]).astype(int) if int(k) not in merged]
    if alone:
        groups.append(("fixations in no target", "#888888", None, alone))
    shown = groups[:MAX_PANELS]
    fig, axes = _grid(plt, len(shown), 2.6, 2.1)
    for ax, (name, c, tg, fixations) in zip(axes, shown, strict=False):
        top = 0.0
        for k in fixations:
            sel = d.est["segment"] == k
            if not sel.any():
                continue
            mine = d.flabels == k
            eye = d.orig[mine].mean(axis=0) if mine.any() else d.center
            P = np.column_stack([d.est["x"][sel], d.est["y"][sel], d.est["z"][sel]])
            depth = np.linalg.norm(P - eye, axis=1) / 1000
            n = np.searchsorted(np.sort(d.samples.t_s[mine]), d.est["t"][sel], side="right")
            ax.plot(n, depth, "-", lw=1.2, color=c)
            r = d.est["radius95_mm"][sel] / 1000
            ax.fill_between(n, np.maximum(depth - r, 0), depth + r, color=c, alpha=0.15, lw=0)
            top = max(top, float(depth[-1]))
            X = _truth_point(d, tg) if tg is not None else None
            if X is not None:
                true = np.linalg.norm(X - eye) / 1000
                ax.plot([n[0], n[-1]], [true, true], "--", color="black", lw=0.8)
                top = max(top, true)
        if top == 0.0:
            _empty(ax, "no running estimate\n(a moving target)")
        ax.set_ylim(0, max(2.0 * top, 0.5))
        ax.set_title(name, fontsize=9, color=c)
        ax.tick_params(labelsize=7)
    fig.supxlabel("view lines of the fixation fed in (binocular samples)", fontsize=9)
    fig.supylabel("distance from the head (m)", fontsize=9)
    _save(fig, out / PLOTS[0], fixed=True)
    return (PLOTS[0], "Running estimate per fixation, one panel per target in its colour (band: 95 % radius"
            + ("; dashed: the truth" if d.truth else "") + ")" + _left_out(len(shown), len(groups), "panels"))


def _slice_axes(d, tg) -> tuple[np.ndarray, np.ndarray]:
    """(across, along): unit vectors (3,) spanning the slice through a target: horizontal
    across its view lines, and along their mean direction."""
    sel = d.tlabels == tg.index
    u = np.mean(d.cyc[sel], axis=0) if sel.any() else tg.position_mm - d.center
    u = u / np.linalg.norm(u)
    h = np.cross([0.0, -1.0, 0.0], u)
    h = h / np.linalg.norm(h) if np.linalg.norm(h) > 1e-6 else np.array([1.0, 0.0, 0.0])
    return h, u


def _plot_density(d, out: Path) -> tuple[str, str]:
    """Log-likelihood slices through each static target (up to ``MAX_PANELS``), in the plane of
    its view lines (a moving one's lines meet no one point); the truth as a white square."""
    plt = _plt()
    every = [tg for tg in d.targets if not tg.moving and np.all(np.isfinite(tg.position_mm))]
    static = every[:MAX_PANELS]
    fig, axes = _grid(plt, len(static), 2.9, 3.0)
    for i, tg in enumerate(static):
        ax = axes[i]
        X = tg.position_mm
        h, u = _slice_axes(d, tg)
        lines = d.samples.select(np.flatnonzero(d.tlabels == tg.index)).lines()
        a = tg.axes95_mm if np.all(np.isfinite(tg.axes95_mm)) else np.array([30.0, 30.0, 100.0])
        # across: the ellipsoid's short axes; along: the likelihood's own extent (about the
        # Cramer-Rao bound; the error model's ellipsoid can be far longer)
        wide = 1.5 * a[2] if not np.isfinite(tg.crb_mm) else min(1.5 * a[2], 6 * tg.crb_mm)
        across, along = max(4 * a[0], 30.0), max(wide, 4 * a[0], 30.0)
        ga, gb = np.meshgrid(np.linspace(-across, across, 45), np.linspace(-along, along, 61))
        P = X + ga.ravel()[:, None] * h + gb.ravel()[:, None] * u
        ll = angular_log_likelihood(P, lines.origins_mm, lines.directions, np.deg2rad(1.0)).reshape(ga.shape)
        ax.imshow(np.maximum(ll - ll.max(), -30), origin="lower", cmap="magma", aspect="auto",
                  extent=(-across, across, -along, along))
        ax.plot(0, 0, "c+", ms=10, label="estimate")
        T = _truth_point(d, tg)
        if T is not None:
            ax.plot(np.dot(T - X, h), np.dot(T - X, u), color="w", **TRUTH_STYLE, label="truth")
            ax.set_xlim(-across, across)
            ax.set_ylim(-along, along)
        ax.set_title(f"target {tg.index}", fontsize=9)
        ax.set_xlabel("across the view lines (mm)", fontsize=8)
        ax.set_ylabel("along the view lines (mm)" if i % PANELS_PER_ROW == 0 else "", fontsize=8)
        ax.tick_params(labelsize=7)
    if not static:
        _empty(axes[0], "no static target")
    _save(fig, out / PLOTS[1], fixed=True)
    return (PLOTS[1], "Log-likelihood of the gazed point (to -30) in the plane through each target along its view "
            "lines: narrow across them, long along them" + (" (white square: the truth)" if d.truth else "")
            + _left_out(len(static), len(every), "static targets"))


def _plot_3d(d, out: Path, color) -> tuple[str, str]:
    """The still 3D view (``figure_3d``) saved."""
    _save(figure_3d(d, color), out / PLOTS[2])
    return (PLOTS[2], "3D view (still): head path, view lines, targets and their 95 % credible regions (dashed: "
            "no far end; an arrow: running on past the axes); the view above can be turned")


@renamed_kwargs({"colour": "color"})
def figure_3d(d, color):
    """3D view (a matplotlib figure): head path, every 10th view line of each target, the targets
    (a moving one as its path) with their credible regions, the truth; equal scales on the three
    axes (x, z, up: -y), which hold the head path and the targets (``ReportData.box``). Lines
    drawn many at a time are one collection each (one artist per line cost a millisecond a line)."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection  # type: ignore[import-untyped]

    plt = _plt()
    fig = plt.figure(figsize=(7, 6), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    ax.plot(d.head[:, 0], d.head[:, 2], -d.head[:, 1], "k-", lw=1, label="head")
    lo, hi = d.box()
    many = _numbered(d)
    for k, region in d.regions.items():
        r = region_lines(region, lo, hi)
        _region_3d(ax, r, color(k))
        if many and k not in d.paths and not _has_point(d, k):
            ax.text(*_xzu(r.axis[1]), f" {k}", color=color(k), **NUMBER_STYLE)
    for tg in d.targets:
        X, c = tg.position_mm, color(tg.index)
        segments = [[_xzu(a), _xzu(b)] for a, b in line_segments(tg, d)]
        if segments:
            ax.add_collection3d(Line3DCollection(segments, colors=c, linewidths=0.3, alpha=0.5))
        if tg.index in d.paths:
            P = d.paths[tg.index][1]
            ax.plot(P[:, 0], P[:, 2], -P[:, 1], "-", color=c, lw=2,
                    label=None if many else f"target {tg.index} (moving: its path)")
            if many:
                ax.text(*_xzu(P[-1]), f" {tg.index}", color=c, **NUMBER_STYLE)
        elif np.all(np.isfinite(X)):
            ax.scatter([X[0]], [X[2]], [-X[1]], color=c, s=40, label=None if many else f"target {tg.index}")
            if many:
                ax.text(*_xzu(X), f" {tg.index}", color=c, **NUMBER_STYLE)
        elif tg.index in d.regions and not many:
            ax.plot([], [], "--", color=c, label=f"target {tg.index} (a direction)")
        T, Tp = _truth_point(d, tg), _truth_path(d, tg)
        if T is not None:
            ax.plot([T[0]], [T[2]], [-T[1]], color=c, **TRUTH_STYLE)
        if Tp is not None:
            ax.plot(Tp[:, 0], Tp[:, 2], -Tp[:, 1], "--", color=c, lw=1)
    if d.truth:
        ax.plot([], [], color="k", **TRUTH_STYLE, label="truth (a path: dashed)")
    if many:
        _kinds_legend(ax, d)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[2], hi[2])
    ax.set_zlim(-hi[1], -lo[1])
    ax.set_box_aspect((hi - lo)[[0, 2, 1]])
    ax.set_xlabel("x (mm)", labelpad=8)
    ax.set_ylabel("z (mm)", labelpad=8)
    ax.set_zlabel("up, -y (mm)", labelpad=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Head path, view lines, targets and their 95 % regions (equal scales)", fontsize=10)
    return fig


def _numbered(d) -> bool:
    """Whether the views number the targets beside them rather than in the legend
    (``MAX_LEGEND_TARGETS``)."""
    return len(d.targets) > MAX_LEGEND_TARGETS


def _has_point(d, k: int) -> bool:
    return any(t.index == k and np.all(np.isfinite(t.position_mm)) for t in d.targets)


def _xzu(p) -> tuple[float, float, float]:
    """A world point (3,) mm in the 3D view's axes (x, z, up: -y)."""
    return float(p[0]), float(p[2]), float(-p[1])


def _kinds_legend(ax, d) -> None:
    """The legend's entries for numbered targets (``_numbered``): what each kind of mark is, once."""
    moving = any(t.index in d.paths for t in d.targets)
    direction = any(t.index not in d.paths and not np.all(np.isfinite(t.position_mm)) and t.index in d.regions
                    for t in d.targets)
    ax.plot([], [], "o", color="#555555", label=f"{len(d.targets)} targets, each numbered beside it in its colour")
    if moving:
        ax.plot([], [], "-", color="#555555", lw=2, label="a moving target: its path")
    if direction:
        ax.plot([], [], "--", color="#555555", label="a target with a direction only: its region")


def _region_3d(ax, r, c: str) -> None:
    """A region's lines (``regions.RegionLines``) on a 3D axes (x, z, -y), one collection, an
    arrow where cut."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    lines = [np.vstack([ring, ring[:1]]) for ring in r.rings] + [np.asarray(ab, float) for ab in [*r.sides, r.axis]]
    ax.add_collection3d(Line3DCollection([q[:, [0, 2, 1]] * [1, 1, -1] for q in lines], colors=c, linewidths=0.9,
                                         linestyles="--" if r.open else "-"))
    if r.cut:
        a, b = r.axis
        v = 0.15 * (b - a)
        ax.quiver(b[0] - v[0], b[2] - v[2], -(b[1] - v[1]), v[0], v[2], -v[1], color=c, arrow_length_ratio=0.6, lw=1.5)


def top_limits(d) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) mm: the top view's square x-z limits about the box of the head path and the
    targets (``ReportData.box``; y unbounded, the height is not seen from above)."""
    lo, hi = d.box()
    mid, half = 0.5 * (lo + hi), 0.5 * float(max(hi[0] - lo[0], hi[2] - lo[2]))
    return (np.array([mid[0] - half, -np.inf, mid[2] - half]), np.array([mid[0] + half, np.inf, mid[2] + half]))


def _plot_top(d, out: Path, color) -> tuple[str, str]:
    """The top view (``figure_top``) saved."""
    _save(figure_top(d, color), out / PLOTS[3])
    return (PLOTS[3], "Top view: each target's 95 % credible region seen from above, its distance interval along "
            "the line of sight by its lateral extent (dashed: no far end; an arrow: it runs on past the axes, "
            "to the far end written beside it)")


@renamed_kwargs({"colour": "color"})
def figure_top(d, color):
    """Top view (a matplotlib figure, x-z): head path, view lines, each target's 95 % credible
    region seen from above (a target without one: its 95 % ellipsoid's shadow; a moving target:
    its path, with its 95 % ellipsoid's shadow at every 10th knot); the truth. The axes hold the
    head path and the targets (``top_limits``), not the regions' far ends."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Ellipse

    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 6.5), layout="constrained")
    ax.plot(d.head[:, 0], d.head[:, 2], "k-", lw=1, label="head")
    lo, hi = top_limits(d)
    drawn = [(k, region_lines(region, lo, hi)) for k, region in d.regions.items()]
    many = _numbered(d)
    for k, r in drawn:
        _region_top(ax, r, color(k), hi[0] - lo[0])
        if many and k not in d.paths and not _has_point(d, k):
            ax.annotate(f" {k}", (r.axis[1, 0], r.axis[1, 2]), color=color(k), **NUMBER_STYLE)
    if any(r.open for _, r in drawn):
        ax.plot([], [], "--", color="#555555", label="dashed: no far end (95 %)")
    for tg in d.targets:
        X, c = tg.position_mm, color(tg.index)
        segments = [[(a[0], a[2]), (b[0], b[2])] for a, b in line_segments(tg, d)]
        if segments:
            ax.add_collection(LineCollection(segments, colors=c, linewidths=0.3, alpha=0.4), autolim=False)
        if tg.index in d.paths:
            _, P, cov = d.paths[tg.index]
            ax.plot(P[:, 0], P[:, 2], "-", color=c, lw=2,
                    label=None if many else f"target {tg.index} (moving: its path)")
            if many:
                ax.annotate(f" {tg.index}", (P[-1, 0], P[-1, 2]), color=c, **NUMBER_STYLE)
            for k in range(0, len(P), 10):
                ax.add_patch(_shadow(Ellipse, P[k], K95 ** 2 * cov[k], c, 0.5))
        elif np.all(np.isfinite(X)):
            E = d.ellipsoid(tg) if tg.index not in d.regions else None
            if E is not None:
                ax.add_patch(_shadow(Ellipse, X, E.T @ E, c, 1.0))
            ax.plot(X[0], X[2], "o", color=c, label=None if many else f"target {tg.index} ({d.distance_m(tg):.2f} m)")
            if many:
                ax.annotate(f" {tg.index}", (X[0], X[2]), color=c, **NUMBER_STYLE)
        elif tg.index in d.regions and not many:
            ax.plot([], [], "--", color=c, label=f"target {tg.index} (a direction)")
        T, Tp = _truth_point(d, tg), _truth_path(d, tg)
        if T is not None:
            ax.plot(T[0], T[2], color=c, **TRUTH_STYLE)
        if Tp is not None:
            ax.plot(Tp[:, 0], Tp[:, 2], "--", color=c, lw=1)
    if d.truth:
        ax.plot([], [], color="k", **TRUTH_STYLE, label="truth (a path: dashed)")
    if many:
        _kinds_legend(ax, d)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[2], hi[2])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.legend(fontsize=7)
    ax.set_title("Top view (shaded: each target's 95 % credible region seen from above)", fontsize=10)
    return fig


def _region_top(ax, r, c: str, span_mm: float) -> None:
    """A region's lines (``regions.RegionLines``) seen from above: the outline of its x-z shadow
    (the convex hull of its end rings) shaded, its line of sight; where cut, an arrow at the
    axes' edge and, when it has one, its far end beside it."""
    from scipy.spatial import ConvexHull, QhullError

    P = r.hull[:, [0, 2]]
    try:
        P = P[ConvexHull(P).vertices]
    except QhullError:                    # seen end on: a line or a point
        pass
    ls = "--" if r.open else "-"
    ax.fill(P[:, 0], P[:, 1], color=c, alpha=0.12, lw=0)
    Q = np.vstack([P, P[:1]])
    ax.plot(Q[:, 0], Q[:, 1], ls, color=c, lw=1)
    a, b = r.axis[:, [0, 2]]
    ax.plot([a[0], b[0]], [a[1], b[1]], ls, color=c, lw=0.8)
    step = b - a
    if r.cut and np.linalg.norm(step) > 1e-6 * span_mm:
        tail = b - step / np.linalg.norm(step) * 0.06 * span_mm
        ax.annotate("", xy=tuple(b), xytext=tuple(tail), arrowprops={"arrowstyle": "-|>", "color": c, "lw": 1.3})
        if r.open:                                    # the legend says it (many rays would bury their texts)
            return
        text = f"far end {r.far_mm / 1000:.2f} m"
        right, up = step[0] > 0, step[1] > 0          # the text beside the arrow's tail, inside the axes
        ax.annotate(text, xy=tuple(tail), xytext=(-5 if right else 5, -5 if up else 5), textcoords="offset points",
                    fontsize=7, color=c, ha="right" if right else "left", va="top" if up else "bottom")


def _shadow(Ellipse, X, M, color: str, lw: float):
    """The outline of an ellipsoid {p: (p - X)^T M^-1 (p - X) <= 1} (M (3, 3), mm^2) seen from
    above: the x-z block of M is its shadow's."""
    S = np.asarray(M, float)[np.ix_([0, 2], [0, 2])]
    w, V = np.linalg.eigh(S)
    w = np.sqrt(np.clip(w, 0, None))
    angle = float(np.degrees(np.arctan2(V[1, 1], V[0, 1])))
    return Ellipse((X[0], X[2]), 2 * w[1], 2 * w[0], angle=angle, fill=False, color=color, lw=lw)


def line_segments(tg, d, every: int = 10):
    """Every ``every``-th view line of a target, from the eye to the target's distance (a moving
    target's: its path's point at the line's time)."""
    for j in np.flatnonzero(d.tlabels == tg.index)[::every]:
        X = tg.position_mm
        if tg.index in d.paths:
            t, P, _ = d.paths[tg.index]
            X = np.array([np.interp(d.samples.t_s[j], t, P[:, m]) for m in range(3)])
        if np.all(np.isfinite(X)):
            yield d.orig[j], d.orig[j] + d.cyc[j] * np.linalg.norm(X - d.orig[j])


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"COLOURS": "COLORS"})
