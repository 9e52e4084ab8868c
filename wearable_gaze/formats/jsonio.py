"""Reading and writing the project's JSON files: one mechanism for every format.

Each format has a JSON Schema in ``wearable_gaze/formats/schemas/NAME.schema.json`` (``SCHEMA_NAMES``:
the inputs session, camera, eyes, marker-map, board, walls, scenario, validation, person; the outputs
targets, summary, viewlines-counts, steps-state; the printed estimate-line and live-message).
``load_json(path, name)`` reads the file, checks it against its schema and then runs the format's
numeric checks that a schema cannot express (matrix consistency, principal point inside the image, ...).
Any problem is a ``UserError`` whose message is one line: the file, the JSON path of the bad field,
what was expected and how to fix it. ``write_json`` writes every JSON file the same way (indent 1, atomically).
"""

from __future__ import annotations

import json
import logging
import math
from functools import cache
from importlib import resources
from pathlib import Path

from ..errors import UserError
from .atomic import write_text

log = logging.getLogger(__name__)

SCHEMA_NAMES = ("session", "camera", "eyes", "marker-map", "board", "walls", "scenario", "validation", "person",
                "targets", "summary", "viewlines-counts", "steps-state", "live-message", "estimate-line", "sfm-map",
                "aois")


@cache
def schema(name: str) -> dict:
    """The parsed JSON Schema of format ``name`` (one of ``SCHEMA_NAMES``)."""
    if name not in SCHEMA_NAMES:
        raise ValueError(f"no schema {name!r}; known: {', '.join(SCHEMA_NAMES)}")
    text = resources.files(__package__).joinpath("schemas", f"{name}.schema.json")
    return json.loads(text.read_text(encoding="utf-8"))


@cache
def _validator(name: str):
    from jsonschema import Draft202012Validator
    from referencing import Registry, Resource  # jsonschema's own dependency

    s = schema(name)
    Draft202012Validator.check_schema(s)
    # a schema refers to another by its file name ("targets.schema.json#/$defs/target")
    registry = Registry().with_resources((schema(n)["$id"], Resource.from_contents(schema(n))) for n in SCHEMA_NAMES)
    return Draft202012Validator(s, registry=registry)


def short(value, limit: int = 60) -> str:
    """A value as JSON, cut to ``limit`` characters, on one line (safe to print)."""
    try:
        text = json.dumps(value, ensure_ascii=True)
    except (TypeError, ValueError):
        text = repr(value)
    text = text.encode("ascii", "backslashreplace").decode("ascii")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def json_path(parts) -> str:
    """``['files', 'scene_video']`` -> ``files.scene_video``; ``['markers', 3, 'id']`` -> ``markers[3].id``."""
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += ("." if out else "") + str(p)
    return out or "(top level)"


def _fix(name: str) -> str:
    s = schema(name)
    fix = s.get("x-fix")
    doc = s.get("x-doc")
    text = f"fix the field (see {doc})" if doc else "fix the field"
    return f"{text}, or {fix}" if fix else text


def fail(source, name: str, where, detail: str) -> UserError:
    """The one-line error of a bad field: ``SOURCE: field 'PATH' of the TITLE: DETAIL; fix the field (see DOC)``."""
    where = json_path(where) if not isinstance(where, str) else where
    return UserError(f"{source}: field '{where}' of the {schema(name)['title']}: {detail}; {_fix(name)}")


