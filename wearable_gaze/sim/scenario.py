"""Scenarios: what a simulated session contains. A scenario is a JSON object; every field has a
default (``DEFAULTS``), a user's file overrides some of them, and validation names the field that
is wrong. The schema is documented in docs/scenarios.md.
"""

from __future__ import annotations

import copy
import logging

from ..errors import UserError
from ..formats.jsonio import fail, short, validate

log = logging.getLogger(__name__)

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
        "survey_inset_mm": 1300.0,
        "survey_loop_s": 60.0,
        "survey_walls_mm": None,
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

# replaced as a whole by a scenario that gives them (not merged field by field)
FREE_FORM = {"calibration.camera_board", "calibration.walls"}

# fields without a default: absent unless a scenario gives them (so that a scenario without them
# resolves, and writes its session, exactly as before they existed); their defaults inside
MOVED_MARKER_DEFAULTS = {"shift_mm": [0.0, 0.0, 0.0], "turn_deg": 0.0}
"""``moved_marker``: ``{"id", "at_s", "shift_mm", "turn_deg"}``, one marker moved during the
session (``world.moved_pose``; docs/scenarios.md)."""

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
    "survey": {
        "name": "survey",
        "duration_s": 60.0,
        "eyes": {"fixation_s": [1000.0, 1000.0]},
        "room": {"markers_per_wall": 6},
        "targets": {"points_mm": [[0.0, 0.0, 1000.0]], "random_count": 0},
        "head": {"motion": "survey", "sway_deg": 3.0, "sway_mm": 50.0, "survey_loop_s": 60.0},
        "calibration": {"camera_views": 8},
    },
    "calibration-only": {
        "name": "calibration-only",
        "session": False,
    },
}


def _merge(base: dict, over: dict, prefix: str = "") -> dict:
    """``over`` (already checked against the schema) merged into ``base`` field by field."""
    out = copy.deepcopy(base)
    for key, val in over.items():
        path = f"{prefix}{key}"
        if isinstance(base.get(key), dict) and isinstance(val, dict) and path not in FREE_FORM:
            out[key] = _merge(base[key], val, path + ".")
        else:
            out[key] = copy.deepcopy(val)
    return out


def check_scenario(s: dict, source="scenario") -> None:
    """What the scenario schema cannot express: relations between fields, dictionary names, a
    session long enough to hold two frames and two eye samples.

    Raises:
        UserError: one line naming the field.
    """
    from calibration.camera import ARUCO_DICTS

    def bad(where, detail):
        return fail(source, "scenario", where, detail)

    n_targets = len(s["targets"]["points_mm"]) + int(s["targets"]["random_count"])
    for i in s["targets"]["moving"]:
        if not i < n_targets:
            raise bad(["targets", "moving"], f"target {i} does not exist (there are {n_targets}: 0..{n_targets - 1})")
    if s["session"] and n_targets == 0:
        raise bad(["targets"], "a session needs at least one target: give points_mm or random_count")
    lo, hi = s["targets"]["random_depth_mm"]
    if not lo <= hi:
        raise bad(["targets", "random_depth_mm"], f"expected [near, far] with near <= far, got {[lo, hi]}")
    lo, hi = s["eyes"]["fixation_s"]
    if not lo <= hi:
        raise bad(["eyes", "fixation_s"], f"expected [shortest, longest] with shortest <= longest, got {[lo, hi]}")
    board = s["calibration"]["camera_board"]
    for where, name in ((["room", "dictionary"], s["room"]["dictionary"]),
                        (["calibration", "camera_board", "dictionary"], board.get("dictionary"))):
        if name is not None and name not in ARUCO_DICTS:
            raise bad(where, f"unknown marker dictionary {short(name)}: use a cv2.aruco name such as DICT_4X4_50")
    if board["type"] == "charuco" and not board["marker_mm"] < board["square_mm"]:
        raise bad(["calibration", "camera_board", "marker_mm"], "a ChArUco marker must be smaller than its square")
    if s["head"]["motion"] in ("sway", "walk") and not s["head"]["follow"] > 0:
        raise bad(["head", "follow"], "expected a fraction in (0, 1] for sway and walk motion")
    if s["head"]["motion"] == "survey":
        _check_survey(s["head"], bad)
    if s.get("moved_marker") is not None:
        _check_moved_marker(s, bad)
    if not any(s["head"]["forward"]):
        raise bad(["head", "forward"], "the heading must be a non-zero vector")
    if s["session"]:
        need = 2 / min(s["camera"]["fps"], s["eyes"]["rate_hz"])      # two frames and two eye samples
        if s["duration_s"] < need:
            raise bad(["duration_s"], f"{s['duration_s']:g} s is too short for a session: give at least "
                      f"{need:.3g} s (--duration)")


