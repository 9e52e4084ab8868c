"""Scenarios: what a simulated session contains. A scenario is a JSON object; every field has a
default (``DEFAULTS``), a user's file overrides some of them, and validation names the field that
is wrong. The schema is documented in docs/scenarios.md.
"""

from __future__ import annotations

import copy
import json

from ..errors import UserError

SCENARIO_VERSION = 1

DEFAULTS = {
    "version": SCENARIO_VERSION,
    "name": "custom",
    "duration_s": 20.0,
    "camera": {
        "resolution": [1280, 720],
        "hfov_deg": 90.0,
        "dist_coeffs": [-0.28, 0.09, 0.0, 0.0, -0.012],
        "fps": 30.0,
        "noise_std": 2.0,
        "gain": 1.0,
        "motion_blur_samples": 1,
        "codec": "mp4v",
    },
    "eyes": {
        "rate_hz": 60.0,
        "ipd_mm": 64.0,
        "centre_offset_mm": [0.0, 30.0, -20.0],
        "sigma_deg": 1.0,
        "bias_deg": [[0.0, 0.0], [0.0, 0.0]],
        "blink_rate_hz": 0.2,
        "dropout_rate": 0.01,
        "fixation_s": [2.5, 4.0],
        "pursuit_lag_s": 0.08,
        "order": "cycle",
    },
    "room": {
        "layout": "lab",
        "size_mm": [4000.0, 2700.0, 5000.0],
        "eye_height_mm": 1600.0,
        "back_mm": 1500.0,
        "dictionary": "DICT_4X4_50",
        "marker_size_mm": 200.0,
        "markers_per_wall": 6,
        "posters_per_wall": 2,
    },
    "targets": {
        "points_mm": [],
        "random_count": 4,
        "random_depth_mm": [500.0, 4000.0],
        "moving": [],
        "size_mm": 100.0,
    },
    "head": {
        "motion": "sway",
        "start_mm": [0.0, 0.0, 0.0],
        "forward": [0.0, 0.0, 1.0],
        "translation_mm": [200.0, 0.0, 0.0],
        "sway_deg": 10.0,
        "sway_mm": 150.0,
        "follow": 0.7,
        "walk_to_mm": [0.0, 0.0, 2000.0],
        "speed_mm_s": 400.0,
    },
    "calibration": {
        "eye": True,
        "walls": [{"distance_mm": 1000.0, "grid": [3, 3], "tilt_deg": 12.0},
                  {"distance_mm": 500.0, "grid": [5, 5], "tilt_deg": -8.0},
                  {"distance_mm": 2000.0, "grid": [5, 5], "tilt_deg": 6.0}],
        "span_deg": [20.0, 15.0],
        "dwell_s": 1.5,
        "camera_board": {"type": "chessboard", "cols": 9, "rows": 6, "square_mm": 30.0},
        "camera_views": 15,
    },
    "session": True,
}

CHOICES = {
    "camera.codec": ("mp4v", "MJPG", "FFV1"),
    "eyes.order": ("cycle", "random"),
    "room.layout": ("lab", "none"),
    "head.motion": ("fixed", "linear", "sway", "walk"),
}
POSITIVE = {"duration_s", "camera.hfov_deg", "camera.fps", "eyes.rate_hz", "eyes.ipd_mm",
            "room.marker_size_mm", "targets.size_mm", "calibration.dwell_s", "camera.gain"}
NON_NEGATIVE = {"camera.noise_std", "eyes.sigma_deg", "eyes.blink_rate_hz", "eyes.dropout_rate",
                "eyes.pursuit_lag_s", "head.sway_deg", "head.sway_mm", "head.speed_mm_s",
                "targets.random_count", "room.markers_per_wall", "room.posters_per_wall",
                "calibration.camera_views"}
FREE_FORM = {"calibration.camera_board", "targets.points_mm", "targets.moving", "eyes.bias_deg",
             "calibration.walls", "camera.dist_coeffs"}