def _describe(err) -> str:
    """What was expected and what was found, for one ``jsonschema.ValidationError``."""
    v, inst, sch = err.validator, err.instance, err.schema
    desc = sch.get("description") if isinstance(sch, dict) else None
    got = short(inst)
    if v == "type":
        types = err.validator_value if isinstance(err.validator_value, list) else [err.validator_value]
        want = desc or " or ".join({"integer": "a whole number", "number": "a number", "string": "a string",
                                     "array": "a list", "object": "an object", "boolean": "true or false",
                                     "null": "null"}[t] for t in types)
        return f"expected {want}, got {got}"
    if v == "required":
        missing = [k for k in err.validator_value if isinstance(inst, dict) and k not in inst]
        return f"missing key {short(missing[0] if missing else err.validator_value[0])}"
    if v == "additionalProperties":
        known = sorted(sch.get("properties", {}))
        return f"unknown field (known: {', '.join(known)})"
    if v in ("enum", "const"):
        options = err.validator_value if v == "enum" else [err.validator_value]
        want = desc or "one of " + ", ".join(short(o) for o in options)
        return f"expected {want}, got {got}"
    if v in ("minItems", "maxItems"):
        want = desc or f"{'at least' if v == 'minItems' else 'at most'} {err.validator_value} items"
        return f"expected {want}, got {len(inst)} item(s)"
    if v in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        op = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}[v]
        return f"expected a number {op} {err.validator_value:g}{f' ({desc})' if desc else ''}, got {got}"
    if v in ("pattern", "minLength", "maxLength"):
        return f"expected {desc or 'a string matching ' + short(err.validator_value)}, got {got}"
    if v == "propertyNames":
        return f"key {got}: expected {short(err.validator_value.get('pattern', ''))}"
    if v in ("anyOf", "oneOf"):
        alts = [r["required"] for r in err.validator_value if "required" in r]
        if alts and all(len(a) == 1 for a in alts):
            return f"needs one of the keys {', '.join(a[0] for a in alts)}"
        if alts and isinstance(inst, dict):
            return "missing keys: " + " or ".join(", ".join(k for k in a if k not in inst) for a in alts)
    return f"{err.message[:120]}" if "\n" not in err.message else f"{v} check failed, got {got}"