def _check_survey(head: dict, bad) -> None:
    """The survey's loop fits inside its walls and keeps its sway away from them."""
    x0, z0, x1, z1 = head["survey_walls_mm"]
    inset = head["survey_inset_mm"]
    if not (x1 - x0 > 2 * inset + 100 and z1 - z0 > 2 * inset + 100):
        most = (min(x1 - x0, z1 - z0) - 100) / 2
        raise bad(["head", "survey_inset_mm"], f"a loop {inset:g} mm from walls {x1 - x0:g} x {z1 - z0:g} mm apart "
                  f"does not fit: give at most {most:g} (or a larger room.size_mm)")
    if not inset >= head["sway_mm"] + 300:
        raise bad(["head", "survey_inset_mm"], f"{inset:g} mm from the walls leaves too little room for "
                  f"head.sway_mm {head['sway_mm']:g}: give at least sway_mm + 300")


def _check_moved_marker(s: dict, bad) -> None:
    """The moved marker exists, moves inside the session, and stays on or in front of its wall."""
    mv = s["moved_marker"]
    n = 4 * int(s["room"]["markers_per_wall"]) if s["room"]["layout"] == "lab" else 0
    if not s["session"]:
        raise bad(["moved_marker"], "a calibration-only scenario (session false) has no session to move a marker in")
    if not mv["id"] < n:
        have = f"there are {n}: 0..{n - 1}" if n else "the room has none"
        raise bad(["moved_marker", "id"], f"marker {mv['id']} does not exist ({have})")
    if not 0 < mv["at_s"] < s["duration_s"]:
        raise bad(["moved_marker", "at_s"], f"{mv['at_s']:g} s is not inside the session: give a time between 0 "
                  f"and duration_s ({s['duration_s']:g} s)")
    if not any(mv["shift_mm"]) and mv["turn_deg"] % 360 == 0:
        raise bad(["moved_marker"], "the move leaves the marker where it was: give shift_mm or turn_deg")
    if mv["shift_mm"][2] > 0:
        raise bad(["moved_marker", "shift_mm"], f"z {mv['shift_mm'][2]:g} mm puts the marker behind its wall: "
                  "z is along its normal, into the wall; give 0 (on the wall) or less (in front of it)")


def survey_walls(room: dict) -> list:
    """[left x, back z, right x, front z] of a room's walls, world mm (as ``world.lab_room`` puts them)."""
    width, _, depth = (float(v) for v in room["size_mm"])
    back = float(room["back_mm"])
    return [-width / 2, -back, width / 2, depth - back]


def resolve(scenario, duration_s=None, resolution=None, source="scenario") -> dict:
    """A complete, validated scenario dict.

    Args:
        scenario: a named scenario (str, ``NAMED``) or a dict parsed from JSON (may name a base
            scenario in ``"base"``).
        duration_s, resolution: command-line overrides.
        source: the file (or "scenario") named in messages.

    Raises:
        UserError: naming the offending field (the schema wearable_gaze/formats/schemas/scenario.schema.json,
            then ``check_scenario``).
    """
    if isinstance(scenario, str):
        if scenario not in NAMED:
            raise UserError(f"unknown scenario {short(scenario)}: use one of {', '.join(NAMED)} or a JSON file")
        over = NAMED[scenario]
    else:
        validate(scenario, "scenario", source)
        over = dict(scenario)
        base = over.pop("base", None)
        if base is not None:
            over = _merge(_merge(DEFAULTS, NAMED[base]), over)
    s = _merge(DEFAULTS, over)
    if duration_s is not None:
        s["duration_s"] = float(duration_s)
    if resolution is not None:
        s["camera"]["resolution"] = list(resolution)
    if s["head"]["motion"] == "survey" and s["head"]["survey_walls_mm"] is None:
        s["head"]["survey_walls_mm"] = survey_walls(s["room"])
    if isinstance(s.get("moved_marker"), dict):
        s["moved_marker"] = {**copy.deepcopy(MOVED_MARKER_DEFAULTS), **s["moved_marker"]}
    if isinstance(scenario, str):
        source = f"scenario {scenario}"
    if duration_s is not None or resolution is not None:
        source = f"{source} with --duration/--resolution"
    validate(s, "scenario", source)
    check_scenario(s, source)
    log.debug("%s: %g s, %s px at %g fps, head motion %s", source, s["duration_s"], s["camera"]["resolution"],
              s["camera"]["fps"], s["head"]["motion"])
    return s