# named scenarios: overrides of DEFAULTS
NAMED = {
    "paper-table1": {
        "name": "paper-table1",
        "duration_s": 200 / 30.0,
        "eyes": {"rate_hz": 30.0, "ipd_mm": 65.0, "centre_offset_mm": [0.0, 0.0, 0.0], "blink_rate_hz": 0.0,
                 "dropout_rate": 0.0, "fixation_s": [1000.0, 1000.0]},
        "room": {"markers_per_wall": 8},
        "targets": {"points_mm": [[0.0, 0.0, 3000.0]], "random_count": 0},
        "head": {"motion": "linear", "start_mm": [-100.0, 0.0, 0.0], "translation_mm": [200.0, 0.0, 0.0]},
    },
    "lab-walkabout": {
        "name": "lab-walkabout",
        "duration_s": 20.0,
        "targets": {"random_count": 4, "random_depth_mm": [500.0, 4000.0]},
        "head": {"motion": "sway"},
    },
    "moving-target": {
        "name": "moving-target",
        "duration_s": 15.0,
        "eyes": {"fixation_s": [1000.0, 1000.0]},
        "targets": {"points_mm": [[-600.0, 0.0, 2000.0]], "random_count": 0, "moving": [0]},
        "head": {"motion": "fixed"},
    },
    "calibration-only": {
        "name": "calibration-only",
        "session": False,
    },
}


def _field_error(path: str, msg: str) -> UserError:
    return UserError(f"scenario field '{path}': {msg}")


def _merge(base: dict, over: dict, prefix: str = "") -> dict:
    out = copy.deepcopy(base)
    for key, val in over.items():
        path = f"{prefix}{key}"
        if key not in base:
            raise _field_error(path, f"unknown field (known: {', '.join(sorted(base))})")
        if isinstance(base[key], dict) and path not in FREE_FORM:
            if not isinstance(val, dict):
                raise _field_error(path, "expected an object")
            out[key] = _merge(base[key], val, path + ".")
        else:
            out[key] = copy.deepcopy(val)
    return out


def _check_types(value, default, path: str):
    if path in FREE_FORM:
        return
    if isinstance(default, dict):
        for k in default:
            _check_types(value[k], default[k], f"{path}.{k}" if path else k)
        return
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise _field_error(path, f"expected true or false, got {json.dumps(value)}")
    elif isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _field_error(path, f"expected a number, got {json.dumps(value)}")
        if path in POSITIVE and not value > 0:
            raise _field_error(path, f"must be > 0, got {value}")
        if path in NON_NEGATIVE and value < 0:
            raise _field_error(path, f"must be >= 0, got {value}")
    elif isinstance(default, str):
        if not isinstance(value, str):
            raise _field_error(path, f"expected a string, got {json.dumps(value)}")
        if path in CHOICES and value not in CHOICES[path]:
            raise _field_error(path, f"expected one of {', '.join(CHOICES[path])}, got {value!r}")
    elif isinstance(default, list):
        if not isinstance(value, list) or len(value) != len(default) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            raise _field_error(path, f"expected a list of {len(default)} numbers, got {json.dumps(value)}")


