"""Every file ``process`` may write into its output folder, with its format (docs/formats.md,
"Outputs of process"): a JSON file's schema (``formats/schemas/``), a CSV's columns with the
dtype pandas reads each as (``pandas.read_csv`` with no options), or the kind of any other file.
``tests/test_exports.py`` checks that this list, the steps' outputs (``pipeline.process.stepcache``) and the
table of docs/formats.md name the same files, and that a processed session's files validate.

``check_output(path)`` checks one file against its entry (a JSON file against its schema, a CSV's
header against its columns); ``output_spec(name)`` gives the entry.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import UserError
from .aoi_tables import FIXATION_NUMBERS, METRIC_CHECKS, METRIC_NUMBERS, TRANSITION_CHECKS, read_aoi_fixations
from .fixations_table import FIXATION_CHECKS, FIXATION_COLUMNS
from .gaze_export import GAZE_CHECKS, GAZE_COLUMNS
from .jsonio import load_json
from .marker_detections import NAME as DETECTIONS
from .marker_detections import read_marker_detections
from .poses import POSE_CHECKS
from .tables import Checks, csv_header, read_table
from .targets import (
    DEVICE_CHECKS,
    DEVICE_COLUMNS,
    ESTIMATE_CHECKS,
    ESTIMATE_COLUMNS,
    PATH_CHECKS,
    PATH_COLUMNS,
    TARGET_CSV_CHECKS,
    TARGET_CSV_COLUMNS,
)

_F, _I, _S = "float64", "int64", "str"
_LINES = {"t": _F, **{f"{s}_{k}": _F for s in ("left", "right") for k in ("ox", "oy", "oz", "dx", "dy", "dz")}}


@dataclass(frozen=True)
class OutputFile:
    """One file of the output folder.

    Attributes:
        name: its file name.
        kind: 'json', 'csv', 'npy', 'npz', 'ply', 'png', 'webp', 'mp4', 'html' or 'txt'.
        what: what it holds, and the step that writes it.
        schema: a JSON file's schema name (``jsonio.SCHEMA_NAMES``).
        columns: a CSV's columns always present, in order: name -> dtype ('int64', 'float64' or
            'str': a text column, pandas' object or str dtype).
        optional_columns: a CSV's columns present only in some sessions (name -> dtype).
        checks: a CSV's values: the ``tables.Checks`` its writer applied, and its reader does.
        read: a CSV whose columns depend on its contents (aoi_fixations.csv's ``p_NAME``), or a
            binary file that has a reader: its reader, which checks it, in place of ``checks``.
    """

    name: str
    kind: str
    what: str
    schema: str | None = None
    columns: dict = field(default_factory=dict)
    optional_columns: dict = field(default_factory=dict)
    checks: Checks | None = None
    read: object = None


PROCESS_OUTPUTS = (
    OutputFile("camera.json", "json", "camera: the scene camera's calibration", schema="camera"),
    OutputFile("camera_undistorted.png", "png", "camera: the first board view beside its undistorted version"),
    OutputFile("eyes.json", "json", "eyes: the eye calibration", schema="eyes"),
    OutputFile("poses.csv", "csv", "tracking: the head pose of every scene-video frame",
               columns={"t": _F, "frame": _I, **dict.fromkeys(("qw", "qx", "qy", "qz", "tx", "ty", "tz"), _F)},
               optional_columns={"n_markers": _I, "n_points": _I, "reproj_rms_px": _F, "status": _S},
               checks=POSE_CHECKS),
    OutputFile("built_map.json", "json", "tracking (--build-map): the marker map built from the video",
               schema="marker-map"),
    OutputFile(DETECTIONS, "npz", "tracking (in a marker map): the markers detected in each frame tracked, which "
               "the report's overlay draws", read=read_marker_detections),
    OutputFile(".viewlines_unsegmented.csv", "csv", "viewlines: the world view lines before segmentation",
               columns=_LINES),
    OutputFile(".viewlines_counts.json", "json", "viewlines: eye samples read, view lines written, dropped",
               schema="viewlines-counts"),
    OutputFile("viewlines.csv", "csv", "targets: the view lines with their fixation labels",
               columns=_LINES | {"segment": _I}),
    OutputFile("estimates.csv", "csv", "targets: the fixations' running estimates",
               columns={k: _I if k == "segment" else _F for k in ESTIMATE_COLUMNS}, checks=ESTIMATE_CHECKS),
    OutputFile("targets.json", "json", "targets: the target records", schema="targets"),
    OutputFile("targets.csv", "csv", "targets: the target records flattened",
               columns={k: _I if k in ("target", "n_samples", "moving") else
                        _S if k in ("fixations", "method", "status") else _F for k in TARGET_CSV_COLUMNS},
               checks=TARGET_CSV_CHECKS),
    OutputFile("target_labels.npy", "npy", "targets: the target index of every row of viewlines.csv, -1 none"),
    OutputFile("target_paths.csv", "csv", "targets: the moving targets' paths (a header alone: none)",
               columns={k: _I if k == "target" else _F for k in PATH_COLUMNS}, checks=PATH_CHECKS),
    OutputFile("fixations.csv", "csv", "targets: one row per fixation", columns=FIXATION_COLUMNS,
               checks=FIXATION_CHECKS),
    OutputFile("device_comparison.csv", "csv", "targets (an imported session): each target beside the device's "
               "3D gaze", columns={k: _I if k in ("target", "n_samples") else _F for k in DEVICE_COLUMNS},
               checks=DEVICE_CHECKS),
    OutputFile("gaze.csv", "csv", "export: one row per eye sample", columns=GAZE_COLUMNS, checks=GAZE_CHECKS),
    OutputFile("targets.ply", "ply", "export: the targets, their 95 % ellipsoids and the head path, mm"),
    OutputFile("aoi_fixations.csv", "csv", "aoi (--aois): each fixation's probability of each area",
               columns={k: _F if k.endswith("_s") else _I for k in FIXATION_NUMBERS} | {"aoi": _S},
               read=read_aoi_fixations),
    OutputFile("aoi_metrics.csv", "csv", "aoi (--aois): the per-area measures",
               columns={"aoi": _S, "group": _S} | {k: _I if k in ("visits", "revisits", "fixations") else _F
                                                   for k in METRIC_NUMBERS}, checks=METRIC_CHECKS),
    OutputFile("aoi_transitions.csv", "csv", "aoi (--aois): transitions between areas",
               columns={"from": _S, "to": _S, "count": _I, "weighted": _F}, checks=TRANSITION_CHECKS),
    OutputFile("aoi_dwell.png", "png", "aoi (--aois): each area's dwell time"),
    OutputFile("aoi_timeline.png", "png", "aoi (--aois): which area when"),
    OutputFile("report.html", "html", "report: the report (docs/processing.md)"),
    *(OutputFile(n, "png", "report: a plot") for n in ("plot_depth_vs_observations.png", "plot_density_slices.png",
                                                         "plot_3d.png", "plot_top_view.png",
                                                         "plot_depth_over_time.png")),
    OutputFile("overlay.mp4", "mp4", "report: the overlay video (H.264, the whole session at about 10 fps, 640 px)"),
    OutputFile("overlay_full.mp4", "mp4", "report (--overlay-video): the overlay at full resolution, every frame"),
    OutputFile("overlay_error.txt", "txt", "report: why the overlay could not be made"),
    OutputFile("summary.json", "json", "process: what ran, failed and was found", schema="summary"),
    OutputFile(".steps.json", "json", "process: the steps' cache fingerprints", schema="steps-state"),
)
"""Every file of ``process``'s output folder."""
_BY_NAME = {o.name: o for o in PROCESS_OUTPUTS}


def output_spec(name: str) -> OutputFile:
    """The entry of output file ``name``.

    Raises:
        KeyError: not a file ``process`` writes.
    """
    return _BY_NAME[name]


def check_output(path) -> OutputFile:
    """Check one file of an output folder against its entry: a JSON file against its schema
    (``jsonio.load_json``), a CSV's header against its columns (every column of ``columns``, in
    order, then only ``optional_columns``) and its values against its ``checks`` (what its writer
    checked). Returns the entry.

    Raises:
        UserError: a file ``process`` does not write, or one not in its format (one line).
    """
    path = Path(path)
    spec = _BY_NAME.get(path.name)
    if spec is None:
        raise UserError(f"{path}: not a file 'wearable-gaze process' writes (docs/formats.md, Outputs of process)")
    if spec.kind == "json":
        load_json(path, spec.schema)
    elif spec.read is not None:
        spec.read(path)
    elif spec.kind == "csv":
        names = csv_header(path, spec.name, "run 'wearable-gaze process' again")
        want = list(spec.columns)
        extra = [n for n in names[len(want):] if n not in spec.optional_columns]
        if names[:len(want)] != want or extra:
            raise UserError(f"{path}: columns {names}, expected {want} then any of {list(spec.optional_columns)}; "
                            "run 'wearable-gaze process' again (--force)")
        if spec.checks is not None:
            text = [n for n, d in (spec.columns | spec.optional_columns).items() if d == _S]
            read_table(path, spec.checks.required, text, rows_required=False, checks=spec.checks)
    return spec
