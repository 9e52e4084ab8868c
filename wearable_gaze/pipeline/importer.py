"""``wearable-gaze import``: a device's recording -> a session folder (docs/importers.md), and
``export-recording``: a simulated session -> a device's recording (the round trip that tests each
importer against the simulator's truth).

The session is built under a temporary name beside the output folder and renamed at the end:
an import that fails leaves nothing behind, and an existing session is never overwritten.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from ..errors import UserError
from ..formats.atomic import atomic_folder, check_new_folder
from ..formats.devices import MODULES, device_module, locate_recording
from ..formats.devices.common import REPORT, ImportOptions, SessionImport, read_simulated_recording
from ..formats.markermap import load_marker_map

log = logging.getLogger(__name__)


def import_recording(src, out, fmt: str | None = None, options: ImportOptions | None = None,
                     progress=None) -> tuple[dict, dict]:
    """Import the recording folder ``src`` as the session folder ``out`` (new or empty).

    Args:
        fmt: the device format (``formats.devices.MODULES``); detected from the folder's files
            when None. ``src`` may be the recording, its parent holding only it, or a folder
            inside it (``formats.devices.locate_recording``; the report's notes say which).
        options: markers, camera, marker size, kappa recording, pose gap (``ImportOptions``).
        progress: a progress(done, total) callback.

    Returns:
        (the session manifest, the import report).

    Raises:
        UserError: an unknown or undetectable format, a bad recording (one line).
    """
    src, out = Path(src), check_new_folder(out)
    if not src.exists():
        raise UserError(f"{src}: no such recording; pass the folder the device wrote")
    located = locate_recording(src, fmt)
    src, name = located.folder, located.format
    if src.is_dir() and src.resolve() in out.resolve().parents:
        raise UserError(f"-o {out}: is inside the recording {src}; writing there would change the recording: "
                        "choose a folder outside it")
    module = device_module(name)
    options = options or ImportOptions()
    for opt, p in (("--markers", options.markers), ("--camera", options.camera),
                   ("--kappa-recording", options.kappa_recording)):
        if p is not None and not Path(p).exists():
            raise UserError(f"{opt} {p}: no such file; check the path")
    with atomic_folder(out) as tmp:
        with SessionImport(tmp, name, src.resolve()) as imp:
            if located.how is not None:
                imp.note(located.how)
            module.read_recording(src, imp, options, progress)
            if not (tmp / "session.json").is_file():
                raise RuntimeError(f"the {name} importer did not finish the session")
    manifest = json.loads((out / "session.json").read_text(encoding="utf-8"))
    report = json.loads((out / REPORT).read_text(encoding="utf-8"))
    return manifest, report


EYE_STATE_FORMATS = ("pupil-cloud",)
"""The formats ``export-recording --eye-states`` applies to (a Neon Cloud export's
``3d_eye_states.csv``; without it the export is Invisible's: 2D gaze only)."""


def export_recording(session, out, fmt: str, eye_states: bool = False) -> str:
    """Write the simulated session ``session`` as a ``fmt`` recording in the new folder ``out``
    (documented fields only): what the round-trip tests import again; ``eye_states``: with the
    per-eye eyeball centres and optical axes (``EYE_STATE_FORMATS`` only). Returns the command
    that imports it (with ``--marker-size-mm`` when the recording's head poses are in marker
    sides, as Pupil Player's head-pose tracker writes them)."""
    if fmt not in MODULES:
        raise UserError(f"unknown recording format '{fmt}'; use one of {', '.join(MODULES)}")
    if eye_states and fmt not in EYE_STATE_FORMATS:
        raise UserError(f"--eye-states applies to --format {' or '.join(EYE_STATE_FORMATS)} only; "
                        f"a {fmt} recording always has its own eye data: leave --eye-states out")
    sim = read_simulated_recording(session)
    with atomic_folder(out) as tmp:
        if eye_states:
            device_module(fmt).write_recording(sim, tmp, eye_states=True)
        else:
            device_module(fmt).write_recording(sim, tmp)
    command = f"wearable-gaze import {out} -o SESSION --format {fmt}"
    if sim.marker_map is not None and any(Path(out).glob("exports/*/head_pose_tracker_poses.csv")):
        size = load_marker_map(sim.marker_map).marker_size_mm
        command += f" --marker-size-mm {size:g}"
    return command


def format_import(manifest: dict, report: dict, out) -> str:
    """The lines ``import`` prints: what was read, kept and dropped (with reasons), the pose
    source, and the notes."""
    src = manifest["source"]
    lines = [f"imported {report['device']} recording {report['source']} -> {out}: "
             f"{report['eye_samples_written']} eye samples kept ({manifest.get('eye_rate_hz', 0):g} Hz)"]
    if report.get("read"):
        lines.append("read: " + ", ".join(f"{n} {k}" for k, n in report["read"].items()))
    dropped = report.get("dropped") or {}
    lines.append("dropped: " + (", ".join(f"{n} ({k})" for k, n in dropped.items()) if dropped else "none"))
    lines.append(f"head poses: {src['pose_source'].replace('_', ' ')}; clock offset {src['clock_offset_s']:.6f} s")
    lines += [f"note: {n}" for n in report.get("notes", ())]
    lines.append(f"next: wearable-gaze process {out}")
    return "\n".join(lines)
