"""Device recordings in: one module per device format, each mapping the device's frames and
clock to ours explicitly (docs/importers.md). Each module has one reader and one writer:

- ``NAME``: the format's name on the command line;
- ``detect(src: Path) -> bool``: the folder holds this format (cheap: file names only);
- ``read_recording(src, imp: SessionImport, options: ImportOptions, progress=None)``: streams the
  recording into ``imp`` and calls ``imp.finish``;
- ``write_recording(sim: SimulatedRecording, dst: Path)``: a simulated session in the device's
  format (documented fields only), for the round-trip tests.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from ...errors import UserError

# format name -> module (imported on demand: a vendor reader may be an optional extra)
MODULES = {"pupil-core": "pupil_core", "pupil-neon": "neon", "tobii-g2": "tobii_g2", "tobii-g3": "tobii_g3",
           "aria-mps": "aria", "pupil-cloud": "pupil_cloud"}


def device_module(name: str):
    """The module of format ``name`` (one of ``MODULES``)."""
    if name not in MODULES:
        raise UserError(f"unknown recording format '{name}'; use one of {', '.join(MODULES)}")
    return importlib.import_module(f"{__name__}.{MODULES[name]}")


def detect_format(src) -> str:
    """The format of the recording folder ``src``, from the names of its files.

    Raises:
        UserError: no format, or more than one, matches.
    """
    src = Path(src)
    if src.is_file():
        raise UserError(f"{src}: a file, not a recording folder; pass the recording's folder, or name the format "
                        "with --format (a Pupil Player gaze_positions CSV: --format pupil-core)")
    if not src.is_dir():
        raise UserError(f"{src}: no such folder; pass the recording's folder")
    found = [name for name in MODULES if device_module(name).detect(src)]
    if not found and (src / "session.json").is_file():
        raise UserError(f"{src}: matches none of the known formats and is a session folder already (session.json): "
                        f"process it with 'wearable-gaze process {src}' (a recording's format is named with --format)")
    if not found:
        inside = _recordings_inside(src)
        if inside:
            raise UserError(f"{src}: the folder matches none of the known formats, but its subfolder "
                            f"{inside[0][0].name} is a {inside[0][1]} recording: import that folder")
    if len(found) != 1:
        what = "none of the known formats" if not found else f"more than one format ({', '.join(found)})"
        raise UserError(f"{src}: the folder matches {what}; pass --format {{{','.join(MODULES)}}} (docs/importers.md "
                        "lists the files each needs)")
    return found[0]


def _recordings_inside(src: Path) -> list[tuple[Path, str]]:
    """(subfolder, format) of each folder directly inside ``src`` that one format matches (a
    recording given by its parent folder, e.g. gazeMapper's data/lead/ holding the G2 project)."""
    out = []
    for sub in sorted(p for p in src.iterdir() if p.is_dir() and not p.name.startswith(".")):
        names = [name for name in MODULES if device_module(name).detect(sub)]
        if len(names) == 1:
            out.append((sub, names[0]))
    return out
