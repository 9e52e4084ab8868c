"""A person's validation recording (``validation.json``) and the gaze bias learned from it
(``person.json``), docs/calibration.md "Per-person bias".

``validation.json``: the targets the person fixated in a session, each with its position in the
world (marker-map) frame, mm, and the [start, end] times (s, the session's clock) it was fixated.
A simulator's ``truth/targets.json`` is accepted too: its static targets are the validation
targets (moving ones are left out).

``person.json``: per eye the correction (horizontal, vertical), degrees, added to the Fick angles
of that eye's head-frame directions (``calibration.kappa``'s model: the negative of the bias the
tracker shows), with the samples and targets it was learned from and the RMS angular error
before and after it.

One reader and one writer each: ``read_validation`` / ``write_validation``, ``read_person`` /
``write_person``; ``person_correction_deg`` is the (2, 2) array the pipeline applies.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import UserError
from .jsonio import fail, read_json_text, short, validate, write_json

log = logging.getLogger(__name__)

VALIDATION_FORMAT = "wearable-gaze-validation"
PERSON_FORMAT = "wearable-gaze-person"


def write_validation(path, targets: list[dict]) -> None:
    """Write a validation.json: ``targets`` as dicts with ``position_mm`` (3,) world frame, mm,
    ``fixations_s`` ([start, end] pairs, s) and optionally ``name``."""
    write_json(path, {"format": VALIDATION_FORMAT, "version": 1, "targets": targets})


def _from_truth(d: dict) -> dict:
    """A simulator's truth/targets.json as a validation dict: its static targets."""
    keep = [{k: t[k] for k in ("name", "position_mm", "fixations_s") if k in t}
            for t in d["targets"] if isinstance(t, dict) and not t.get("moving") and t.get("fixations_s")]
    return {"format": VALIDATION_FORMAT, "version": 1, "targets": keep}


def read_validation(path) -> list[dict]:
    """The targets of a validation.json (or of a simulator's truth/targets.json): dicts with
    ``position_mm`` (3,) world frame, mm, ``fixations_s`` ([start, end] pairs, s) and ``name``.

    Raises:
        UserError: a missing or malformed file, an interval that ends before it starts.
    """
    d = read_json_text(path, "validation file")
    source = path
    if isinstance(d, dict) and "format" not in d and isinstance(d.get("targets"), list):
        source = f"{path} (read as a simulator's truth targets)"
        if d.get("version", 1) != 1:             # a truth file of another version may mean other things
            raise UserError(f"{source}: version {short(d['version'])}, but this program reads version 1; give a "
                            "validation.json (docs/calibration.md) or a truth/targets.json of this version")
        d = _from_truth(d)                       # the simulator's truth/targets.json
        if not d["targets"]:
            raise UserError(f"{source}: no static target with a fixation; a validation needs fixated static targets")
    validate(d, "validation", source)
    for i, t in enumerate(d["targets"]):
        for j, (a, b) in enumerate(t["fixations_s"]):
            if not a < b:
                raise fail(source, "validation", ["targets", i, "fixations_s", j],
                           f"expected [start, end] with start < end, got {[a, b]}")
    return [{"name": t.get("name", f"target {i}"), "position_mm": t["position_mm"], "fixations_s": t["fixations_s"]}
            for i, t in enumerate(d["targets"])]


def write_person(path, person: dict) -> None:
    """Write a person.json: ``person`` holds ``eyes`` (left, right dicts with ``eye``,
    ``correction_deg`` (h, v) degrees and the fit's figures) and optionally ``session`` and
    ``validation``; the format tag is added here."""
    write_json(path, {"format": PERSON_FORMAT, "version": 1, **person})


def read_person(path) -> dict:
    """A person.json, validated (its schema, then the left eye then the right).

    Raises:
        UserError: a missing or malformed file.
    """
    d = read_json_text(path, "per-person bias file")
    validate(d, "person", path)
    names = [e["eye"] for e in d["eyes"]]
    if names != ["left", "right"]:
        raise fail(path, "person", ["eyes"], f"expected the left then the right eye, got {names}")
    return d


def person_correction_deg(person: dict) -> np.ndarray:
    """(2, 2) [eye (left, right), (horizontal, vertical)] degrees of a ``read_person`` dict."""
    return np.array([e["correction_deg"] for e in person["eyes"]], float)