def _check_free_form(s: dict):
    def points(val, path, n=3, min_len=0):
        if not isinstance(val, list) or len(val) < min_len or not all(
                isinstance(p, list) and len(p) == n and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                            for v in p) for p in val):
            raise _field_error(path, f"expected a list of [{', '.join('xyz'[:n]) if n <= 3 else n}] "
                                     f"number lists, got {json.dumps(val)}")
    points(s["targets"]["points_mm"], "targets.points_mm")
    points(s["eyes"]["bias_deg"], "eyes.bias_deg", n=2, min_len=2)
    if len(s["eyes"]["bias_deg"]) != 2:
        raise _field_error("eyes.bias_deg", "expected [[left h, v], [right h, v]] in degrees")
    walls = s["calibration"]["walls"]
    if not isinstance(walls, list) or not walls:
        raise _field_error("calibration.walls", "expected a non-empty list of {distance_mm, grid, tilt_deg}")
    for i, w in enumerate(walls):
        path = f"calibration.walls[{i}]"
        if not isinstance(w, dict) or set(w) != {"distance_mm", "grid", "tilt_deg"}:
            raise _field_error(path, "expected an object with distance_mm, grid [cols, rows] and tilt_deg")
        if not isinstance(w["distance_mm"], (int, float)) or not 200 <= w["distance_mm"] <= 10000:
            raise _field_error(path + ".distance_mm", f"expected 200-10000 mm, got {w['distance_mm']!r}")
        g = w["grid"]
        if not (isinstance(g, list) and len(g) == 2 and all(isinstance(v, int) and 2 <= v <= 9 for v in g)):
            raise _field_error(path + ".grid", f"expected [cols, rows] of 2-9 dots each, got {g!r}")
        if not isinstance(w["tilt_deg"], (int, float)) or abs(w["tilt_deg"]) > 45:
            raise _field_error(path + ".tilt_deg", f"expected -45..45 degrees, got {w['tilt_deg']!r}")
    dc = s["camera"]["dist_coeffs"]
    if not isinstance(dc, list) or len(dc) not in (4, 5, 8) or not all(isinstance(v, (int, float)) for v in dc):
        raise _field_error("camera.dist_coeffs", "expected 4, 5 or 8 OpenCV distortion coefficients")
    mv = s["targets"]["moving"]
    n_targets = len(s["targets"]["points_mm"]) + int(s["targets"]["random_count"])
    if not isinstance(mv, list) or not all(isinstance(i, int) and 0 <= i < n_targets for i in mv):
        raise _field_error("targets.moving", f"expected indices of targets (0..{n_targets - 1}), got {mv!r}")
    if s["session"] and n_targets == 0:
        raise _field_error("targets", "a session needs at least one target (points_mm or random_count)")
    lo, hi = s["targets"]["random_depth_mm"]
    if not 0 < lo <= hi:
        raise _field_error("targets.random_depth_mm", f"expected 0 < near <= far, got {[lo, hi]}")
    board = s["calibration"]["camera_board"]
    if not isinstance(board, dict) or board.get("type") not in ("chessboard", "charuco"):
        raise _field_error("calibration.camera_board.type", "expected 'chessboard' or 'charuco'")
    need = ("cols", "rows", "square_mm") + (("marker_mm", "dictionary") if board["type"] == "charuco" else ())
    for k in need:
        if k not in board:
            raise _field_error(f"calibration.camera_board.{k}", "missing")
    if 4 * s["room"]["markers_per_wall"] > 46:
        raise _field_error("room.markers_per_wall", "at most 11: ids 46-49 are the calibration wall's markers")
    w, h = s["camera"]["resolution"]
    if not (int(w) == w and int(h) == h and 64 <= w <= 8192 and 64 <= h <= 8192):
        raise _field_error("camera.resolution", f"expected [width, height] in pixels (64-8192), got {[w, h]}")
    if not 0 < s["head"]["follow"] <= 1 and s["head"]["motion"] in ("sway", "walk"):
        raise _field_error("head.follow", "expected a fraction in (0, 1]")


def resolve(scenario, duration_s=None, resolution=None) -> dict:
    """A complete, validated scenario dict.

    Args:
        scenario: a named scenario (str, ``NAMED``) or a dict parsed from JSON (may name a base
            scenario in ``"base"``).
        duration_s, resolution: command-line overrides.

    Raises:
        UserError: naming the offending field.
    """
    if isinstance(scenario, str):
        if scenario not in NAMED:
            raise UserError(f"unknown scenario {scenario!r}: use one of {', '.join(NAMED)} or a JSON file")
        over = NAMED[scenario]
    else:
        if not isinstance(scenario, dict):
            raise UserError("scenario file: expected a JSON object at the top level")
        over = dict(scenario)
        base = over.pop("base", None)
        if base is not None:
            if base not in NAMED:
                raise _field_error("base", f"unknown scenario {base!r}: use one of {', '.join(NAMED)}")
            over = _merge(_merge(DEFAULTS, NAMED[base]), over)
    s = _merge(DEFAULTS, over)
    if s["version"] != SCENARIO_VERSION:
        raise _field_error("version", f"this program reads version {SCENARIO_VERSION}, got {s['version']!r}")
    if duration_s is not None:
        s["duration_s"] = float(duration_s)
    if resolution is not None:
        s["camera"]["resolution"] = list(resolution)
    _check_types(s, DEFAULTS, "")
    _check_free_form(s)
    return s
