"""Issue 25's bad inputs, re-run as a new user would: each through the installed ``wearable-gaze``
command in a fresh process, with its damaged input made from a small simulated session or a copy
of the real recordings (../shared/data/real). For each case: the exit status, the number of lines
on stderr, whether a traceback was printed, and whether any input file changed (SHA-256 of every
file under the inputs before and after). A case passes when it exits 2 with one line and no input
changed, or when it is a documented, counted drop (exit 0 with the drop in the output).

    python benchmarks/bad_inputs_issue25.py --work DIR [--real ../shared/data/real]

Prints one row per case and the count that pass; exits 1 when any fails.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "wearable_gaze"]


def digest(paths) -> dict:
    out = {}
    for p in paths:
        p = Path(p)
        files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else []
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def run(args, inputs, env=None, timeout=900) -> dict:
    before = digest(inputs)
    p = subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, **(env or {})})
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and "still running" not in ln
             and not ln.rstrip().endswith((" done", " s"))]          # progress lines off a terminal
    return {"status": p.returncode, "lines": len(lines), "traceback": "Traceback" in p.stderr,
            "changed": sorted(k for k, v in digest(inputs).items() if before.get(k) != v)
            + sorted(set(before) - set(digest(inputs))), "first": lines[0][:150] if lines else p.stdout[-150:],
            "warning": next((ln for ln in lines if ": warning: " in ln), "")}


def simulated(work: Path) -> tuple[Path, Path]:
    s, out = work / "S", work / "OUT"
    if not (s / "session.json").is_file():
        subprocess.run(CLI + ["simulate", "--scenario", "lab-walkabout", "--duration", "6", "--resolution", "640x360",
                              "-o", str(s), "--seed", "3"], check=True, capture_output=True)
    if not (out / "summary.json").is_file():
        subprocess.run(CLI + ["process", str(s), "-o", str(out), "--no-overlay"], capture_output=True)
    return s, out


def processed(session: Path, out: Path) -> Path:
    """``out``: ``session`` processed into it afresh (a cached run there is then valid: the
    damage that follows is the only change)."""
    if out.exists():
        shutil.rmtree(out)
    subprocess.run(CLI + ["process", str(session), "-o", str(out), "--no-overlay"], capture_output=True)
    return out


def cases(work: Path, real: Path):
    s, out = simulated(work)
    c = work / "cases"
    c.mkdir(exist_ok=True)

    def copy(src, name):
        dst = c / name
        if dst.exists():
            shutil.rmtree(dst)
        (shutil.copytree if Path(src).is_dir() else shutil.copy)(src, dst)
        return dst

    # 1-2. calibrate-eyes: a wall photo with no marker, a truncated wall photo
    for name in ("nomarker", "truncated"):
        ss = copy(s, f"S_{name}")
        wall = ss / "calibration" / "eye" / "wall_0.png"
        if name == "nomarker":
            import cv2
            import numpy as np
            img = cv2.imread(str(wall))
            cv2.imwrite(str(wall), np.full_like(img, 200))
        else:
            wall.write_bytes(wall.read_bytes()[: len(wall.read_bytes()) // 2])
        yield f"calibrate-eyes, wall photo {name}", ["calibrate-eyes", ss, "--camera", ss / "truth/camera.json",
                                                     "-o", c / f"eyes_{name}.json"], [ss]
    # 3-6. a map whose dictionary is not the printed one
    bad_map = c / "map_apriltag.json"
    m = json.loads((s / "markers.json").read_text())
    m["dictionary"] = "DICT_APRILTAG_36h11"
    bad_map.write_text(json.dumps(m))
    yield "track, map of another dictionary", ["track", s / "scene.mp4", "--camera", s / "truth/camera.json",
                                               "--markers", bad_map, "-o", c / "p.csv"], [s, bad_map]
    yield "map --extend, map of another dictionary", ["map", s / "scene.mp4", "--camera", s / "truth/camera.json",
                                                      "--size-mm", "120", "--extend", bad_map, "-o", c / "m2.json"], \
        [s, bad_map]
    yield "map, --dict not the printed one", ["map", s / "scene.mp4", "--camera", s / "truth/camera.json",
                                              "--size-mm", "120", "--dict", "DICT_APRILTAG_36h11",
                                              "-o", c / "m3.json"], [s]
    ss = copy(s, "S_dict")
    (ss / "markers.json").write_text(json.dumps(m))
    yield "process, session map of another dictionary", ["process", ss, "-o", c / "o_dict"], [ss]
    # 7. viewlines with unsorted pose times
    poses = copy(out / "poses.csv", "poses_swapped.csv")
    rows = poses.read_text().splitlines()
    rows[5], rows[6] = rows[6], rows[5]
    poses.write_text("\n".join(rows) + "\n")
    yield "viewlines, pose times unsorted", ["viewlines", s / "eye.csv", "--eyes", out / "eyes.json", "--poses", poses,
                                             "-o", c / "vl.csv"], [s, out, poses]
    # 8. process on an imported session with two head_poses.csv rows swapped
    if (real / "aria_mps_sample_gen1").is_dir():
        imp = c / "aria_imported"
        if not imp.is_dir():
            subprocess.run(CLI + ["import", real / "aria_mps_sample_gen1", "-o", imp], capture_output=True, check=True)
        ia = copy(imp, "aria_swapped")
        hp = ia / "head_poses.csv"
        rows = hp.read_text().splitlines()
        rows[10], rows[11] = rows[11], rows[10]
        hp.write_text("\n".join(rows) + "\n")
        yield "process, imported head_poses.csv rows swapped", ["process", ia, "-o", c / "o_aria"], [ia]
    # 9-10. Neon: non-UTF-8 bytes in info.json and calibration.bin
    neon = real / "pupil_labs_neon_demo_recording"
    if neon.is_dir():
        src = next(p.parent for p in neon.rglob("info.json"))
        for name in ("info.json", "calibration.bin"):
            nd = copy(src, f"neon_{name}")
            f = nd / name
            if f.is_file():
                b = bytearray(f.read_bytes())
                if name == "info.json":
                    b[2:4] = b"\xff\xfe"
                else:
                    b[1:7] = b"\xff\xfe\xfd\xfc\xfb\xfa"        # the serial number's bytes
                f.write_bytes(bytes(b))
                yield f"import neon, {name} not UTF-8", ["import", nd, "-o", c / f"o_neon_{name}",
                                                        "--format", "pupil-neon"], [nd]
    # 11-12. OUT/.viewlines_counts.json not UTF-8, OUT/.steps.json deeply nested
    for name, text in ((".viewlines_counts.json", b"\xff\xfe{"), (".steps.json", b"[" * 100000 + b"]" * 100000)):
        o = processed(s, c / f"OUT_{name}")
        (o / name).write_bytes(text)
        yield f"process, OUT/{name} damaged (warning, full redo)", ["process", s, "-o", o, "--no-overlay"], [s]
    # 13-15. estimate with nothing to estimate
    vl = out / "viewlines.csv"
    head, *body = vl.read_text().splitlines()
    one = c / "vl_one.csv"
    one.write_text(head + "\n" + body[0] + "\n")
    yield "estimate, one row", ["estimate", one, "--method", "paper"], [one]
    seg = c / "vl_seg.csv"
    cols = head.split(",")
    k = cols.index("segment") if "segment" in cols else None
    if k is not None:
        seg.write_text(head + "\n" + "\n".join(",".join(r.split(",")[:k] + ["-1"] + r.split(",")[k + 1:])
                                                for r in body) + "\n")
        yield "estimate, every row in segment -1", ["estimate", seg], [seg]
    # 16. calibrate-eyes with a camera file of another image size
    cam = json.loads((s / "truth/camera.json").read_text())
    cam["image_size"] = [1920, 1080]
    big = c / "camera_1920.json"
    big.write_text(json.dumps(cam))
    yield "calibrate-eyes, camera of another image size", ["calibrate-eyes", s, "--camera", big,
                                                           "-o", c / "eyes_big.json"], [s, big]
    # 17. learn-bias with "version": 99
    val = json.loads((s / "truth/targets.json").read_text())
    val["version"] = 99
    v99 = c / "validation99.json"
    v99.write_text(json.dumps(val))
    yield "learn-bias, version 99", ["learn-bias", s, "--validation", v99, "-o", c / "person.json"], [s, v99]
    # 18-19. Aria: per-eye gaze file garbage, renamed columns
    if (real / "aria_mps_sample_gen1").is_dir():
        for name in ("garbage", "renamed"):
            ad = copy(real / "aria_mps_sample_gen1", f"aria_{name}")
            for f in ad.glob("eye_gaze*/*.csv"):
                text = f.read_text()
                if "left_yaw_rads_cpf" in text:                 # the per-eye file
                    f.write_text("\x00garbage\x01\n" * 5 if name == "garbage" else
                                 text.replace("left_yaw", "L_yaw").replace("right_yaw", "R_yaw"))
            yield f"import aria, per-eye gaze {name}", ["import", ad, "-o", c / f"o_aria_{name}"], [ad]
    # 20. batch -o inside one of its sessions
    sb = copy(s, "S_batch")
    yield "batch -o inside one of its sessions", ["batch", sb, "-o", sb / "batch_out"], [sb]
    # 21. learn-bias -o PROCESSED/eyes.json
    ob = copy(out, "OUT_learn")
    yield "learn-bias -o PROCESSED/eyes.json", ["learn-bias", s, "--validation", s / "truth/targets.json",
                                                "--processed", ob, "-o", ob / "eyes.json"], [s, ob]
    # 22. calibrate-camera -o photos/cam.json, twice
    photos = copy(s / "calibration" / "camera", "photos")
    run(["calibrate-camera", photos, "--board", "chessboard:9x6:30", "-o", photos / "cam.json"], [])
    yield "calibrate-camera again into the photo folder", ["calibrate-camera", photos, "--board", "chessboard:9x6:30",
                                                           "-o", photos / "cam2.json"], []
    # 23. process -o SESSION/calibration/camera
    sc = copy(s, "S_outinside")
    yield "process -o SESSION/calibration/camera", ["process", sc, "-o", sc / "calibration" / "camera"], [sc]
    # 24. a cached output cut short
    oc = processed(s, c / "OUT_cut")
    p = oc / "poses.csv"
    rows = p.read_text().splitlines()
    p.write_text("\n".join(rows[: len(rows) // 2]) + "\n")
    yield "process after OUT/poses.csv cut to half (redone, said)", ["process", s, "-o", oc, "--no-overlay"], [s]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", required=True, type=Path)
    ap.add_argument("--real", type=Path, default=ROOT.parent / "shared" / "data" / "real")
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    ok_all = 0
    rows = []
    for name, args, inputs in cases(a.work, a.real):
        r = run(args, inputs)
        redo = "redone" in name or "full redo" in name
        ok = bool(not r["traceback"] and not r["changed"]
              and ((r["status"] == 2 and r["lines"] == 1) or (redo and r["status"] in (0, 3) and r["warning"]) or
                   ("again" in name and r["status"] == 0)))
        ok_all += ok
        rows.append((name, r))
        print(f"{'ok ' if ok else 'BAD'} {name}: exit {r['status']}, {r['lines']} stderr line(s), "
              f"{'traceback, ' if r['traceback'] else ''}{len(r['changed'])} input(s) changed | "
              f"{r['warning'][:150] if redo else r['first']}",
              flush=True)
    print(f"{ok_all} of {len(rows)} cases pass")
    return 0 if ok_all == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
