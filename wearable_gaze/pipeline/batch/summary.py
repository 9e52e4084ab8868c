"""The report of ``wearable-gaze batch`` (docs/batch.md; the status files it reads:
``formats.batch_status``): one
table of all sessions as ``batch_report.html`` and ``batch_report.csv`` (targets, durations,
problems, accuracy against the simulator's truth where the session has one), and every
session's targets in one table, ``all_targets.csv``. All written atomically.
"""

from __future__ import annotations

import html
import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np

from ...errors import UserError
from ...formats.aoi_tables import read_aoi_metrics
from ...formats.atomic import write_text
from ...formats.session import MANIFEST
from ...formats.tables import write_table
from ...formats.targets import read_targets, write_targets_csv
from ...formats.truth import read_truth_targets
from ..report.plots import _plt
from ..report.truth_match import TruthFrame, match_targets
from ..steps.target_status import is_fixated

log = logging.getLogger(__name__)

REPORT_FILES = ("batch_report.html", "batch_report.csv", "all_targets.csv")

# the report's columns: (CSV name, HTML header with its unit)
COLUMNS = (("session", "session"), ("state", "state"), ("reason", "reason"), ("n_targets", "targets"),
           ("recording_s", "recording (s)"), ("processing_s", "processing (s)"), ("n_problems", "problems"),
           ("truth_targets", "true targets"), ("truth_found", "found"), ("error_rms_mm", "RMS error (mm)"),
           ("error_max_mm", "max error (mm)"), ("crb_rms_mm", "RMS Cramér-Rao bound (mm)"),
           ("peak_rss_mb", "worker peak memory (MB)"), ("worker", "worker"), ("path", "session folder"))
FORMATS = {"recording_s": ".1f", "processing_s": ".1f", "error_rms_mm": ".1f", "error_max_mm": ".1f",
           "crb_rms_mm": ".1f", "peak_rss_mb": ".0f"}


# --- the report ----------------------------------------------------------------------------------

def _recording_s(session: Path) -> float:
    """The recording's length from its manifest (frames / fps), s; NaN when it does not say."""
    try:
        man = json.loads((session / MANIFEST).read_text(encoding="utf-8"))
        if isinstance(man.get("duration_s"), (int, float)):
            return float(man["duration_s"])
        return float(man["n_frames"]) / float(man["fps"])
    except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
        return float("nan")


def truth_errors(session: Path, rows: list[dict], frame: TruthFrame | None = None) -> dict:
    """The targets found (rows of targets.json) against a simulated session's truth
    (``truth/targets.json``; ``truth_match.match_targets``), moved into the world of the map the
    session was processed with (``frame``, from its summary.json; None: the truth's own): the
    static true targets, how many were found, the RMS and largest distance of each found one to
    its truth (mm) and the RMS of their Cramér-Rao bounds (mm). {} without a truth, or one that
    cannot be moved into that world."""
    path = session / "truth" / "targets.json"
    if not path.is_file() or (frame is not None and frame.T_map_from_truth is None):
        return {}
    try:
        truth = [t for t in read_truth_targets(path) if "position_mm" in t]
    except UserError as exc:
        log.warning("%s", exc)
        return {}
    truth = frame.targets(truth) if frame is not None else truth
    pairs = [(tt, f) for tt, f in match_targets(rows, truth) if f is not None]
    err = np.array([np.linalg.norm(np.array(f["position_mm"]) - tt["position_mm"]) for tt, f in pairs])
    crb = np.array([np.nan if f["crb_mm"] is None else f["crb_mm"] for _, f in pairs], float)
    nan = float("nan")
    return {"truth_targets": len(truth), "truth_found": len(pairs),
            "error_rms_mm": float(np.sqrt(np.mean(err ** 2))) if len(err) else nan,
            "error_max_mm": float(err.max()) if len(err) else nan,
            "crb_rms_mm": float(np.sqrt(np.nanmean(crb ** 2))) if np.isfinite(crb).any() else nan}


def _session_row(out: Path, st: dict) -> tuple[dict, list[dict]]:
    """A session's row of the report and its targets (rows of targets.json; none unless done)."""
    session = Path(st["session"])
    rows = []
    if st["state"] in ("done", "partial") and (out / st["name"] / "targets.json").is_file():
        try:
            rows = read_targets(out / st["name"] / "targets.json")
        except UserError as exc:
            log.warning("%s", exc)
    nan = float("nan")
    row = {"session": st["name"], "state": st["state"], "reason": st.get("reason") or "",
           "n_targets": sum(is_fixated(r["status"]) for r in rows), "recording_s": _recording_s(session),
           "processing_s": float(st.get("duration_s", nan)), "n_problems": len(st.get("problems", [])),
           "truth_targets": "", "truth_found": "", "error_rms_mm": nan, "error_max_mm": nan, "crb_rms_mm": nan,
           "peak_rss_mb": float(st.get("peak_rss_mb") or nan), "worker": st.get("worker", ""), "path": str(session)}
    row.update(truth_errors(session, rows, _truth_frame(out / st["name"])) if rows else {})
    return row, rows


