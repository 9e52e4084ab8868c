"""The bad-input matrix (issue 12): every command, every kind of bad input.

Each case runs ``wearable_gaze.cli.main(argv)`` in-process and asserts: exit status 2, exactly one
line on stderr (``process``, which goes on with its other steps, one line per problem) naming the
problem, with a fix, no traceback; every input and every earlier output byte-identical afterwards,
and no file left behind. A few cases run the installed ``wearable-gaze`` executable as well.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from wearable_gaze.cli import main

# --- fixtures: one tiny simulated session and its calibrations, built once --------------------


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    base = tmp_path_factory.mktemp("bad_inputs")
    s = base / "session"
    assert main(["simulate", "-o", str(s), "--resolution", "320x180", "--duration", "2"]) == 0
    shutil.copy(s / "truth" / "camera.json", base / "camera.json")
    shutil.copy(s / "truth" / "head_poses.csv", base / "poses.csv")
    assert main(["calibrate-eyes", str(s), "--camera", str(base / "camera.json"), "-o", str(base / "eyes.json")]) == 0
    return Env(base)


class Env:
    """Paths of the good inputs (never to be changed by a case)."""

    def __init__(self, base: Path):
        self.base = base
        self.session = base / "session"
        self.camera = base / "camera.json"
        self.eyes = base / "eyes.json"
        self.poses = base / "poses.csv"
        self.eye = self.session / "eye.csv"
        self.viewlines = self.session / "truth" / "viewlines.csv"
        self.markers = self.session / "markers.json"
        self.video = self.session / "scene.mp4"
        self.timestamps = self.session / "scene_timestamps.csv"
        self.views = self.session / "calibration" / "camera"
        self.eye_cal = self.session / "calibration" / "eye"
        self.board = "chessboard:9x6:30"

    def __getitem__(self, key):
        return str(getattr(self, key))


def _snapshot(*roots) -> dict:
    """Every file under the roots with its SHA-256 (and every folder, as None)."""
    out = {}
    for root in roots:
        for dirpath, dirnames, filenames in os.walk(root):
            for n in dirnames:
                out[os.path.join(dirpath, n)] = None
            for n in filenames:
                p = os.path.join(dirpath, n)
                with open(p, "rb") as fh:
                    out[p] = hashlib.sha256(fh.read()).hexdigest()
    return out


def _run(argv, capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:                      # argparse
        code = exc.code
    out, err = capsys.readouterr()
    return code, err


FIX_WORDS = ("(see", "give", "choose", "pass ", "use ", "run ", "write ", "save ", "record", "check", "e.g.",
             "restore", "add ", "fix", "remove", "calibrate", "print ", "drop ", "complete", "leave", "sort ")


def _assert_one_line(err: str, match, command: str, many: bool = False) -> str:
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if many:
        assert lines, "no message on stderr"
    else:
        assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{err}"
    for ln in lines:
        assert ln.startswith("wearable-gaze"), ln
        assert "\x1b" not in ln and "\x00" not in ln, ln
    text = " ".join(lines)
    for m in (match,) if isinstance(match, str) else match:
        assert m.lower() in text.lower(), f"{m!r} not in {text!r}"
    assert any(w in text for w in FIX_WORDS), f"no fix named in {text!r}"
    return text


# --- helpers to write bad files ----------------------------------------------------------------

def write(d: Path, name: str, content) -> str:
    p = d / name
    p.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, bytes):
        p.write_bytes(content)
    elif isinstance(content, str):
        p.write_text(content, encoding="utf-8")
    else:
        p.write_text(json.dumps(content), encoding="utf-8")
    return str(p)


def edited_json(src: Path, edit) -> dict:
    d = json.loads(src.read_text())
    edit(d)
    return d


def read_only_dir(d: Path) -> Path:
    """A folder nobody can write into (as root: the immutable attribute)."""
    ro = d / "ro"
    ro.mkdir()
    (ro / "keep.txt").write_text("keep")
    os.chmod(ro, 0o555)
    if os.geteuid() == 0:
        r = subprocess.run(["chattr", "+i", str(ro)], capture_output=True)
        if r.returncode != 0:
            pytest.skip("cannot make a read-only folder as root here (no chattr)")
    try:
        (ro / "probe").write_text("x")
    except OSError:
        return ro
    pytest.skip("cannot make a read-only folder here")


@pytest.fixture
def case_dir(tmp_path):
    yield tmp_path
    for p in tmp_path.rglob("ro"):
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(p)], capture_output=True)
        os.chmod(p, 0o755)


CSV_BINARY_HEADER = b"\x1b[31m\x7fELF\x01\x02\x1b[0m,t\n1,2\n"
UTF16_BOM = "\ufeff"


def utf16(text: str) -> bytes:
    return text.encode("utf-16")


# --- the cases ---------------------------------------------------------------------------------

@dataclass
class Case:
    id: str
    command: str
    build: object                  # (env, case dir) -> argv after the command name
    match: object = ()             # substring(s) the one line must contain
    many: bool = False             # process: one line per problem


CASES: list[Case] = []


def case(id_, command, match=()):
    def deco(fn):
        CASES.append(Case(id_, command, fn, match))
        return fn
    return deco


def add(id_, command, build, match=(), many=False):
    CASES.append(Case(id_, command, build, match, many))


# generic bad files of any kind: (id, name, content, expected words)
def generic_file_variants(ext: str):
    return [
        ("missing", None, None, "no such"),
        ("folder", "__dir__", None, "folder"),
        ("empty", f"f{ext}", b"", ("empty" if ext == ".csv" else "not valid json")),
        ("utf16", f"f{ext}", utf16("{}\n" if ext == ".json" else "t,x\n1,2\n"), "utf-16"),
        ("binary", f"f{ext}", b"\x00\x01\x02\xff\xfe garbage", "binary"),
        ("latin1", f"f{ext}", "caf\xe9,\xe9t\xe9\n1,2\n".encode("latin-1"), "not utf-8"),
    ]


def make_generic(d: Path, name, content) -> str:
    if name is None:
        return str(d / "does_not_exist")
    if name == "__dir__":
        (d / "a_folder.json").mkdir()
        return str(d / "a_folder.json")
    return write(d, name, content)


# commands and where a JSON or CSV file goes in their argv
def argv_estimate(e, vl, extra=()):
    return ["estimate", vl, *extra]


def argv_fixations(e, d, vl=None, out=None, extra=()):
    return ["fixations", vl or e["viewlines"], "-o", out or str(d / "fx.csv"), *extra]


def argv_viewlines(e, d, eye=None, eyes=None, poses=None, out=None):
    return ["viewlines", eye or e["eye"], "--eyes", eyes or e["eyes"], "--poses", poses or e["poses"],
            "-o", out or str(d / "vl.csv")]


def argv_track(e, d, video=None, camera=None, markers=None, out=None, extra=()):
    return ["track", video or e["video"], "--camera", camera or e["camera"], "--markers", markers or e["markers"],
            "-o", out or str(d / "poses.csv"), *extra]


def argv_calibrate_eyes(e, d, source=None, camera=None, out=None, extra=()):
    return ["calibrate-eyes", source or e["session"], "--camera", camera or e["camera"],
            "-o", out or str(d / "eyes.json"), *extra]


def argv_calibrate_camera(e, d, inputs=None, board=None, out=None, extra=()):
    return ["calibrate-camera", *(inputs or [e["views"]]), "--board", board or e.board,
            "-o", out or str(d / "camera.json"), *extra]


def argv_live(e, d, camera_calib=None, eyes=None, markers=None, extra=()):
    return ["live", "--serial", "socket://127.0.0.1:9", "--camera", e["video"],
            "--camera-calib", camera_calib or e["camera"], "--eyes", eyes or e["eyes"],
            "--markers", markers or e["markers"], "--duration", "0.5", "--quiet", *extra]


def argv_process(e, d, session, extra=()):
    return ["process", session, "-o", str(d / "out"), "--no-overlay", *extra]


# 1. generic file problems, for every file slot of every command ---------------------------------

FILE_SLOTS = [
    ("estimate-viewlines", "estimate", ".csv", lambda e, d, p: argv_estimate(e, p)),
    ("fixations-viewlines", "fixations", ".csv", lambda e, d, p: argv_fixations(e, d, p)),
    ("viewlines-eye", "viewlines", ".csv", lambda e, d, p: argv_viewlines(e, d, eye=p)),
    ("viewlines-poses", "viewlines", ".csv", lambda e, d, p: argv_viewlines(e, d, poses=p)),
    ("viewlines-eyes", "viewlines", ".json", lambda e, d, p: argv_viewlines(e, d, eyes=p)),
    ("track-camera", "track", ".json", lambda e, d, p: argv_track(e, d, camera=p)),
    ("track-video", "track", ".mp4", lambda e, d, p: argv_track(e, d, video=p)),
    ("track-reference", "track", ".png", lambda e, d, p: ["track", e["video"], "--camera", e["camera"], "--reference",
                                                           p, "--reference-size-mm", "300", "200",
                                                           "-o", str(d / "o.csv")]),
    ("track-markers", "track", ".json", lambda e, d, p: argv_track(e, d, markers=p)),
    ("track-timestamps", "track", ".csv", lambda e, d, p: argv_track(e, d, extra=["--timestamps", p])),
    ("calibrate-eyes-camera", "calibrate-eyes", ".json", lambda e, d, p: argv_calibrate_eyes(e, d, camera=p)),
    ("live-camera-calib", "live", ".json", lambda e, d, p: argv_live(e, d, camera_calib=p)),
    ("live-eyes", "live", ".json", lambda e, d, p: argv_live(e, d, eyes=p)),
    ("live-markers", "live", ".json", lambda e, d, p: argv_live(e, d, markers=p)),
    ("simulate-scenario", "simulate", ".json", lambda e, d, p: ["simulate", "--scenario", p, "-o", str(d / "s")]),
]

for slot, command, ext, build in FILE_SLOTS:
    for vid, name, content, words in generic_file_variants(ext):
        if slot == "simulate-scenario" and vid == "missing":
            words = "unknown scenario"
        if slot == "track-timestamps" and vid == "folder":
            words = "folder"
        if slot in ("track-video", "track-reference"):
            words = {"missing": "no such file", "folder": "is a folder"}.get(vid, slot.split("-")[1])

        def b(e, d, build=build, name=name, content=content):
            return build(e, d, make_generic(d, name, content))
        add(f"{slot}-{vid}", command, b, words)


# 2. CSV problems -------------------------------------------------------------------------------

def csv_variants(good: str, required: list[str]):
    """(id, text or bytes, expected words) of a bad CSV derived from a good one."""
    lines = good.splitlines()
    header, rows = lines[0], lines[1:6]
    cols = header.split(",")
    first_req = required[0]
    j = cols.index(required[-1])

    def set_cell(row, value, col=j):
        cells = row.split(",")
        cells[col] = value
        return ",".join(cells)

    return [
        ("header-only", header + "\n", "no data rows"),
        ("missing-column", ",".join(c for c in cols if c != first_req) + "\n"
         + "\n".join(",".join(v for c, v in zip(cols, r.split(","), strict=True) if c != first_req) for r in rows),
         ("missing column", first_req)),
        ("duplicated-column", header + "," + cols[1] + "\n" + "\n".join(r + "," + r.split(",")[1] for r in rows),
         ("appears more than once", cols[1])),
        ("binary-header", CSV_BINARY_HEADER, ("missing column", "\\x1b")),
        ("utf16", utf16("\n".join([header, *rows]) + "\n"), "utf-16"),
        ("text-cell", "\n".join([header, set_cell(rows[0], "abc"), *rows[1:]]) + "\n", ("not a number", "abc")),
        ("nan-cell", "\n".join([header, set_cell(rows[0], "nan"), *rows[1:]]) + "\n", "not a finite number"),
        ("inf-cell", "\n".join([header, set_cell(rows[0], "-inf"), *rows[1:]]) + "\n", "not a finite number"),
        ("huge-cell", "\n".join([header, set_cell(rows[0], "1e308"), *rows[1:]]) + "\n", ("1e308", "plausible")),
        ("escape-in-cell", "\n".join([header, set_cell(rows[0], "\x1b[2J"), *rows[1:]]) + "\n", ("not a number",
                                                                                                   "\\x1b")),
        ("truncated-row", "\n".join([header, *rows, rows[-1].split(",")[0]]) + "\n", ("cells", "truncated")),
        ("unterminated-quote", "\n".join([header, *rows]) + '\n"1,2\n', ("line", "")),
    ]


def add_csv_cases(slot, command, good_path_attr, required, build, time_col="t", skip=()):
    def variants(e):
        return csv_variants(Path(e[good_path_attr]).read_text(), required)

    # ids are needed at collection time: compute them from a fixed list
    ids = ["header-only", "missing-column", "duplicated-column", "binary-header", "utf16", "text-cell",
           "nan-cell", "inf-cell", "huge-cell", "escape-in-cell", "truncated-row", "unterminated-quote"]
    for k, vid in enumerate(ids):
        if vid in skip:
            continue

        def b(e, d, k=k):
            _, content, _ = variants(e)[k]
            return build(e, d, write(d, "bad.csv", content))
        CASES.append(Case(f"{slot}-csv-{vid}", command, b, _CsvMatch(good_path_attr, required, k)))
    if time_col:
        def b2(e, d):
            lines = Path(e[good_path_attr]).read_text().splitlines()
            text = "\n".join([lines[0], lines[2], lines[1], *lines[3:8]]) + "\n"
            return build(e, d, write(d, "bad.csv", text))
        add(f"{slot}-csv-time-not-increasing", command, b2, ("increase", "time"))


class _CsvMatch:
    """The expected words of a CSV variant, computed once the fixture exists."""

    def __init__(self, attr, required, k):
        self.attr, self.required, self.k = attr, required, k

    def resolve(self, e):
        return csv_variants(Path(e[self.attr]).read_text(), self.required)[self.k][2]


EYE_REQ = ["t", "counter", "left_x", "left_y", "right_x", "right_y", "left_valid", "right_valid"]
POSE_REQ = ["t", "frame", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]
VL_REQ = ["t", "left_ox", "left_oy", "left_oz", "left_dx", "left_dy", "left_dz",
          "right_ox", "right_oy", "right_oz", "right_dx", "right_dy", "right_dz"]

add_csv_cases("viewlines-eye", "viewlines", "eye", EYE_REQ, lambda e, d, p: argv_viewlines(e, d, eye=p))
add_csv_cases("viewlines-poses", "viewlines", "poses", POSE_REQ, lambda e, d, p: argv_viewlines(e, d, poses=p))
add_csv_cases("estimate", "estimate", "viewlines", VL_REQ, lambda e, d, p: argv_estimate(e, p), time_col=None)
add_csv_cases("fixations", "fixations", "viewlines", VL_REQ, lambda e, d, p: argv_fixations(e, d, p), time_col=None)
add_csv_cases("track-timestamps", "track", "timestamps", ["frame", "t"],
              lambda e, d, p: argv_track(e, d, extra=["--timestamps", p]), time_col="t",
              skip=("truncated-row",))


# 3. JSON of the wrong shape, per format ----------------------------------------------------------

def _camera_edits():
    def k(v):
        return lambda c: c.__setitem__("camera_matrix", v)
    return [
        ("list-top", lambda c: None, [1, 2, 3], ("top level", "expected an object")),
        ("K-ragged", k([[100, 0], [0, 100, 50], [0, 0, 1]]), None, ("camera_matrix[0]", "3")),
        ("K-strings", k([["a", 0, 1], [0, 1, 1], [0, 0, 1]]), None, ("camera_matrix[0][0]", "number")),
        ("K-negative-focal", lambda c: c["camera_matrix"][0].__setitem__(0, -5.0), None, ("focal", "> 0")),
        ("K-huge", lambda c: c["camera_matrix"][0].__setitem__(0, 1e308), None, ("camera_matrix[0][0]", "<=")),
        ("K-bottom-row", lambda c: c["camera_matrix"].__setitem__(2, [0, 1, 1]), None, ("camera_matrix", "[0, 0, 1]")),
        ("principal-point-outside", lambda c: c["camera_matrix"][0].__setitem__(2, 5000.0), None, "outside"),
        ("dist-overflow", None, '{"camera_matrix": [[160, 0, 160], [0, 160, 90], [0, 0, 1]], '
         '"dist_coeffs": [1e400, 0, 0, 0, 0], "image_size": [320, 180]}', ("dist_coeffs[0]", "finite")),
        ("dist-nan", None, '{"camera_matrix": [[160, 0, 160], [0, 160, 90], [0, 0, 1]], '
         '"dist_coeffs": [NaN, 0, 0, 0, 0], "image_size": [320, 180]}', ("nan", "finite")),
        ("dist-3-values", lambda c: c.__setitem__("dist_coeffs", [0.1, 0.0, 0.0]), None, ("dist_coeffs", "3 values")),
        ("dist-strings", lambda c: c.__setitem__("dist_coeffs", "none"), None, ("dist_coeffs", "coefficients")),
        ("size-zero", lambda c: c.__setitem__("image_size", [0, 180]), None, ("image_size[0]", ">= 1")),
        ("size-floats", lambda c: c.__setitem__("image_size", [320.5, 180]), None, ("image_size[0]", "whole")),
        ("no-image-size", lambda c: c.pop("image_size"), None, ("image_size", "missing")),
        ("model-unknown", lambda c: c.__setitem__("model", "spherical"), None, ("model", "pinhole")),
        ("fisheye-5-coeffs", lambda c: c.__setitem__("model", "fisheye"), None, ("dist_coeffs", "fisheye")),
        ("format-wrong", lambda c: c.__setitem__("format", "other"), None, ("format", "wearable-gaze-camera")),
    ]


CAMERA_SLOTS = [("track-camera", "track", lambda e, d, p: argv_track(e, d, camera=p)),
                ("calibrate-eyes-camera", "calibrate-eyes", lambda e, d, p: argv_calibrate_eyes(e, d, camera=p)),
                ("live-camera-calib", "live", lambda e, d, p: argv_live(e, d, camera_calib=p))]


def _json_case(slot, command, build, vid, good_attr, edit, raw, words, name="f.json"):
    def b(e, d):
        content = raw if raw is not None else edited_json(Path(e[good_attr]), edit)
        return build(e, d, write(d, name, content))
    add(f"{slot}-{vid}", command, b, words)


def _json_matrix(slots, edits, good_attr, subset):
    """Every edit of a JSON file in the first slot (command), the ``subset`` of edit ids in the others.
    ``edits``: (id, edit of the good file's JSON, raw content instead (or None), words of the message)."""
    for k, (slot, command, build) in enumerate(slots):
        for vid, edit, raw, words in edits:
            if k == 0 or vid in subset:
                _json_case(slot, command, build, vid, good_attr, edit, raw, words)


_json_matrix(CAMERA_SLOTS, _camera_edits(), "camera",
             ("K-ragged", "dist-nan", "list-top", "no-image-size", "K-huge", "dist-overflow"))

OPENCV_YAML = """%YAML:1.0
---
image_width: 320
image_height: 180
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 160., 0., 160., 0., 160., 90., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ {d} ]
"""
for slot, command, build in CAMERA_SLOTS[:2]:
    add(f"{slot}-yaml-garbage", command,
        lambda e, d, build=build: build(e, d, write(d, "cam.yml", "%YAML:1.0\n---\n: : [ {{{ !!opencv-matrix\n")),
        ("opencv", "camera"))
    add(f"{slot}-yaml-nan-dist", command,
        lambda e, d, build=build: build(e, d, write(d, "cam.yml", OPENCV_YAML.replace("{d}", ".nan, 0., 0., 0., 0."))),
        ("dist_coeffs", "finite"))
    add(f"{slot}-yaml-no-matrix", command,
        lambda e, d, build=build: build(e, d, write(d, "cam.yml", "%YAML:1.0\n---\nimage_width: 320\n")),
        ("camera_matrix",))
    add(f"{slot}-yaml-text-file", command,
        lambda e, d, build=build: build(e, d, write(d, "cam.txt", "fx=160 fy=160\n")), ("opencv", "camera"))


def _eyes_edits():
    def eye0(fn):
        return lambda c: fn(c["eyes"][0])
    return [
        ("format-wrong", lambda c: c.__setitem__("format", "x"), ("format", "wearable-gaze-eyes")),
        ("eyes-empty", lambda c: c.__setitem__("eyes", []), ("eyes", "two eye calibrations", "0 item")),
        ("one-eye", lambda c: c["eyes"].pop(), ("eyes", "1 item")),
        ("eyes-not-list", lambda c: c.__setitem__("eyes", {"left": 1}), ("eyes", "two eye calibrations")),
        ("eye-name", eye0(lambda x: x.__setitem__("eye", "middle")), ("eyes[0].eye", "left")),
        ("eyes-swapped", lambda c: c["eyes"].reverse(), ("left then the right",)),
        ("centre-strings", eye0(lambda x: x.__setitem__("centre_mm", ["a", 0, 0])), ("centre_mm[0]", "number")),
        ("centre-huge", eye0(lambda x: x.__setitem__("centre_mm", [1e200, 0, 0])), ("centre_mm[0]", "<=")),
        ("plane-negative", eye0(lambda x: x.__setitem__("plane_mm", -1)), ("plane_mm", "> 0")),
        ("no-raw-map", eye0(lambda x: x.pop("raw_map")), ("raw_map", "missing")),
        ("coef-ragged", eye0(lambda x: x["raw_map"]["coef"].__setitem__(2, [1.0])), ("coef[2]", "pair")),
        ("coef-rows", eye0(lambda x: x["raw_map"]["coef"].pop()), ("coef", "5 item")),
        ("cubic-6-rows", eye0(lambda x: x["raw_map"].__setitem__("model", "cubic")), ("coef", "cubic model has 10")),
        ("model-unknown", eye0(lambda x: x["raw_map"].__setitem__("model", "linear")), ("raw_map.model", "quadratic")),
        ("scale-zero", eye0(lambda x: x["raw_map"].__setitem__("scale", 0)), ("scale", "> 0")),
    ]


EYES_SLOTS = [("viewlines-eyes", "viewlines", lambda e, d, p: argv_viewlines(e, d, eyes=p)),
              ("live-eyes", "live", lambda e, d, p: argv_live(e, d, eyes=p))]
_json_matrix(EYES_SLOTS, [(vid, edit, None, words) for vid, edit, words in _eyes_edits()], "eyes",
             ("eyes-empty", "coef-ragged", "format-wrong"))


def _map_edits():
    def m0(fn):
        return lambda c: fn(c["markers"][0])
    return [
        ("list-top", None, ("top level", "object")),                 # the file holds [1, 2]
        ("markers-strings", lambda c: c.__setitem__("markers", ["a", "b"]), ("markers[", "object")),
        ("markers-empty", lambda c: c.__setitem__("markers", []), ("markers", "non-empty")),
        ("T-ragged", m0(lambda x: x["T_world_from_marker"].__setitem__(1, [0, 1, 0])), ("T_world_from_marker[1]", "4")),
        ("T-strings", m0(lambda x: x["T_world_from_marker"][0].__setitem__(0, "one")), ("T_world_from_marker[0][0]",)),
        ("T-huge", m0(lambda x: x["T_world_from_marker"][0].__setitem__(3, 1e308)),
         ("T_world_from_marker[0][3]", "<=")),
        ("T-not-rigid", m0(lambda x: x["T_world_from_marker"][0].__setitem__(0, 3.0)), ("rigid",)),
        ("no-pose", m0(lambda x: x.pop("T_world_from_marker")), ("markers[0]", "T_world_from_marker")),
        ("corners-ragged", m0(lambda x: (x.pop("T_world_from_marker"), x.__setitem__("corners_mm", [[0, 0, 0]] * 3))),
         ("corners_mm", "3 item")),
        ("id-negative", m0(lambda x: x.__setitem__("id", -1)), ("markers[0].id", ">= 0")),
        ("id-string", m0(lambda x: x.__setitem__("id", "7")), ("markers[0].id", "whole number")),
        ("id-duplicate", lambda c: c["markers"].append(dict(c["markers"][0])), ("twice",)),
        ("id-beyond-dictionary", m0(lambda x: x.__setitem__("id", 4000)), ("not in",)),
        ("dictionary-unknown", lambda c: c.__setitem__("dictionary", "DICT_NOPE"), ("dictionary", "unknown")),
        ("dictionary-not-dict", lambda c: c.__setitem__("dictionary", 5), ("dictionary", "dictionary name")),
        ("size-string", lambda c: c.__setitem__("marker_size_mm", "200"), ("marker_size_mm", "millimetres")),
        ("size-metres", lambda c: c.__setitem__("marker_size_mm", 0.2), ("millimetres",)),
        ("format-wrong", lambda c: c.__setitem__("format", "x"), ("format",)),
    ]


MAP_SLOTS = [("track-markers", "track", lambda e, d, p: argv_track(e, d, markers=p)),
             ("live-markers", "live", lambda e, d, p: argv_live(e, d, markers=p))]
_json_matrix(MAP_SLOTS, [(vid, edit, "[1, 2]" if vid == "list-top" else None, words)
                         for vid, edit, words in _map_edits()], "markers",
             ("markers-strings", "T-ragged", "dictionary-unknown"))


# 4. sessions: the manifest and the files it names (process, emulate, calibrate-eyes) ----------

def copy_session(e, d) -> Path:
    s = d / "sess"
    shutil.copytree(e.session, s, ignore=shutil.ignore_patterns("truth", "calibration"))
    return s


def session_with(manifest_edit=None, raw=None, setup=None):
    def make(e, d):
        s = copy_session(e, d)
        if raw is not None:
            (s / "session.json").write_bytes(raw if isinstance(raw, bytes) else raw.encode())
        elif manifest_edit is not None:
            m = json.loads((s / "session.json").read_text())
            for k in [k for k in m["files"] if k.startswith("truth") or k in ("eye_calibration", "camera_views")]:
                del m["files"][k]
            manifest_edit(m)
            (s / "session.json").write_text(json.dumps(m))
        if setup is not None:
            setup(s)
        return str(s)
    return make


def _files(key, value):
    return lambda m: m["files"].__setitem__(key, value)


SESSION_VARIANTS = [
    ("manifest-list", session_with(raw="[1, 2]"), ("top level", "object")),
    ("manifest-missing", session_with(setup=lambda s: (s / "session.json").unlink()), ("session.json", "no such")),
    ("manifest-broken", session_with(raw='{"format": '), ("not valid json",)),
    ("manifest-utf16", session_with(raw=utf16('{"format": "wearable-gaze-session"}')), ("utf-16",)),
    ("manifest-nan", session_with(raw='{"format": "wearable-gaze-session", "version": 1, "fps": NaN, "files": {}}'),
     ("nan",)),
    ("format-wrong", session_with(lambda m: m.__setitem__("format", "other")), ("format", "wearable-gaze-session")),
    ("version-2", session_with(lambda m: m.__setitem__("version", 2)), ("version", "1")),
    ("files-missing", session_with(lambda m: m.pop("files")), ("files", "missing")),
    ("files-list", session_with(lambda m: m.__setitem__("files", ["eye.csv"])), ("files", "object")),
    ("scene-video-number", session_with(_files("scene_video", 5)), ("files.scene_video", "relative")),
    ("eye-samples-etc-passwd", session_with(_files("eye_samples", "/etc/passwd")), ("files.eye_samples", "inside")),
    ("camera-views-root", session_with(_files("camera_views", "/")), ("files.camera_views", "inside")),
    ("eye-samples-dotdot", session_with(_files("eye_samples", "../../eye.csv")), ("files.eye_samples", "..")),
    ("marker-map-dotdot-middle", session_with(_files("marker_map", "a/../../markers.json")), ("files.marker_map",)),
    ("scene-video-empty", session_with(_files("scene_video", "")), ("files.scene_video",)),
    ("eye-samples-not-listed", session_with(lambda m: m["files"].pop("eye_samples")), ("eye_samples", "missing")),
    ("listed-file-missing", session_with(lambda m: None, setup=lambda s: (s / "eye.csv").unlink()),
     ("eye.csv", "missing")),
    ("image-size-strings", session_with(lambda m: m.__setitem__("image_size", ["a", "b"])), ("image_size[",)),
    ("has-recording-string", session_with(lambda m: m.__setitem__("has_recording", "yes")), ("has_recording",)),
    ("symlink-out", session_with(lambda m: None,
                                 setup=lambda s: (s / "eye.csv").unlink() or os.symlink("/etc/passwd", s / "eye.csv")),
     ("files.eye_samples", "inside")),
]
for vid, make, words in SESSION_VARIANTS:
    add(f"process-session-{vid}", "process", lambda e, d, make=make: argv_process(e, d, make(e, d)), words)
    if vid in ("manifest-list", "scene-video-number", "eye-samples-etc-passwd", "eye-samples-dotdot",
               "format-wrong", "files-list", "manifest-utf16"):
        add(f"emulate-session-{vid}", "emulate",
            lambda e, d, make=make: ["emulate", make(e, d), "--listen", "127.0.0.1:0", "--duration", "0.2"], words)
add("process-session-missing", "process", lambda e, d: argv_process(e, d, str(d / "nope")), "no such session")
add("process-session-is-file", "process", lambda e, d: argv_process(e, d, e["eye"]), "no such session")
add("emulate-session-missing", "emulate", lambda e, d: ["emulate", str(d / "nope")], "no such session")
add("emulate-no-serial-bytes", "emulate",
    lambda e, d: ["emulate", session_with(setup=lambda s: None, manifest_edit=lambda m: m["files"].pop("eye_serial"))(
        e, d)], "eye_serial")


# process: a bad calibration recording gives one line per problem and exit 2 (no target)
def _process_with(setup):
    def b(e, d):
        s = d / "sess"
        shutil.copytree(e.session, s)
        setup(s)
        return argv_process(e, d, str(s))
    return b


def _board(content):
    return lambda s: (s / "calibration" / "camera" / "board.json").write_text(
        content if isinstance(content, str) else json.dumps(content))


for vid, content, words in [
        ("board-list", [1, 2], ("board.json", "object")),
        ("board-cols-string", {"version": 1, "board": {"type": "chessboard", "cols": "a", "rows": 6,
                                                        "square_mm": 30}}, ("board.cols", "whole number")),
        ("board-type-unknown", {"version": 1, "board": {"type": "circles", "cols": 9, "rows": 6, "square_mm": 30}},
         ("board.type", "chessboard")),
        ("board-charuco-no-dictionary", {"version": 1, "board": {"type": "charuco", "cols": 9, "rows": 6,
                                                                  "square_mm": 30, "marker_mm": 20}},
         ("board", "dictionary")),
        ("board-missing-key", {"version": 1}, ("board", "missing")),
        ("board-broken", "{", ("board.json", "not valid json"))]:
    add(f"process-{vid}", "process", _process_with(_board(content)), words, many=True)


def _walls_edit(fn):
    def setup(s):
        p = s / "calibration" / "eye" / "walls.json"
        w = json.loads(p.read_text())
        fn(w)
        p.write_text(json.dumps(w))
    return setup


WALLS_VARIANTS = [
    ("recordings-missing", lambda w: w.pop("recordings"), ("recordings", "missing")),
    ("recordings-empty", lambda w: w.__setitem__("recordings", []), ("recordings", "non-empty")),
    ("recordings-string", lambda w: w.__setitem__("recordings", "all"), ("recordings", "list")),
    ("image-absolute", lambda w: w["recordings"][0].__setitem__("image", "/etc/passwd"), ("recordings[0].image",
                                                                                          "inside")),
    ("image-dotdot", lambda w: w["recordings"][0].__setitem__("image", "../../../wall.png"), ("recordings[0].image",)),
    ("image-number", lambda w: w["recordings"][0].__setitem__("image", 3), ("recordings[0].image",)),
    ("dictionary-unknown", lambda w: w["recordings"][1].__setitem__("dictionary", "DICT_X"),
     ("recordings[1].dictionary", "unknown")),
    ("markers-ragged", lambda w: w["recordings"][0]["markers_wall_mm"].__setitem__("46", [1.0]),
     ("markers_wall_mm.46", "[x, y]")),
    ("markers-bad-id", lambda w: w["recordings"][0]["markers_wall_mm"].__setitem__("forty", [1.0, 2.0]),
     ("markers_wall_mm", "forty")),
    ("targets-strings", lambda w: w["recordings"][0].__setitem__("targets_wall_mm", [["a", "b"]]),
     ("targets_wall_mm[0][", "number")),
    ("size-missing", lambda w: w["recordings"][0].pop("marker_size_mm"), ("marker_size_mm", "missing")),
    ("size-huge", lambda w: w["recordings"][0].__setitem__("marker_size_mm", 1e300), ("marker_size_mm", "<=")),
    ("recording-negative", lambda w: w["recordings"][0].__setitem__("recording", -1), ("recording", ">= 0")),
]
for vid, fn, words in WALLS_VARIANTS:
    def b(e, d, fn=fn):
        s = d / "sess"
        shutil.copytree(e.session / "calibration", s / "calibration")
        _walls_edit(fn)(s)
        return argv_calibrate_eyes(e, d, source=str(s))
    add(f"calibrate-eyes-walls-{vid}", "calibrate-eyes", b, words)
add("process-walls-image-absolute", "process",
    _process_with(_walls_edit(lambda w: w["recordings"][0].__setitem__("image", "/etc/passwd"))),
    ("recordings[0].image", "inside"), many=True)


def _eyecal_csv(edit_text):
    def b(e, d):
        s = d / "sess"
        shutil.copytree(e.session / "calibration" / "eye", s / "calibration" / "eye")
        p = s / "calibration" / "eye" / "eye_calibration.csv"
        p.write_bytes(edit_text(p.read_text()))
        return argv_calibrate_eyes(e, d, source=str(s))
    return b


for vid, fn, words in [
        ("no-target-column", lambda t: t.replace(",target", ",tgt").encode(), ("missing column", "target")),
        ("utf16", lambda t: utf16(t), "utf-16"),
        ("readings-1e308", lambda t: t.replace("\n0.016667,1,", "\n0.016667,1,1e308,").replace(
            "\n0.016667,1,1e308,", "\n0.016667,1,1e308,", 1).encode(), ("plausible",)),
        ("duplicated-target", lambda t: t.replace(",recording,target", ",recording,recording").encode(),
         ("more than once", "recording")),
        ("target-beyond-walls", lambda t: "\n".join(ln if i == 0 else ln.rsplit(",", 1)[0] + ",99"
                                                    for i, ln in enumerate(t.splitlines())).encode(), ("target 99",)),
        ("target-negative", lambda t: "\n".join(ln if i != 5 else ln.rsplit(",", 1)[0] + ",-3"
                                                for i, ln in enumerate(t.splitlines())).encode(), ("target -3",))]:
    add(f"calibrate-eyes-csv-{vid}", "calibrate-eyes", _eyecal_csv(fn), words)
add("calibrate-eyes-source-missing", "calibrate-eyes", lambda e, d: argv_calibrate_eyes(e, d, source=str(d / "x")),
    "no eye_calibration.csv")
add("calibrate-eyes-wall-image-missing", "calibrate-eyes",
    lambda e, d: argv_calibrate_eyes(e, d, source=_copy_eyecal(e, d, lambda s: (s / "wall_1.png").unlink())),
    ("wall_1.png", "unreadable"))
add("calibrate-eyes-wall-image-garbage", "calibrate-eyes",
    lambda e, d: argv_calibrate_eyes(e, d, source=_copy_eyecal(e, d, lambda s: (s / "wall_0.png").write_bytes(
        b"\x89PNG\r\n\x1a\n garbage"))), ("wall_0.png", "unreadable"))
add("calibrate-eyes-model-unknown", "calibrate-eyes", lambda e, d: argv_calibrate_eyes(e, d, extra=["--model", "x"]),
    ("--model", "invalid choice"))


def _copy_eyecal(e, d, fn):
    s = d / "eyecal"
    shutil.copytree(e.eye_cal, s)
    fn(s)
    return str(s)


# 5. scenarios -----------------------------------------------------------------------------------

SCENARIO_VARIANTS = [
    ("fixation-zero", {"eyes": {"fixation_s": [0, 0]}}, ("eyes.fixation_s", "0.05")),
    ("fixation-reversed", {"eyes": {"fixation_s": [3, 1]}}, ("eyes.fixation_s", "shortest <= longest")),
    ("base-list", {"base": ["lab-walkabout"]}, ("base", "one of")),
    ("base-unknown", {"base": "office"}, ("base", "one of")),
    ("dictionary-unknown", {"room": {"dictionary": "DICT_9X9_1"}}, ("room.dictionary", "unknown")),
    ("board-cols-string", {"calibration": {"camera_board": {"type": "chessboard", "cols": "a", "rows": 6,
                                                            "square_mm": 30}}}, ("camera_board.cols", "whole")),
    ("board-charuco-incomplete", {"calibration": {"camera_board": {"type": "charuco", "cols": 5, "rows": 7,
                                                                   "square_mm": 30}}}, ("camera_board", "marker_mm")),
    ("board-charuco-marker-big", {"calibration": {"camera_board": {"type": "charuco", "cols": 5, "rows": 7,
                                                                   "square_mm": 30, "marker_mm": 40,
                                                                   "dictionary": "DICT_4X4_50"}}}, ("smaller",)),
    ("top-list", [1, 2], ("top level", "object")),
    ("unknown-top-field", {"durration_s": 3}, ("durration_s", "unknown field")),
    ("camera-not-object", {"camera": 5}, ("camera", "object")),
    ("resolution-huge", {"camera": {"resolution": [100000, 100000]}}, ("camera.resolution", "8192")),
    ("resolution-one", {"camera": {"resolution": [640]}}, ("camera.resolution",)),
    ("duration-huge", {"duration_s": 1e300}, ("duration_s", "<=")),
    ("duration-zero", {"duration_s": 0}, ("duration_s", "> 0")),
    ("duration-bool", {"duration_s": True}, ("duration_s", "seconds", "got true")),
    ("fps-zero", {"camera": {"fps": 0}}, ("camera.fps",)),
    ("rate-negative", {"eyes": {"rate_hz": -60}}, ("eyes.rate_hz",)),
    ("codec-unknown", {"camera": {"codec": "H265"}}, ("camera.codec", "mp4v")),
    ("dist-coeffs-3", {"camera": {"dist_coeffs": [0, 0, 0]}}, ("camera.dist_coeffs",)),
    ("bias-ragged", {"eyes": {"bias_deg": [[0, 0], [0]]}}, ("eyes.bias_deg[1]",)),
    ("points-ragged", {"targets": {"points_mm": [[0, 0]]}}, ("targets.points_mm[0]",)),
    ("points-huge", {"targets": {"points_mm": [[0, 0, 1e200]]}}, ("targets.points_mm[0][2]", "<=")),
    ("moving-missing-target", {"targets": {"moving": [9]}}, ("targets.moving", "does not exist")),
    ("no-targets", {"targets": {"random_count": 0, "points_mm": []}}, ("targets", "at least one target")),
    ("depth-reversed", {"targets": {"random_depth_mm": [4000, 500]}}, ("random_depth_mm", "near <= far")),
    ("walls-empty", {"calibration": {"walls": []}}, ("calibration.walls", "non-empty")),
    ("wall-grid-big", {"calibration": {"walls": [{"distance_mm": 1000, "grid": [20, 3], "tilt_deg": 0}]}},
     ("walls[0].grid[0]", "<= 9")),
    ("wall-extra-key", {"calibration": {"walls": [{"distance_mm": 1000, "grid": [3, 3], "tilt_deg": 0, "x": 1}]}},
     ("walls[0].x", "unknown")),
    ("markers-per-wall-12", {"room": {"markers_per_wall": 12}}, ("room.markers_per_wall", "<= 11")),
    ("motion-unknown", {"head": {"motion": "run"}}, ("head.motion", "fixed")),
    ("forward-zero", {"head": {"forward": [0, 0, 0]}}, ("head.forward", "non-zero")),
    ("follow-zero", {"head": {"follow": 0}}, ("head.follow",)),
    ("version-2", {"version": 2}, ("version", "1")),
    ("nan-value", '{"duration_s": NaN}', ("nan",)),
    ("overflow-value", '{"duration_s": 1e999}', ("duration_s", "finite")),
]
for vid, content, words in SCENARIO_VARIANTS:
    add(f"simulate-scenario-{vid}", "simulate",
        lambda e, d, content=content: ["simulate", "--scenario", write(d, "scn.json", content), "-o", str(d / "s")],
        words)


# 6. options -------------------------------------------------------------------------------------

def opt_cases(command, build, option, values, words=()):
    for v in values:
        vid = {"-1": "negative", "0": "zero", "nan": "nan", "inf": "inf", "abc": "text", "": "empty",
               "1e300": "huge"}.get(v, v.replace(":", "_").replace("/", "_").replace(".", "_"))
        add(f"{command}-{option.lstrip('-')}-{vid}", command, lambda e, d, v=v: build(e, d, [option, v]),
            (option, *words) if isinstance(words, tuple) else (option, words))


opt_cases("estimate", lambda e, d, x: argv_estimate(e, e["viewlines"], x), "--sigma-deg", ["0", "-1", "nan", "inf",
                                                                                          "abc", "1e300"])
opt_cases("estimate", lambda e, d, x: argv_estimate(e, e["viewlines"], x), "--method", ["magic"])
add("estimate-export-density-not-ply", "estimate",
    lambda e, d: argv_estimate(e, e["viewlines"], ["--export-density", str(d / "d.txt")]), ".ply")
add("estimate-export-density-with-lse", "estimate",
    lambda e, d: argv_estimate(e, e["viewlines"], ["--method", "lse", "--export-density", str(d / "d.ply")]),
    ("--export-density", "voxel"))
add("estimate-direction-1e200", "estimate",
    lambda e, d: argv_estimate(e, write(d, "vl.csv", _vl_with(e, "left_dx", "1e200"))), ("left_dx", "plausible"))
add("estimate-direction-zero", "estimate",
    lambda e, d: argv_estimate(e, write(d, "vl.csv", _vl_zero_direction(e))), ("direction is zero",))
add("estimate-partly-empty-eye", "estimate",
    lambda e, d: argv_estimate(e, write(d, "vl.csv", _vl_with(e, "left_oy", ""))), ("left_oy", "empty"))


for opt, values in (("--window", ["0", "-1", "abc"]), ("--jump-deg", ["0", "nan"]), ("--eye-rate-hz", ["0", "inf"]),
                    ("--min-fixation-s", ["-1"]), ("--max-gap-s", ["abc"])):
    opt_cases("fixations", lambda e, d, x: argv_fixations(e, d, extra=x), opt, values)


def _vl_unsegmented(e, d) -> str:
    """View lines of two 1 s fixations 20 deg apart at 60 Hz, without a segment column."""
    import numpy as np

    from estimator import BinocularSamples
    from wearable_gaze.formats.viewlines import write_viewlines_csv
    from wearable_gaze.sim.protocol import simulate_lines

    rng = np.random.default_rng(3)
    parts = [simulate_lines(p, rng).select(slice(0, 60)) for p in ([0, 0, 1500.0], [600.0, 0, 1500.0])]
    both = BinocularSamples.concatenate(parts)
    s = BinocularSamples(np.arange(120) / 60.0, both.left_origin_mm, both.left_direction, both.right_origin_mm,
                         both.right_direction, both.left_valid, both.right_valid)
    write_viewlines_csv(d / "unsegmented.csv", s)
    return str(d / "unsegmented.csv")


def _vl_segment(e, d, value) -> str:
    """The session's view lines with every segment cell replaced by ``value``."""
    lines = Path(e["viewlines"]).read_text().splitlines()
    j = lines[0].split(",").index("segment")
    rows = [ln.split(",") for ln in lines[1:]]
    for r in rows:
        r[j] = value
    return write(d, "vl.csv", "\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")


add("estimate-unsegmented-several-fixations", "estimate", lambda e, d: argv_estimate(e, _vl_unsegmented(e, d)),
    ("no segment column", "fixations", "--one-point"))
add("estimate-targets-unsegmented", "estimate",
    lambda e, d: argv_estimate(e, _vl_unsegmented(e, d), ["--targets"]), ("--targets", "no segment column"))
add("estimate-targets-text-segment", "estimate",
    lambda e, d: argv_estimate(e, _vl_segment(e, d, "near"), ["--targets"]), ("segment 'near'", "fixations"))
add("estimate-one-point-segmented", "estimate", lambda e, d: argv_estimate(e, e["viewlines"], ["--one-point"]),
    ("--one-point", "has a segment column"))
add("estimate-one-point-and-targets", "estimate",
    lambda e, d: argv_estimate(e, e["viewlines"], ["--one-point", "--targets"]), ("--targets", "not allowed"))
add("estimate-targets-export-density", "estimate",
    lambda e, d: argv_estimate(e, e["viewlines"], ["--targets", "--export-density", str(d / "d.ply")]),
    ("--export-density", "per target"))


def _vl_with(e, col, value):
    lines = Path(e["viewlines"]).read_text().splitlines()
    j = lines[0].split(",").index(col)
    cells = lines[1].split(",")
    cells[j] = value
    return "\n".join([lines[0], ",".join(cells), *lines[2:10]]) + "\n"


def _vl_zero_direction(e):
    lines = Path(e["viewlines"]).read_text().splitlines()
    cols = lines[0].split(",")
    cells = lines[1].split(",")
    for c in ("left_dx", "left_dy", "left_dz"):
        cells[cols.index(c)] = "0"
    return "\n".join([lines[0], ",".join(cells), *lines[2:10]]) + "\n"


opt_cases("reproduce", lambda e, d, x: ["reproduce", "table1", "--out", str(d / "r"), *x], "--trials",
          ["0", "-1", "abc"])
opt_cases("reproduce", lambda e, d, x: ["reproduce", "figure5", "--out", str(d / "r"), *x], "--seed",
          ["-1", "abc", "1e300"])
add("reproduce-what-unknown", "reproduce", lambda e, d: ["reproduce", "table2"], "invalid choice")
opt_cases("calibrate-camera", lambda e, d, x: argv_calibrate_camera(e, d, extra=x), "--max-views", ["0", "-1", "abc"])
opt_cases("calibrate-camera", lambda e, d, x: argv_calibrate_camera(e, d, extra=x), "--model", ["spherical"])
for vid, board, words in [("text", "chess", "--board"), ("zero-square", "chessboard:9x6:0", "square"),
                          ("one-col", "chessboard:1x6:30", "2x2"),
                          ("charuco-dict", "charuco:5x7:30:20:DICT_NOPE", "dictionary"),
                          ("charuco-marker-big", "charuco:5x7:30:40:DICT_4X4_50", "smaller")]:
    add(f"calibrate-camera-board-{vid}", "calibrate-camera", lambda e, d, board=board: argv_calibrate_camera(
        e, d, board=board), words)
add("calibrate-camera-board-wrong-size", "calibrate-camera",
    lambda e, d: argv_calibrate_camera(e, d, board="chessboard:4x3:30"), ("usable board views", "calibration"))
add("calibrate-camera-input-missing", "calibrate-camera",
    lambda e, d: argv_calibrate_camera(e, d, inputs=[str(d / "nope.png")]), "no such file")
add("calibrate-camera-empty-folder", "calibrate-camera",
    lambda e, d: argv_calibrate_camera(e, d, inputs=[str(d / "empty")]) if (d / "empty").mkdir() is None else None,
    "no images")
add("calibrate-camera-garbage-image", "calibrate-camera",
    lambda e, d: argv_calibrate_camera(e, d, inputs=[write(d, "x.png", b"\x89PNG garbage")]), "not a readable image")
add("calibrate-camera-text-as-video", "calibrate-camera",
    lambda e, d: argv_calibrate_camera(e, d, inputs=[write(d, "x.mp4", b"not a video")]), "video")
add("calibrate-camera-mixed-sizes", "calibrate-camera",
    lambda e, d: argv_calibrate_camera(e, d, inputs=[str(e.views / "view_000.png"), e["session"] + "/calibration/eye/"
                                                     "wall_0.png", _small_png(d)]), "resolution")


def _small_png(d):
    import cv2
    import numpy as np
    p = d / "small.png"
    cv2.imwrite(str(p), np.zeros((100, 100), np.uint8))
    return str(p)


opt_cases("viewlines", lambda e, d, x: argv_viewlines(e, d) + x, "--max-gap", ["0", "-1", "nan", "abc"])
add("viewlines-clocks-apart", "viewlines",
    lambda e, d: argv_viewlines(e, d, poses=write(d, "p.csv", _shift_poses(e, 1000.0))), ("no head pose", "clock"))


def _shift_poses(e, dt):
    lines = Path(e["poses"]).read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        c = ln.split(",")
        c[0] = f"{float(c[0]) + dt:.6f}"
        out.append(",".join(c))
    return "\n".join(out) + "\n"


opt_cases("track", lambda e, d, x: argv_track(e, d, extra=x), "--smooth", ["-1", "nan", "inf", "abc"])
add("track-video-garbage", "track", lambda e, d: argv_track(e, d, video=write(d, "v.mp4", b"\x00garbage" * 100)),
    ("video",))
add("track-reference-missing-in-folder", "track",
    lambda e, d: ["track", e["video"], "--camera", e["camera"], "--reference", str(d / "ref.png"),
                  "--reference-size-mm", "300", "200", "-o", str(d / "p.csv")], ("ref.png", "no such file"))
add("track-reference-size-negative", "track",
    lambda e, d: ["track", e["video"], "--camera", e["camera"], "--reference", str(e.views / "view_000.png"),
                  "--reference-size-mm", "-3", "200", "-o", str(d / "p.csv")], ("--reference-size-mm", "positive"))
add("track-no-source", "track", lambda e, d: ["track", e["video"], "--camera", e["camera"], "-o", str(d / "p.csv")],
    ("--markers", "required"))
add("track-camera-other-resolution", "track",
    lambda e, d: argv_track(e, d, camera=write(d, "c.json", edited_json(e.camera, lambda c: c.__setitem__(
        "image_size", [640, 360])))), ("320x180", "calibrate"))

add("markers-ids-reversed", "markers", lambda e, d: ["markers", "--ids", "5-3", "--size-mm", "50", "-o",
                                                     str(d / "m.pdf")], ("5-3", "backwards"))
for vid, ids, words in [("text", "a-b", "give ids"), ("negative", "-3", "negative"), ("empty", "", "ids"),
                        ("comma-only", ",", "give ids"), ("beyond-dictionary", "0-60", "not in"),
                        ("too-many", "0-99999999", "more than"), ("triple-range", "1-2-3", "give ids"),
                        ("escape", "\x1b[31m", "\\x1b")]:
    add(f"markers-ids-{vid}", "markers", lambda e, d, ids=ids: ["markers", "--ids", ids, "--size-mm", "50", "-o",
                                                                str(d / "m.pdf")], words)
for vid, args, words in [("dpi-70000", ["--dpi", "70000"], ("--dpi", "1200")), ("dpi-zero", ["--dpi", "0"], "--dpi"),
                         ("dpi-text", ["--dpi", "x"], "--dpi"), ("size-zero", ["--size-mm", "0"], "--size-mm"),
                         ("size-huge", ["--size-mm", "5000"], "--size-mm"), ("size-nan", ["--size-mm", "nan"],
                                                                               "--size-mm"),
                         ("dict-unknown", ["--dict", "DICT_NOPE"], "dictionary"),
                         ("page-unknown", ["--page", "a0"], "--page"),
                         ("suffix", ["-o", "sheet.svg"], ".pdf or .png"),
                         ("too-big-for-page", ["--size-mm", "300"], "does not fit")]:
    def b(e, d, args=args):
        base = {"--ids": "0-3", "--size-mm": "50", "-o": str(d / "m.pdf")}
        extra = []
        for k in range(0, len(args), 2):
            if args[k] in base:
                base[args[k]] = args[k + 1] if args[k] != "-o" else str(d / args[k + 1])
            else:
                extra += args[k:k + 2]
        return ["markers", *[x for kv in base.items() for x in kv], *extra]
    add(f"markers-{vid}", "markers", b, words)

opt_cases("simulate", lambda e, d, x: ["simulate", "-o", str(d / "s"), *x], "--seed", ["-1", "abc", "1e300"])
opt_cases("simulate", lambda e, d, x: ["simulate", "-o", str(d / "s"), *x], "--duration", ["0", "-1", "nan", "inf"])
add("simulate-duration-0_01", "simulate", lambda e, d: ["simulate", "-o", str(d / "s"), "--duration", "0.01",
                                                        "--resolution", "320x180"], ("duration_s", "too short"))
add("simulate-duration-huge", "simulate", lambda e, d: ["simulate", "-o", str(d / "s"), "--duration", "1e8"],
    ("duration_s", "<="))
for v in ("big", "10x10", "100000x100", "0x0", "axb"):
    add(f"simulate-resolution-{v}", "simulate", lambda e, d, v=v: ["simulate", "-o", str(d / "s"), "--resolution", v],
        "--resolution")
add("simulate-scenario-unknown-name", "simulate", lambda e, d: ["simulate", "--scenario", "office", "-o",
                                                                str(d / "s")], "unknown scenario")
add("simulate-out-not-empty", "simulate", lambda e, d: ["simulate", "-o", str(d)] if write(d, "keep.txt", "x") else 0,
    "not empty")

opt_cases("process", lambda e, d, x: argv_process(e, d, e["session"], x), "--track-every", ["0", "-1", "abc"])
opt_cases("process", lambda e, d, x: argv_process(e, d, e["session"], x), "--method", ["magic"])
add("process-camera-missing", "process", lambda e, d: argv_process(e, d, _session_copy_full(e, d),
                                                                   ["--camera", str(d / "nope.json")]),
    ("camera", "no such"), many=True)
add("process-camera-bad-json", "process", lambda e, d: argv_process(
    e, d, _session_copy_full(e, d), ["--camera", write(d, "c.json", {"camera_matrix": "x"})]),
    ("camera calibration", "missing key"), many=True)
add("process-eyes-bad-json", "process", lambda e, d: argv_process(
    e, d, _session_copy_full(e, d), ["--camera", e["camera"], "--eyes", write(d, "e.json", {"eyes": []})]),
    ("eyes",), many=True)



# --- learn-bias, and --person of process and viewlines (issue 15) --------------------------------

def argv_learn_bias(e, d, validation=None, processed=None, out=None):
    """learn-bias on the fixture session; its 'processed' folder is the base (poses.csv, eyes.json)."""
    return ["learn-bias", e["session"], "--validation", validation or str(e.session / "truth" / "targets.json"),
            "--processed", processed or str(e.base), "-o", out or str(d / "person.json")]


def _validation(e, edit=None) -> dict:
    truth = json.loads((e.session / "truth" / "targets.json").read_text())["targets"]
    d = {"format": "wearable-gaze-validation", "version": 1,
         "targets": [{"position_mm": t["position_mm"], "fixations_s": t["fixations_s"]}
                     for t in truth if not t["moving"] and t["fixations_s"]]}
    if edit:
        edit(d)
    return d


def _bad_validation(edit):
    return lambda e, d: argv_learn_bias(e, d, write(d, "v.json", _validation(e, edit)))


def _person(edit=None) -> dict:
    d = {"format": "wearable-gaze-person", "version": 1,
         "eyes": [{"eye": "left", "correction_deg": [1.0, 0.5]}, {"eye": "right", "correction_deg": [1.0, 0.5]}]}
    if edit:
        edit(d)
    return d


add("learn-bias-validation-missing", "learn-bias", lambda e, d: argv_learn_bias(e, d, str(d / "nope.json")),
    "no such file")
add("learn-bias-validation-not-json", "learn-bias",
    lambda e, d: argv_learn_bias(e, d, write(d, "v.json", "{targets: [}")), "not valid json")
add("learn-bias-validation-no-targets", "learn-bias", _bad_validation(lambda v: v.update(targets=[])),
    ("validation", "targets"))
add("learn-bias-validation-interval-reversed", "learn-bias",
    _bad_validation(lambda v: v["targets"][0].update(fixations_s=[[1.5, 0.5]])), ("fixations_s[0]", "start < end"))
add("learn-bias-validation-position-2d", "learn-bias",
    _bad_validation(lambda v: v["targets"][0].update(position_mm=[0.0, 0.0])), "position_mm")
add("learn-bias-validation-other-clock", "learn-bias", _bad_validation(
    lambda v: [t.update(fixations_s=[[a + 1000, b + 1000] for a, b in t["fixations_s"]]) for t in v["targets"]]),
    ("too few eye samples", "clock"))
add("learn-bias-not-processed", "learn-bias", lambda e, d: argv_learn_bias(e, d, processed=str(d)),
    ("no head poses", "process"))
add("learn-bias-out-is-validation", "learn-bias", lambda e, d: argv_learn_bias(
    e, d, out=_cp(e.session / "truth" / "targets.json", d, "t.json"),
    validation=str(d / "t.json")), "-o")
add("process-person-missing", "process", lambda e, d: argv_process(e, d, e["session"],
                                                                   ["--person", str(d / "nope.json")]),
    ("no such file", "per-person bias"))
add("process-person-correction-huge", "process", lambda e, d: argv_process(e, d, e["session"], [
    "--person", write(d, "p.json", _person(lambda p: p["eyes"][0].update(correction_deg=[90.0, 0.0])))]),
    ("correction_deg", "per-person bias"))
add("viewlines-person-eyes-swapped", "viewlines", lambda e, d: argv_viewlines(e, d) + [
    "--person", write(d, "p.json", _person(lambda p: p["eyes"].reverse()))], ("left then the right",))

def _session_copy_full(e, d):
    s = d / "sess"
    if not s.exists():
        shutil.copytree(e.session, s)
    return str(s)


LIVE_OPTS = [("--publish", ["udp://127.0.0.1:99999", "udp://127.0.0.1:abc", "http://127.0.0.1:80",
                            "udp://:5555", "udp://127.0.0.1", "tcp://127.0.0.1:-1", "udp://127.0.0.1:0"]),
             ("--baud", ["0", "-9600", "abc"]), ("--duration", ["0", "-1", "nan", "inf"])]
for opt, values in LIVE_OPTS:
    opt_cases("live", lambda e, d, x: argv_live(e, d, extra=x), opt, values)
add("live-camera-calib-yaml-garbage", "live",
    lambda e, d: argv_live(e, d, camera_calib=write(d, "c.yml", "%YAML:1.0\n---\n: : [ {{{\n")), ("opencv",))
add("live-record-is-file", "live", lambda e, d: argv_live(e, d, extra=["--record", write(d, "rec", "x")]),
    ("--record", "is a file"))
add("live-record-parent-file", "live",
    lambda e, d: argv_live(e, d, extra=["--record", write(d, "f", "x") + "/rec"]), ("--record", "not a folder"))

opt_cases("emulate", lambda e, d, x: ["emulate", e["session"], *x], "--listen", ["127.0.0.1:99999", "localhost",
                                                                                 "127.0.0.1:abc", ":80"])
opt_cases("emulate", lambda e, d, x: ["emulate", e["session"], *x], "--duration", ["0", "-1", "nan"])

opt_cases("demo", lambda e, d, x: ["demo", "--out", str(d / "demo"), *x], "--seed", ["-1", "abc"])
opt_cases("demo", lambda e, d, x: ["demo", "--out", str(d / "demo"), *x], "--duration", ["0", "-5", "nan", "inf"])
add("demo-duration-0_01", "demo", lambda e, d: ["demo", "--out", str(d / "demo"), "--duration", "0.01"],
    ("duration_s", "too short"))

add("no-command-option", "estimate", lambda e, d: ["estimate", e["viewlines"], "--bogus"], "unrecognized")
add("unknown-option-with-escape", "estimate", lambda e, d: ["estimate", e["viewlines"], "--bogus\x1b[2J"],
    ("unrecognized", "\\x1b"))
add("estimate-path-with-escape", "estimate", lambda e, d: ["estimate", str(d / "lines\x1b[2J.csv")],
    ("no such file", "\\x1b"))
add("viewlines-out-path-with-newline", "viewlines",
    lambda e, d: argv_viewlines(e, d, out=str(_mkdir(d / "a\nfolder"))), ("is a folder",))


def _emulate_with_stream(data: bytes):
    def b(e, d):
        s = d / "sess"
        shutil.copytree(e.session, s, ignore=shutil.ignore_patterns("truth", "calibration", "scene.mp4"))
        m = json.loads((s / "session.json").read_text())
        m["files"] = {k: v for k, v in m["files"].items() if not k.startswith("truth") and k not in (
            "eye_calibration", "camera_views", "scene_video")}
        m["has_recording"] = False
        (s / "session.json").write_text(json.dumps(m))
        (s / "eye_serial.bin").write_bytes(data)
        return ["emulate", str(s), "--listen", "127.0.0.1:0", "--duration", "0.3"]
    return b


add("emulate-eye-serial-garbage", "emulate", _emulate_with_stream(bytes(range(256)) * 4), "no valid record")
add("emulate-eye-serial-empty", "emulate", _emulate_with_stream(b""), "no valid record")
add("emulate-eye-serial-bad-checksums", "emulate",
    _emulate_with_stream(b"$EMR8,1,0.0,1.00,2.00,3.00,4.00,3*00\r\n" * 50), "no valid record")
add("emulate-listen-unassignable", "emulate",
    lambda e, d: ["emulate", e["session"], "--listen", "192.0.2.1:5555", "--duration", "0.3"], "cannot listen")
add("emulate-pty-and-listen", "emulate", lambda e, d: ["emulate", e["session"], "--pty", "--listen", "127.0.0.1:0"],
    "not allowed")
add("reproduce-calibration-out-is-file", "reproduce",
    lambda e, d: ["reproduce", "calibration", "--trials", "1", "--out", write(d, "f", "keep")], ("--out", "is a file"))
add("reproduce-trials-too-many", "reproduce", lambda e, d: ["reproduce", "table1", "--trials", "99999999999",
                                                            "--out", str(d / "r")], ("--trials", "too large"))
add("demo-duration-10-days", "demo", lambda e, d: ["demo", "--out", str(d / "demo"), "--duration", "864000"],
    ("duration_s", "<="))
add("demo-out-parent-parent-is-file", "demo", lambda e, d: ["demo", "--out", write(d, "f", "k") + "/a/b"],
    ("--out", "not a folder"))


# 7. outputs: a folder where a file goes, a file where a folder goes, a parent that is a file,
#    a read-only folder, an output that is an input --------------------------------------------

FILE_OUTPUTS = [
    ("estimate", "--export-density", ".ply", lambda e, d, o: argv_estimate(e, e["viewlines"],
                                                                           ["--export-density", o])),
    ("calibrate-camera", "-o", ".json", lambda e, d, o: argv_calibrate_camera(e, d, out=o)),
    ("calibrate-eyes", "-o", ".json", lambda e, d, o: argv_calibrate_eyes(e, d, out=o)),
    ("viewlines", "-o", ".csv", lambda e, d, o: argv_viewlines(e, d, out=o)),
    ("fixations", "-o", ".csv", lambda e, d, o: argv_fixations(e, d, out=o)),
    ("track", "-o", ".csv", lambda e, d, o: argv_track(e, d, out=o)),
    ("track-overlay", "--overlay", ".mp4", lambda e, d, o: argv_track(e, d, extra=["--overlay", o])),
    ("markers", "-o", ".pdf", lambda e, d, o: ["markers", "--ids", "0-3", "--size-mm", "50", "-o", o]),
]
for name, opt, ext, build in FILE_OUTPUTS:
    command = name.split("-overlay")[0]
    add(f"{name}-out-is-folder", command, lambda e, d, build=build, ext=ext: build(e, d, str(_mkdir(d / f"o{ext}"))),
        (opt, "is a folder"))
    add(f"{name}-out-parent-is-file", command, lambda e, d, build=build, ext=ext: build(
        e, d, write(d, "afile", "keep") + f"/o{ext}"), (opt, "not a folder"))
    add(f"{name}-out-parent-parent-is-file", command, lambda e, d, build=build, ext=ext: build(
        e, d, write(d, "afile", "keep") + f"/x/y/o{ext}"), (opt, "not a folder"))
    add(f"{name}-out-read-only-folder", command, lambda e, d, build=build, ext=ext: build(
        e, d, str(read_only_dir(d) / f"o{ext}")), (opt, "not writable"))


def _mkdir(p: Path) -> Path:
    p.mkdir()
    (p / "keep.txt").write_text("keep")
    return p


FOLDER_OUTPUTS = [
    ("reproduce", "--out", lambda e, d, o: ["reproduce", "table1", "--trials", "1", "--out", o]),
    ("simulate", "-o", lambda e, d, o: ["simulate", "-o", o, "--resolution", "320x180", "--duration", "1"]),
    ("process", "-o", lambda e, d, o: ["process", e["session"], "-o", o, "--no-overlay"]),
    ("demo", "--out", lambda e, d, o: ["demo", "--out", o, "--duration", "2"]),
    ("live", "--record", lambda e, d, o: argv_live(e, d, extra=["--record", o])),
    ("import", "-o", lambda e, d, o: ["import", e["session"], "-o", o, "--format", "tobii-g3"]),
    ("export-recording", "-o", lambda e, d, o: ["export-recording", e["session"], "-o", o, "--format", "tobii-g3"]),
]
for command, opt, build in FOLDER_OUTPUTS:
    add(f"{command}-out-is-file", command, lambda e, d, build=build: build(e, d, write(d, "afile", "keep")),
        (opt, "is a file"))
    add(f"{command}-out-parent-is-file", command, lambda e, d, build=build: build(e, d, write(d, "afile", "k") + "/o"),
        (opt, "not a folder"))
    add(f"{command}-out-read-only-folder", command, lambda e, d, build=build: build(e, d, str(read_only_dir(d) / "o")),
        (opt, "not writable"))

# import and export-recording (issue 14): the recording, the format, the options
add("import-src-missing", "import", lambda e, d: ["import", str(d / "nothing"), "-o", str(d / "s")],
    ("no such recording",))
add("import-src-undetectable", "import", lambda e, d: ["import", e["session"], "-o", str(d / "s")],
    ("none of the known formats", "--format"))
add("import-src-is-file", "import", lambda e, d: ["import", e["markers"], "-o", str(d / "s")], ("a file", "--format"))
add("import-out-not-empty", "import", lambda e, d: ["import", e["session"], "-o", str(_mkdir(d / "o"))],
    ("not empty",))
add("import-out-is-src", "import", lambda e, d: ["import", e["session"], "-o", e["session"]], ("also an input",))
add("import-markers-missing", "import", lambda e, d: ["import", e["session"], "-o", str(d / "s"), "--format",
                                                      "tobii-g3", "--markers", str(d / "m.json")], ("--markers",))
add("import-format-unknown", "import", lambda e, d: ["import", e["session"], "-o", str(d / "s"), "--format", "emr8"],
    ("--format",))
opt_cases("import", lambda e, d, x: ["import", e["session"], "-o", str(d / "s"), *x], "--marker-size-mm",
          ["0", "-1", "nan", "abc"])
opt_cases("import", lambda e, d, x: ["import", e["session"], "-o", str(d / "s"), *x], "--max-pose-gap",
          ["0", "inf"])
add("export-recording-not-simulated", "export-recording",
    lambda e, d: ["export-recording", str(_mkdir(d / "x")), "-o", str(d / "r"), "--format", "aria-mps"],
    ("session.json",))
add("export-recording-session-missing", "export-recording",
    lambda e, d: ["export-recording", str(d / "none"), "-o", str(d / "r"), "--format", "aria-mps"], ("session",))
add("export-recording-format-missing", "export-recording",
    lambda e, d: ["export-recording", e["session"], "-o", str(d / "r")], ("--format",))
add("export-recording-format-unknown", "export-recording",
    lambda e, d: ["export-recording", e["session"], "-o", str(d / "r"), "--format", "emr8"], ("--format",))
add("export-recording-eye-states-not-cloud", "export-recording",
    lambda e, d: ["export-recording", e["session"], "-o", str(d / "r"), "--format", "tobii-g2", "--eye-states"],
    ("--eye-states", "pupil-cloud", "leave --eye-states out"))
add("export-recording-aria-gen2", "export-recording",
    lambda e, d: ["export-recording", e["session"], "-o", str(d / "r"), "--format", "aria-gen2"],
    ("aria-gen2 is not available", "--format aria-mps"))

# aoi (issue 28): the AOI file, the processed folder, the options
def argv_aoi(e, d, aois=None, processed=None, out=None, extra=()):
    if aois is None:
        aois = write(d, "aois.json", json.dumps({"aois": [{"name": "a", "sphere": {"center_mm": [0, 0, 1000],
                                                                                  "radius_mm": 100}}]}))
    return ["aoi", processed or str(e.base), "--aois", aois, "-o", out or str(d / "o"), *extra]


add("aoi-file-missing", "aoi", lambda e, d: argv_aoi(e, d, str(d / "none.json")), ("no such file",))
add("aoi-file-not-json", "aoi", lambda e, d: argv_aoi(e, d, write(d, "a.json", "{not json")), ("a.json",))
add("aoi-no-shape", "aoi", lambda e, d: argv_aoi(e, d, write(d, "a.json", '{"aois": [{"name": "x"}]}')),
    ("needs one of the keys",))
add("aoi-name-twice", "aoi", lambda e, d: argv_aoi(e, d, write(d, "a.json", json.dumps({"aois": [
    {"name": "x", "sphere": {"center_mm": [0, 0, 1], "radius_mm": 1}}] * 2}))), ("used twice",))
add("aoi-marker-not-in-map", "aoi", lambda e, d: argv_aoi(e, d, write(d, "a.json", json.dumps({"aois": [
    {"name": "m", "marker": {"id": 999}}]})), extra=["--markers", e["markers"]]), ("not in the marker map",))
add("aoi-not-processed", "aoi", lambda e, d: argv_aoi(e, d, processed=str(d)), ("viewlines.csv",))
add("aoi-out-is-file", "aoi", lambda e, d: argv_aoi(e, d, out=write(d, "afile", "keep")), ("-o", "is a file"))
opt_cases("aoi", lambda e, d, x: argv_aoi(e, d, extra=x), "--assign-probability", ["0", "1", "1.5", "nan", "abc"])

# -o equal to an input (the four, and their neighbours)
SAME = [
    ("fixations-out-is-viewlines", "fixations", lambda e, d: argv_fixations(e, d, _cp(e.viewlines, d),
                                                                            str(d / "viewlines.csv"))),
    ("viewlines-out-is-eye-csv", "viewlines",
     lambda e, d: argv_viewlines(e, d, eye=_cp(e.eye, d), out=str(d / "eye.csv"))),
    ("viewlines-out-is-poses", "viewlines", lambda e, d: argv_viewlines(e, d, poses=_cp(e.poses, d),
                                                                        out=str(d / "poses.csv"))),
    ("viewlines-out-is-eyes-json", "viewlines", lambda e, d: argv_viewlines(e, d, eyes=_cp(e.eyes, d),
                                                                            out=str(d / "eyes.json"))),
    ("viewlines-out-is-eye-csv-other-spelling", "viewlines",
     lambda e, d: argv_viewlines(e, d, eye=_cp(e.eye, d), out=str(d / "sub" / ".." / "eye.csv"))
     if _mkdir(d / "sub") else None),
    ("track-out-is-video", "track", lambda e, d: argv_track(e, d, video=_cp(e.video, d), out=str(d / "scene.mp4"))),
    ("track-out-is-markers", "track", lambda e, d: argv_track(e, d, markers=_cp(e.markers, d),
                                                              out=str(d / "markers.json"))),
    ("track-overlay-is-video", "track", lambda e, d: argv_track(e, d, video=_cp(e.video, d),
                                                                extra=["--overlay", str(d / "scene.mp4")])),
    ("track-overlay-is-out", "track", lambda e, d: argv_track(e, d, out=str(d / "p.csv"),
                                                              extra=["--overlay", str(d / "p.csv")])),
    ("track-out-is-timestamps", "track",
     lambda e, d: argv_track(e, d, out=_cp(e.timestamps, d), extra=["--timestamps", str(d / "scene_timestamps.csv")])),
    ("track-out-is-video-symlink", "track",
     lambda e, d: argv_track(e, d, video=_cp(e.video, d), out=_symlink(d / "scene.mp4", d / "link.mp4"))),
    ("calibrate-camera-out-is-image", "calibrate-camera",
     lambda e, d: argv_calibrate_camera(e, d, inputs=[_cptree(e.views, d)], out=str(d / "views" / "view_003.png"))),
    ("calibrate-camera-preview-is-image", "calibrate-camera",
     lambda e, d: argv_calibrate_camera(e, d, inputs=[_cptree(e.views, d)], out=str(d / "views" / "view.json"))
     if (d / "views").exists() or _cptree(e.views, d) and os.rename(d / "views" / "view_004.png",
                                                                    d / "views" / "view_undistorted.png") is None
     else None),
    ("calibrate-eyes-out-is-camera", "calibrate-eyes",
     lambda e, d: argv_calibrate_eyes(e, d, camera=_cp(e.camera, d), out=str(d / "camera.json"))),
    ("calibrate-eyes-out-is-walls", "calibrate-eyes",
     lambda e, d: argv_calibrate_eyes(e, d, source=_cptree(e.eye_cal, d), out=str(d / "eye" / "walls.json"))),
    ("calibrate-eyes-out-is-csv", "calibrate-eyes",
     lambda e, d: argv_calibrate_eyes(e, d, source=_cptree(e.eye_cal, d), out=str(d / "eye" / "eye_calibration.csv"))),
    ("estimate-density-is-input", "estimate",
     lambda e, d: argv_estimate(e, _cp(e.viewlines, d, "v.ply"), ["--export-density", str(d / "v.ply")])),
    ("process-out-is-session", "process", lambda e, d: ["process", _session_copy_full(e, d), "-o", str(d / "sess"),
                                                        "--no-overlay"]),
    ("simulate-out-is-scenario", "simulate",
     lambda e, d: ["simulate", "--scenario", write(d, "s.json", {"base": "lab-walkabout"}), "-o", str(d / "s.json")]),
]
for vid, command, build in SAME:
    add(vid, command, build, "is also an input")


def _cp(src: Path, d: Path, name=None) -> str:
    dst = d / (name or src.name)
    shutil.copy(src, dst)
    return str(dst)


def _cptree(src: Path, d: Path) -> str:
    dst = d / ("views" if src.name == "camera" else "eye")
    if not dst.exists():
        shutil.copytree(src, dst)
    return str(dst)


def _symlink(target: Path, link: Path) -> str:
    os.symlink(target, link)
    return str(link)


# 8. damaged inputs of the issue-25 run: internal errors, a silent exit 0, an input overwritten -------

def _real(*parts) -> Path:
    from conftest import real_data_root

    return real_data_root().joinpath(*parts)


def _real_copy(d: Path, name: str) -> Path:
    """A writable copy of a real recording in the case folder."""
    dst = d / name
    shutil.copytree(_real(name), dst)
    for p in [dst, *dst.rglob("*")]:
        os.chmod(p, 0o755 if p.is_dir() else 0o644)
    return dst


def _wrong_dict_map(e, d) -> str:
    """The session's map (DICT_4X4_50 markers printed) saying DICT_APRILTAG_36h11."""
    return write(d, "map36h11.json", edited_json(e.markers, lambda m: m.__setitem__("dictionary",
                                                                                  "DICT_APRILTAG_36h11")))


def _session_with(e, d, rel: str, content) -> str:
    s = _session_copy_full(e, d)
    write(Path(s), rel, content)
    return s


def _imported_swapped_poses(e, d) -> str:
    """An imported session (simulated Aria MPS recording) whose head_poses.csv has rows 3 and 4 swapped."""
    assert main(["export-recording", e["session"], "-o", str(d / "rec"), "--format", "aria-mps"]) == 0
    assert main(["import", str(d / "rec"), "-o", str(d / "imp")]) == 0
    p = d / "imp" / "head_poses.csv"
    lines = p.read_text().splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    p.write_text("\n".join(lines) + "\n")
    return str(d / "imp")


def _viewlines_rows(e, edit_row, n=None) -> str:
    lines = e.viewlines.read_text().splitlines()
    rows = lines[1:] if n is None else lines[1:1 + n]
    return "\n".join([lines[0], *(",".join(edit_row(r.split(","))) for r in rows)]) + "\n"


def _neon_damaged(name, damage):
    def b(e, d):
        src = _real_copy(d, "pupil_labs_neon_demo_recording")
        p = src / name
        p.write_bytes(damage(p.read_bytes()))
        return ["import", str(src), "-o", str(d / "s")]
    return b


def _aria_gaze(damage):
    def b(e, d):
        src = _real_copy(d, "aria_mps_sample_gen1")
        p = src / "eye_gaze_vergence" / "generalized_gaze.csv"
        p.write_bytes(damage(p.read_bytes()))
        return ["import", str(src), "-o", str(d / "s")]
    return b


def _truncated_wall_jpeg(e, d) -> list:
    import cv2

    eye = Path(_cptree(e.eye_cal, d))
    ok, buf = cv2.imencode(".jpg", cv2.imread(str(eye / "wall_0.png")))
    (eye / "wall_0.jpg").write_bytes(buf.tobytes()[:len(buf) // 2])
    (eye / "walls.json").write_text((eye / "walls.json").read_text().replace("wall_0.png", "wall_0.jpg"))
    return argv_calibrate_eyes(e, d, source=str(eye))


add("track-map-other-dictionary", "track", lambda e, d: argv_track(e, d, markers=_wrong_dict_map(e, d)),
    ("no marker of DICT_APRILTAG_36h11", "look like DICT_4X4_50"))
add("map-dict-other-dictionary", "map", lambda e, d: ["map", e["video"], "--camera", e["camera"], "--dict",
                                                      "DICT_APRILTAG_36h11", "--size-mm", "200",
                                                      "-o", str(d / "m.json")],
    ("no marker of DICT_APRILTAG_36h11", "--dict DICT_4X4_50"))
add("map-extend-other-dictionary", "map", lambda e, d: ["map", e["video"], "--camera", e["camera"], "--extend",
                                                        _wrong_dict_map(e, d), "-o", str(d / "m.json")],
    ("no marker of DICT_APRILTAG_36h11", "DICT_4X4_50"))
add("process-map-other-dictionary", "process", lambda e, d: argv_process(
    e, d, _session_with(e, d, "markers.json", edited_json(e.markers, lambda m: m.__setitem__(
        "dictionary", "DICT_APRILTAG_36h11"))), ["--camera", e["camera"], "--eyes", e["eyes"]]),
    ("tracking", "look like DICT_4X4_50"), many=True)
add("viewlines-poses-time-repeated", "viewlines", lambda e, d: argv_viewlines(e, d, poses=write(
    d, "p.csv", "\n".join((ls := e.poses.read_text().splitlines())[:3] + [ls[2]] + ls[3:]) + "\n")),
    ("line 4", "does not increase", "sort"))
add("process-imported-poses-swapped", "process", lambda e, d: argv_process(e, d, _imported_swapped_poses(e, d)),
    ("head_poses.csv line 5", "does not increase"), many=True)
add("estimate-one-row-paper", "estimate", lambda e, d: argv_estimate(e, write(d, "v.csv", _viewlines_rows(
    e, lambda c: c, 1)), ["--method", "paper"]), ("nothing could be estimated", "segment 0"))
add("estimate-every-row-segment-minus-1", "estimate", lambda e, d: argv_estimate(e, write(d, "v.csv", _viewlines_rows(
    e, lambda c: [*c[:-1], "-1"]))), ("nothing to estimate", "segment -1"))
# parallel lines are no bad input since issue 27: they are answered by their direction (direction-only,
# tests/test_direction_only.py)
add("calibrate-eyes-camera-other-image-size", "calibrate-eyes", lambda e, d: argv_calibrate_eyes(e, d, camera=write(
    d, "c.json", edited_json(e.camera, lambda c: c.__setitem__("image_size", [1920, 1080])))),
    ("320x180", "1920x1080"))
add("calibrate-eyes-wall-jpeg-truncated", "calibrate-eyes", _truncated_wall_jpeg, ("wall_0.jpg", "truncated"))
add("learn-bias-truth-version-99", "learn-bias", lambda e, d: argv_learn_bias(e, d, write(
    d, "t.json", edited_json(e.session / "truth" / "targets.json", lambda t: t.__setitem__("version", 99)))),
    ("version 99", "version 1"))
add("learn-bias-out-is-processed-eyes", "learn-bias", lambda e, d: argv_learn_bias(e, d, out=e["eyes"]),
    ("is also an input", "eyes.json"))
add("process-out-in-board-views", "process", lambda e, d: ["process", _session_copy_full(e, d), "-o",
                                                           str(d / "sess" / "calibration" / "camera"), "--no-overlay"],
    ("input folder", "calibration/camera"))
add("import-neon-info-json-not-utf8", "import", _neon_damaged("info.json", lambda b: b.replace(
    b"Neon Companion", b"Neon \xff\xfeCompanion")), ("info.json", "not utf-8"))
add("import-neon-calibration-serial-not-utf8", "import", _neon_damaged(
    "calibration.bin", lambda b: b[:1] + b"\xff\xfe" * 3 + b[7:]), ("calibration.bin", "serial", "not utf-8"))
add("import-aria-per-eye-gaze-renamed", "import", _aria_gaze(lambda b: b.replace(
    b"left_yaw_rads_cpf,right_yaw_rads_cpf,pitch_rads_cpf,", b"left_yaw,right_yaw,pitch,", 1)),
    ("generalized_gaze.csv", "not an mps eye-gaze csv"))
add("import-aria-per-eye-gaze-garbage", "import", _aria_gaze(lambda b: bytes(range(256)) * 8),
    ("generalized_gaze.csv", "not an mps eye-gaze csv"))


# --- the test ------------------------------------------------------------------------------------

@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_bad_input(c: Case, env, case_dir, capsys):
    argv = c.build(env, case_dir)
    assert argv is not None
    match = c.match.resolve(env) if isinstance(c.match, _CsvMatch) else c.match
    before = _snapshot(env.base, case_dir)
    code, err = _run([str(a) for a in argv], capsys)
    assert code == 2, f"exit status {code}, stderr:\n{err}"
    _assert_one_line(err, match, c.command, many=c.many)
    after = _snapshot(env.base, case_dir)
    changed = sorted(p for p in set(before) | set(after) if before.get(p, "gone") != after.get(p, "gone"))
    if c.many:            # process goes on with its other steps: their outputs may appear in its -o folder
        changed = [p for p in changed if p in before or not p.startswith(str(case_dir / "out"))]
    assert not changed, f"files changed, appeared or vanished: {changed[:5]}"


def test_matrix_covers_every_command_with_enough_cases():
    commands = {"estimate", "fixations", "reproduce", "calibrate-camera", "calibrate-eyes", "viewlines", "track",
                "markers", "simulate", "process", "live", "emulate", "demo", "import", "export-recording",
                "learn-bias", "aoi"}
    per = {k: sum(c.command == k for c in CASES) for k in commands}
    assert all(n >= 5 for n in per.values()), per
    assert len(CASES) >= 250, len(CASES)
    assert len({c.id for c in CASES}) == len(CASES), "case ids must be unique"


# --- the installed executable behaves the same ---------------------------------------------------

EXE = Path(sys.executable).parent / "wearable-gaze"


@pytest.mark.skipif(not EXE.exists(), reason=f"{EXE} not installed (pip install -e .)")
@pytest.mark.parametrize("cid", ["viewlines-out-is-eye-csv", "track-out-is-video", "markers-ids-reversed",
                                 "live-publish-udp___127_0_0_1_99999", "track-camera-yaml-garbage",
                                 "process-session-eye-samples-etc-passwd", "simulate-scenario-fixation-zero",
                                 "track-markers-T-ragged"])
def test_installed_executable_same(cid, env, case_dir):
    c = next(c for c in CASES if c.id == cid)
    argv = [str(a) for a in c.build(env, case_dir)]
    before = _snapshot(env.base, case_dir)
    r = subprocess.run([str(EXE), *argv], capture_output=True, text=True, timeout=120, cwd=case_dir)
    assert r.returncode == 2, r.stderr
    _assert_one_line(r.stderr, c.match, c.command, many=c.many)
    assert _snapshot(env.base, case_dir) == before


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"wearable-gaze {version('wearable-gaze')}"


def test_untrusted_camera_calibration_warns_and_says_so(env, tmp_path, capsys):
    """A calibration OpenCV returns but that is plainly wrong (here: 320x180 views too coarse for the
    board, RMS 1.6 px and fx 20 % off) is kept, marked untrusted, with one warning line per reason."""
    out = tmp_path / "cam.json"
    code, err = _run(["calibrate-camera", env["views"], "--board", env.board, "-o", str(out)], capsys)
    assert code == 0 and "Traceback" not in err
    d = json.loads(out.read_text())
    assert d["trusted"] is False and d["warnings"]
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == len(d["warnings"]) and all("cannot be trusted" in ln for ln in lines)
    assert any("RMS" in w for w in d["warnings"])


# --- the issue-25 run's cases that are not one bad input -----------------------------------------

def test_calibrate_camera_twice_into_its_photo_folder(env, tmp_path, capsys):
    """``-o photos/cam.json`` writes cam_undistorted.png among the photos: the next calibration of
    the folder leaves that preview out (it used to refuse to overwrite it as an input)."""
    photos = tmp_path / "photos"
    shutil.copytree(env.views, photos)
    argv = ["calibrate-camera", str(photos), "--board", env.board, "-o", str(photos / "cam.json")]
    assert _run(argv, capsys)[0] == 0
    first = json.loads((photos / "cam.json").read_text())
    assert (photos / "cam_undistorted.png").is_file()
    code, err = _run(argv, capsys)
    assert code == 0, err
    assert json.loads((photos / "cam.json").read_text())["camera_matrix"] == first["camera_matrix"]


def test_process_failed_eye_step_prints_its_error_only(env, tmp_path, capsys):
    """A failed eye calibration is reported once; the targets step's error model, which will not
    run, no longer warns that eyes.json has no leave-one-out errors ([Errno 2])."""
    s = tmp_path / "sess"
    shutil.copytree(env.session, s)
    (s / "calibration" / "eye" / "walls.json").write_text("{")
    code, err = _run(["process", str(s), "-o", str(tmp_path / "out"), "--no-overlay", "--camera", env["camera"]],
                     capsys)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "walls.json" in lines[0], err


def test_image_reader_keeps_libjpeg_warnings_off_stderr(tmp_path, capfd):
    """A JPEG libjpeg decodes with a warning (junk bytes before a marker) is read, and the
    warning, which libjpeg prints on file descriptor 2 itself, does not reach the terminal."""
    import cv2
    import numpy as np

    from wearable_gaze.formats.images import read_gray_image

    img = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    data = cv2.imencode(".jpg", img)[1].tobytes()
    k = data.index(b"\xff\xdb")                          # the first quantisation table: junk before it
    (tmp_path / "a.jpg").write_bytes(data[:k] + b"\x12\x34\x56" + data[k:])
    capfd.readouterr()
    assert read_gray_image(tmp_path / "a.jpg").shape == (48, 64)
    assert capfd.readouterr().err == ""
