"""The report's plot of the gaze's depth over the session's time (issue 28): each fixation's
running estimate (its distance from the eyes, in its target's colour, with its 95 % radius as a
band) and, over each fixation of a target, that target's 95 % depth interval (symmetric in
inverse depth, ``estimator.errormodel.depth_interval``): a shaded span, hatched and open at the
top where the interval has no far end. ``d`` is the report's ``report.ReportData``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimator.deprecation import renamed_kwargs

from .plots import PLOTS, _empty, _plt, _save

DEPTH_OVER_TIME = PLOTS[4]


def _fixation_spans(d, tg) -> list[tuple[float, float, np.ndarray]]:
    """[(start s, end s, the eyes' mean origin (3,) mm)] of target ``tg``'s fixations."""
    out = []
    for f in tg.fixations:
        sel = d.flabels == f
        if sel.any():
            t = d.samples.t_s[sel]
            out.append((float(t.min()), float(t.max()), d.orig[sel].mean(axis=0)))
    return out


def _running(d, color, ax, target_of: dict) -> float:
    """Draw each fixation's running estimate; the largest distance drawn, m."""
    top = 0.0
    for k in np.unique(d.est["segment"]).astype(int):
        sel = d.est["segment"] == k
        mine = d.flabels == k
        eye = d.orig[mine].mean(axis=0) if mine.any() else d.center
        P = np.column_stack([d.est["x"][sel], d.est["y"][sel], d.est["z"][sel]])
        depth = np.linalg.norm(P - eye, axis=1) / 1000
        tg = target_of.get(k)
        c = color(tg.index) if tg is not None else "#888888"
        t = d.est["t"][sel]
        ax.plot(t, depth, "-", lw=1.2, color=c)
        r = np.nan_to_num(d.est["radius95_mm"][sel], nan=0.0) / 1000
        ax.fill_between(t, np.maximum(depth - r, 0), depth + r, color=c, alpha=0.10, lw=0)
        if len(depth):
            top = max(top, float(np.nanmedian(depth)))
    return top


@renamed_kwargs({"colour": "color"})
def plot_depth_over_time(d, out: Path, color) -> tuple[str, str]:
    """Write ``DEPTH_OVER_TIME`` into ``out``; (its name, its caption)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9.0, 3.8), layout="constrained")
    target_of = {f: tg for tg in d.targets for f in tg.fixations}
    top = _running(d, color, ax, target_of)
    spans = []
    for tg in d.targets:
        if tg.sight is None or not np.all(np.isfinite(tg.position_mm)):
            continue
        for a, b, eye in _fixation_spans(d, tg):
            D = float(np.linalg.norm(tg.position_mm - eye)) / 1000
            near, far = (v / 1000 for v in tg.sight.depth_interval(tg.position_mm, 0.95))
            spans.append((a, b, D, near, far, color(tg.index), tg.index))
            top = max(top, D)
    ymax = max(1.6 * top, 1.0)
    labeled = set()
    for a, b, D, near, far, c, k in spans:
        open_top = not np.isfinite(far) or far > ymax
        ax.fill_between([a, b], [near] * 2, [min(far, ymax)] * 2, color=c, alpha=0.18, lw=0,
                        hatch="//" if open_top else None)
        ax.plot([a, b], [D, D], color=c, lw=2.5, label=None if k in labeled else f"target {k}")
        labeled.add(k)
    ax.set_ylim(0, ymax)
    ax.set_xlabel("session time (s)")
    ax.set_ylabel("distance from the eyes (m)")
    if not spans and not len(d.est["t"]):
        _empty(ax, "no estimate")
    elif labeled:
        ax.legend(fontsize=7, ncol=min(len(labeled), 6), loc="upper left")
    _save(fig, out / DEPTH_OVER_TIME)
    return (DEPTH_OVER_TIME, "The gaze's distance over time: each fixation's running estimate (line, band: its 95 % "
            "radius) and each target's 95 % depth interval over its fixations (shaded; hatched and cut at the top "
            "where it has no far end), its estimate as a thick line")
