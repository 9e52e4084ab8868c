"""The AOI step's plots (``steps/aoi.py``; docs/aois.md): each area's dwell time, and which area
when."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .plots import _plt

if TYPE_CHECKING:
    from ..steps.aoi import AoiResult


def plot_dwell(metrics: list[dict], path: Path) -> None:
    """A bar chart of each area's dwell time with its probability-weighted dwell beside it."""
    plt = _plt()

    names = [m["aoi"] for m in metrics]
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(max(4.0, 0.8 * len(names) + 2), 3.2))
    ax.bar(x - 0.2, [m["dwell_s"] for m in metrics], 0.4, label="dwell (assigned fixations)")
    ax.bar(x + 0.2, [m["dwell_weighted_s"] for m in metrics], 0.4, label="dwell weighted by probability")
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylabel("s")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_timeline(rows: list[str], res: AoiResult, fixations: tuple, path: Path) -> None:
    """Rows of areas (``rows``: ``res``'s areas, then the row of no area) against session time:
    each fixation drawn in each row as dark as its probability of that area, outlined in the row it
    is assigned to."""
    plt = _plt()

    fig, ax = plt.subplots(figsize=(9.0, 0.45 * len(rows) + 1.2))
    for f, p, a in zip(fixations, res.probabilities, res.assigned, strict=True):
        for j in range(len(rows)):
            if np.isfinite(p[j]) and p[j] > 0.01:
                ax.barh(j, f.end_s - f.start_s, left=f.start_s, height=0.7, color="#0067a5", alpha=float(p[j]), lw=0)
        j = a if a >= 0 else len(rows) - 1
        ax.barh(j, f.end_s - f.start_s, left=f.start_s, height=0.7, fill=False, edgecolor="black", lw=0.8)
    ax.set_yticks(range(len(rows)), rows)
    ax.invert_yaxis()
    ax.set_xlabel("session time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