def _truth_frame(folder: Path) -> TruthFrame | None:
    """The ``TruthFrame`` a session's summary.json records (None: none, or no readable summary)."""
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        return TruthFrame.from_record(summary.get("truth_frame"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def write_batch_report(out, statuses: dict) -> list[dict]:
    """Write ``REPORT_FILES`` into ``out`` from each session's status ({name: status}) and
    outputs. Returns the report's rows (dicts keyed by ``COLUMNS``' CSV names)."""
    out = Path(out)
    table, targets, sessions = [], [], []
    for st in statuses.values():
        row, rows = _session_row(out, st)
        table.append(row)
        targets += rows
        sessions += [st["name"]] * len(rows)
    write_table(out / "batch_report.csv", {k: np.array([r[k] for r in table], dtype=object if k not in FORMATS
                                                          else float) for k, _ in COLUMNS}, FORMATS)
    write_targets_csv(out / "all_targets.csv", targets, sessions)           # targets.csv's columns after session
    write_text(out / "batch_report.html", _html(out, table))
    write_batch_aois(out, [st["name"] for st in statuses.values()])
    return table


AOI_MEASURES = ("dwell_s", "dwell_weighted_s", "visits", "fixations", "first_fixation_s", "share")
"""The measures of the batch's sessions x areas table plotted one figure each."""
AOI_COUNTS = ("visits", "revisits", "fixations")
"""Its columns that count (written as integers)."""


def write_batch_aois(out: Path, names: list[str]) -> bool:
    """``batch_aoi_metrics.csv`` (one row per session and area: ``session`` then aoi_metrics.csv's
    columns) and ``batch_aoi_MEASURE.png`` for each of ``AOI_MEASURES`` (grouped bars, one group
    per area, one bar per session), from the sessions' ``OUT/NAME/aoi_metrics.csv``; nothing when
    no session has one. Returns whether it wrote them."""
    rows = {}
    for name in names:
        f = out / name / "aoi_metrics.csv"
        if f.is_file():
            rows[name] = read_aoi_metrics(f)
    if not rows:
        return False
    cols = {"session": np.array([n for n, m in rows.items() for _ in m["aoi"]], object)}
    first = next(iter(rows.values()))
    for k in first:
        cols[k] = np.concatenate([m[k] for m in rows.values()])
        if k in AOI_COUNTS:                                     # counts as integers, as aoi_metrics.csv has them
            cols[k] = cols[k].astype(np.int64)
    write_table(out / "batch_aoi_metrics.csv", cols,
                {k: ".4f" for k in AOI_MEASURES if k in cols and k not in AOI_COUNTS})
    for k in AOI_MEASURES:
        plot_grouped(rows, k, out / f"batch_aoi_{k}.png")
    return True


def plot_grouped(rows: dict, measure: str, path: Path) -> None:
    """Grouped bars of ``measure``: one group per area, one bar per session (``rows``: session ->
    its aoi_metrics.csv columns)."""
    plt = _plt()

    areas = list(dict.fromkeys(a for m in rows.values() for a in m["aoi"]))
    width = 0.8 / max(len(rows), 1)
    fig, ax = plt.subplots(figsize=(max(4.0, 0.9 * len(areas) + 2), 3.2))
    for j, (name, m) in enumerate(rows.items()):
        vals = {a: v for a, v in zip(m["aoi"], m[measure], strict=True)}
        ax.bar(np.arange(len(areas)) + (j - (len(rows) - 1) / 2) * width,
               [vals.get(a, np.nan) for a in areas], width, label=name)
    ax.set_xticks(np.arange(len(areas)), areas, rotation=30, ha="right")
    ax.set_ylabel(measure)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _cell(key: str, value, out: Path) -> str:
    if isinstance(value, float):
        return "" if not np.isfinite(value) else format(value, FORMATS.get(key, ".1f"))
    if key == "session" and (out / str(value) / "report.html").is_file():
        return f'<a href="{html.escape(str(value))}/report.html">{html.escape(str(value))}</a>'
    return html.escape(str(value))


def _html(out: Path, table: list[dict]) -> str:
    counts = Counter(r["state"] for r in table)
    head = "".join(f"<th>{html.escape(h)}</th>" for _, h in COLUMNS)
    body = "".join(f'<tr class="{html.escape(r["state"])}">' + "".join(
        f"<td>{_cell(k, r[k], out)}</td>" for k, _ in COLUMNS) + "</tr>" for r in table)
    found = [r for r in table if r["truth_targets"] != ""]
    truth = ""
    if found:
        err = np.array([r["error_rms_mm"] for r in found], float)
        truth = (f"<p>Against the simulator's truth ({len(found)} session(s)): {sum(r['truth_found'] for r in found)} "
                 f"of {sum(r['truth_targets'] for r in found)} true targets found; RMS error over sessions "
                 f"{np.sqrt(np.nanmean(err ** 2)):.1f} mm.</p>" if np.isfinite(err).any() else "")
    summary = ", ".join(f"{counts.get(k, 0)} {k}" for k in ("done", "partial", "failed", "pending", "running")
                        if counts.get(k))
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>wearable-gaze batch report</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:4px 8px}}
tr.failed{{background:#fdd}}tr.partial,tr.pending,tr.running{{background:#ffd}}</style>
</head><body><h1>Batch: {len(table)} session(s)</h1>
<p>{html.escape(summary)}. Each session's outputs are in its folder (its name links to its report). Errors are
the distances from each found target to the true one it matches, world frame; the Cramér-Rao bound is the
smallest RMS error the view lines allow. The same table: batch_report.csv; every target: all_targets.csv.</p>
{truth}
<table><tr>{head}</tr>{body}</table>
</body></html>
"""
