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
from dataclasses import dataclass
from pathlib import Path

from ...errors import UserError

# format name -> module (imported on demand: a vendor reader may be an optional extra)
MODULES = {"pupil-core": "pupil_core", "pupil-neon": "neon", "tobii-g2": "tobii_g2", "tobii-g3": "tobii_g3",
           "aria-mps": "aria", "aria-gen2": "aria_gen2", "pupil-cloud": "pupil_cloud"}
MAX_LEVELS_UP = 2
"""How far up ``locate_recording`` looks for the recording a folder is inside (Tobii G2's
``segments/1`` is two levels below its recording)."""


def device_module(name: str):
    """The module of format ``name`` (one of ``MODULES``)."""
    if name not in MODULES:
        raise UserError(f"unknown recording format '{name}'; use one of {', '.join(MODULES)}")
    return importlib.import_module(f"{__name__}.{MODULES[name]}")


def _formats(src: Path, fmt: str | None = None) -> list[str]:
    """The formats whose ``detect`` accepts the folder ``src`` (only ``fmt`` when given), less
    those another found format ``SUPERSEDES``."""
    names = [fmt] if fmt else list(MODULES)
    try:
        found = [name for name in names if device_module(name).detect(src)]
    except OSError:                                   # a folder we may not list
        return []
    beaten = {o for name in found for o in getattr(device_module(name), "SUPERSEDES", ())}
    return [name for name in found if name not in beaten]


def _one(src: Path, found: list[str]) -> str:
    if len(found) != 1:
        what = "none of the known formats" if not found else f"more than one format ({', '.join(found)})"
        raise UserError(f"{src}: the folder matches {what}; pass --format {{{','.join(MODULES)}}} (docs/importers.md "
                        "lists the files each needs)")
    return found[0]


@dataclass(frozen=True)
class Located:
    """Where the recording is: its ``format``, its ``folder``, and ``how`` it was found when that
    is not the folder given (one sentence for the import report; None: the folder given)."""

    format: str
    folder: Path
    how: str | None = None


def locate_recording(src, fmt: str | None = None) -> Located:
    """The recording ``src`` points at, from any folder level: ``src`` itself, else the one
    recording in one of its sub-folders, else the recording ``src`` is inside (up to
    ``MAX_LEVELS_UP`` levels: a Tobii G2 ``segments/1`` folder). With ``fmt`` only that format
    is looked for, and a path it is not found at is passed on as given (its reader says what is
    missing; a Pupil Player CSV is a file).

    Raises:
        UserError: no folder; a file without ``fmt``; a session folder; several recordings
            below ``src`` (listed: pass one); no format, or more than one, anywhere.
    """
    src = Path(src)
    if fmt is not None and fmt not in MODULES:
        device_module(fmt)                             # the one-line refusal
    if not src.exists():
        raise UserError(f"{src}: no such folder; pass the recording's folder")
    if src.is_file():
        if fmt is None:
            raise UserError(f"{src}: a file, not a recording folder; pass the recording's folder, or name the "
                            "format with --format (a Pupil Player gaze_positions CSV: --format pupil-core)")
        return Located(fmt, src)
    found = _formats(src, fmt)
    if found:
        return Located(_one(src, found), src)
    if fmt is None and (src / "session.json").is_file():
        raise UserError(f"{src}: matches none of the known formats and is a session folder already (session.json): "
                        f"process it with 'wearable-gaze process {src}' (a recording's format is named with --format)")
    try:
        kids = [(p, f) for p in sorted(src.iterdir()) if p.is_dir() for f in [_formats(p, fmt)] if f]
    except OSError:
        kids = []
    if len(kids) > 1:
        listed = ", ".join(f"{p.name} ({'/'.join(f)})" for p, f in kids)
        raise UserError(f"{src}: holds {len(kids)} recordings ({listed}); pass one of them")
    if kids:
        (p, f), = kids
        return Located(_one(p, f), p, f"{src} holds one recording, {p.name}/: that folder was read")
    for up, parent in enumerate(src.absolute().parents[:MAX_LEVELS_UP], 1):
        if f := _formats(parent, fmt):
            return Located(_one(parent, f), parent, f"{src} is inside the recording {parent} ({up} level"
                           f"{'s' if up > 1 else ''} up): that folder was read")
    if fmt is not None:
        return Located(fmt, src)
    return Located(_one(src, []), src)


def detect_format(src) -> str:
    """The format of the recording folder ``src`` itself, from the names of its files (see
    ``locate_recording`` for other folder levels).

    Raises:
        UserError: no format, or more than one, matches.
    """
    src = Path(src)
    located = locate_recording(src)
    if located.how is not None:
        _one(src, [])
    return located.format