def _non_finite(obj, where=()):
    """The path of the first number that is not finite (1e400 parses as inf), or None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return list(where)
    if isinstance(obj, dict):
        for k, v in obj.items():
            p = _non_finite(v, (*where, k))
            if p is not None:
                return p
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            p = _non_finite(v, (*where, i))
            if p is not None:
                return p
    return None


def validate(obj, name: str, source) -> None:
    """Check ``obj`` against schema ``name`` and the format's numeric checks.

    Raises:
        UserError: one line naming ``source``, the JSON path, what was expected and the fix.
    """
    from jsonschema.exceptions import best_match

    bad = _non_finite(obj)
    if bad is not None:
        raise fail(source, name, bad, "not a finite number (NaN, Infinity or out of range); write a finite value")
    err = best_match(_validator(name).iter_errors(obj))
    if err is not None:
        where = list(err.absolute_path)
        if err.validator == "additionalProperties" and isinstance(err.instance, dict):
            known = err.schema.get("properties", {})
            where += [next((k for k in err.instance if k not in known), "?")]
        raise fail(source, name, where, _describe(err))
    check = CHECKS.get(name)
    if check is not None:
        check(obj, source)


def read_json_text(path, what: str = "JSON file"):
    """Parse a JSON file strictly (UTF-8; no NaN or Infinity), without a schema.

    Raises:
        UserError: missing or unreadable file, another encoding, invalid JSON.
    """
    path = Path(path)
    if not path.is_file():
        hint = "it is a folder, not a file" if path.is_dir() else "no such file"
        raise UserError(f"{path}: {hint}; pass the {what} (check the path)")
    data = path.read_bytes()
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or (len(data) > 1 and (data[0] == 0 or data[1] == 0)):
        raise UserError(f"{path}: the {what} is UTF-16 (or binary); save it as UTF-8 JSON")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: the {what} is not UTF-8 text (byte {exc.start}); save it as UTF-8 JSON") from None

    def constant(name):
        raise ValueError(f"{name} is not a JSON number; write a finite number")

    try:
        return json.loads(text, parse_constant=constant)
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: the {what} is not valid JSON (line {exc.lineno} column {exc.colno}: "
                        f"{exc.msg}); fix the syntax") from None
    except ValueError as exc:
        raise UserError(f"{path}: the {what}: {exc}") from None
    except RecursionError:
        raise UserError(f"{path}: the {what} is nested too deeply to be one of our files") from None


def load_json(path, name: str):
    """Read ``path`` and validate it as format ``name`` (``SCHEMA_NAMES``); return the parsed object.

    Raises:
        UserError: one line (file, JSON path, what was expected, how to fix it).
    """
    obj = read_json_text(path, schema(name)["title"])
    validate(obj, name, path)
    return obj


def write_json(path, obj) -> None:
    """Write ``obj`` as JSON (indent 1, a final newline), atomically: the one JSON writer."""
    write_text(path, json.dumps(obj, indent=1) + "\n")


def inside(root, rel: str, source, name: str, where) -> Path:
    """``root / rel`` after checking it stays inside ``root`` (symbolic links resolved).

    Raises:
        UserError: an absolute path or one that leaves ``root``.
    """
    root = Path(root)
    p = root / rel
    try:
        ok = Path(rel).is_absolute() is False and p.resolve().is_relative_to(root.resolve())
    except (OSError, RuntimeError, ValueError):
        ok = False
    if not ok:
        raise fail(source, name, where, f"{short(rel)} leaves the folder {root}; give a path inside it")
    return p


# --- numeric checks a schema cannot express ------------------------------------------------------

def _check_camera(d: dict, source) -> None:
    K = d["camera_matrix"]
    w, h = d["image_size"]
    if not (K[0][0] > 0 and K[1][1] > 0):
        raise fail(source, "camera", ["camera_matrix"], f"focal lengths fx {K[0][0]:g}, fy {K[1][1]:g} must be > 0")
    if K[1][0] != 0 or K[2] != [0, 0, 1]:
        raise fail(source, "camera", ["camera_matrix"], "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    if not (0 <= K[0][2] <= w and 0 <= K[1][2] <= h):
        raise fail(source, "camera", ["camera_matrix"], f"principal point ({K[0][2]:g}, {K[1][2]:g}) lies outside "
                   f"the {w}x{h} image")
    model = d.get("model", "pinhole")
    n = len(d["dist_coeffs"])
    if model == "fisheye" and n != 4 or model == "pinhole" and n not in (0, 4, 5, 8, 12, 14):
        raise fail(source, "camera", ["dist_coeffs"], f"{n} values, which the {model} model does not take "
                   "(pinhole 0, 4, 5, 8, 12 or 14; fisheye 4)")


def _check_eyes(d: dict, source) -> None:
    names = [e["eye"] for e in d["eyes"]]
    if names != ["left", "right"]:
        raise fail(source, "eyes", ["eyes"], f"expected the left then the right eye, got {short(names)}")
    for i, e in enumerate(d["eyes"]):
        m = e["raw_map"]
        need = 10 if m["model"] == "cubic" else 6
        if len(m["coef"]) != need:
            raise fail(source, "eyes", ["eyes", i, "raw_map", "coef"],
                       f"the {m['model']} model has {need} rows of 2, got {len(m['coef'])}")
        if m["model"] == "tps":
            tps = m.get("tps")
            if not tps or len(tps["nodes"]) != len(tps["values"]):
                raise fail(source, "eyes", ["eyes", i, "raw_map", "tps"],
                           "the tps model needs as many nodes as values")
        if abs(e["centre_mm"][2]) >= e["plane_mm"]:
            raise fail(source, "eyes", ["eyes", i, "plane_mm"], "the calibration plane must lie beyond the eye centre")


def _check_dictionary(name: str, value: str, source, where) -> None:
    from calibration.camera import ARUCO_DICTS

    if value not in ARUCO_DICTS:
        raise fail(source, name, where, f"unknown marker dictionary {short(value)}: use a cv2.aruco name such as "
                   "DICT_4X4_50 or DICT_APRILTAG_36h11")


def _check_marker_map(d: dict, source) -> None:
    _check_dictionary("marker-map", d["dictionary"], source, ["dictionary"])


def _check_board(d: dict, source) -> None:
    b = d["board"]
    if b["type"] == "charuco":
        _check_dictionary("board", b["dictionary"], source, ["board", "dictionary"])
        if not b["marker_mm"] < b["square_mm"]:
            raise fail(source, "board", ["board", "marker_mm"], "a ChArUco marker must be smaller than its square")


def _check_walls(d: dict, source) -> None:
    for r, rec in enumerate(d["recordings"]):
        _check_dictionary("walls", rec["dictionary"], source, ["recordings", r, "dictionary"])


def _check_session(d: dict, source) -> None:
    root = Path(source).parent
    for key, rel in d["files"].items():
        inside(root, rel, source, "session", ["files", key])


CHECKS = {"camera": _check_camera, "eyes": _check_eyes, "marker-map": _check_marker_map, "board": _check_board,
          "walls": _check_walls, "session": _check_session}
