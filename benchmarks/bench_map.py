"""A marker map built from a simulated survey (issue 16): the `survey` scenario (a loop around the
lab room's walls, 24 markers, 1280x720 at 30 fps) rendered once, then ``wearable-gaze map`` on its
video (at most --frames evenly spaced frames) with the scene camera's true intrinsics, on one core.
Accuracy: the built map's marker corners against the true map, after the transform fixed by the
origin marker (its pose in both maps) and after the best similarity; and the time per run.

    python benchmarks/bench_map.py [--seconds 60] [--seed 0] [--frames 300] [--work DIR] [--walkabout N]
                                   [--moved [ID]] [--resolution WxH] [--fps F] [--rough N]

With ``--walkabout N``: also N lab-walkabout sessions of the same room (seeds seed..seed+N-1, each
with its own survey), each processed with its true map and with the map built from its survey
(moved into the true world by the origin marker's pose, for the comparison only): the fixated
targets' errors with each.

With ``--moved [ID]``: also the same survey with marker ID (default 15) moved 150 mm along its
wall halfway through (scenario ``moved_marker``, docs/scenarios.md): whether the map flags it,
and only it; its pose after the move (the map's) and before it (fitted to the views before the
move as the map posed them) against the truth; the other markers' corner errors beside the
unmoved survey's (the baseline, measured in the same run). Marker 15 is in view at the loop's
start and end; most markers are in view during one stretch of the loop only, so a move between
two of their views cannot be seen (the run prints how many views it had on each side).

With ``--resolution`` or ``--fps`` (e.g. ``--resolution 960x540 --fps 3``, the size
tests/test_sim_survey.py renders): the surveys at that size and rate, rendered as the test does
(no calibration recordings, eyes at 10 Hz); with --frames above the video's frame count, every frame.

With ``--rough N`` (e.g. ``--resolution 960x540 --fps 3 --rough 8``): the survey rendered with N
board views too, the camera calibrated from them (``calibrate_camera_views``, as
``calibrate-camera``), its error against the true K printed, and the map built three ways: true
intrinsics as they are, the rough ones as they are (``refine=False``), the rough ones refined with
the map (the default); corner errors and flags of each (docs/tracking.md, "Building a map").

Each survey is rendered once into --work (``survey-SEED-SECONDS``, ``...-movedID``) and reused;
delete a folder there to render it again.

Targets (issue 16): corners median <= 1.5 mm and max <= 5 mm after the origin marker's transform;
<= 60 s for a 60 s 720p survey on one core; targets with the built map within 1.2x the errors
with the true map.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np

from tracking.mapbuild import similarity_errors
from wearable_gaze.formats.markermap import load_marker_map
from wearable_gaze.pipeline.maps.markers import build_map_files
from wearable_gaze.sim.simulate import simulate_scenario

MOVED_SHIFT_MM = [150.0, 0.0, 0.0]
"""--moved: the move, in the marker's frame (150 mm to its right along its wall)."""


def survey_tag(seed: int, seconds: float, moved: int | None = None, camera=None) -> str:
    """The name of a survey's folder in --work (``survey-TAG``) and of its built map."""
    size = f"-{camera['resolution'][0]}x{camera['resolution'][1]}-{camera['fps']:g}fps" if camera else ""
    return f"{seed}-{seconds:g}{size}" + (f"-moved{moved}" if moved is not None else "")


def survey_map(work: Path, seed: int, seconds: float, frames: int, moved: int | None = None, camera=None,
               board_views: int = 0, camera_path=None, refine: bool = True, name: str = ""):
    """(true map, built map, BuiltMap, seconds to build) of the survey of seed ``seed``;
    ``moved``: the marker moved ``MOVED_SHIFT_MM`` halfway through it; ``camera``: the scene
    camera's {"resolution": [w, h], "fps": f} when not the scenario's (rendered as the tests do),
    with ``board_views`` board views; ``camera_path``: the calibration to map with (default the
    true one), ``refine`` its refinement; ``name``: told apart in the built map's file name."""
    tag = survey_tag(seed, seconds, moved, camera) + (f"-board{board_views}" if board_views else "")
    root = work / f"survey-{tag}"
    scn = {"base": "survey", "duration_s": seconds}
    if camera:
        scn.update({"camera": camera, "eyes": {"rate_hz": 10.0},
                    "calibration": {"eye": False, "camera_views": board_views}})
    if moved is not None:
        scn["moved_marker"] = {"id": moved, "at_s": seconds / 2, "shift_mm": MOVED_SHIFT_MM}
    if not (root / "session.json").is_file():
        t0 = time.perf_counter()
        simulate_scenario(scn, root, seed=seed)
        print(f"simulated {root} in {time.perf_counter() - t0:.0f} s")
    true_map = load_marker_map(root / "markers.json")
    out = work / f"built-{tag}-{frames}{name}.json"
    t0 = time.perf_counter()
    built = build_map_files([root / "scene.mp4"], camera_path or root / "truth" / "camera.json", out,
                            true_map.dictionary, true_map.marker_size_mm, max_frames=frames, refine=refine)
    return true_map, out, built, time.perf_counter() - t0


def walkabout_errors(work: Path, seed: int, built_path: Path) -> tuple[list, list]:
    """Target errors (mm) of lab-walkabout ``seed`` processed with its true map and with the built
    one (the built world moved into the true one by the origin marker's pose)."""
    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.pipeline.report.truth_match import match_targets

    root = work / f"walkabout-{seed}"
    if not (root / "session.json").is_file():
        simulate_scenario({"base": "lab-walkabout"}, root, seed=seed)
    true_map, built = load_marker_map(root / "markers.json"), load_marker_map(built_path)
    other = work / f"walkabout-{seed}-built"
    if not other.is_dir():
        def link(a, b):                                                 # the video and all: linked, not copied
            Path(b).hardlink_to(a)
        shutil.copytree(root, other, ignore=shutil.ignore_patterns("processed", "markers.json"), copy_function=link)
        shutil.copyfile(built_path, other / "markers.json")
    o = next(i for i in built.poses if np.allclose(built.poses[i], np.eye(4)))
    T = true_map.poses[o]                                               # built world -> true world
    truth = [t for t in json.loads((root / "truth" / "targets.json").read_text())["targets"]
             if sum(b - a for a, b in t["fixations_s"]) >= 1.0]
    out = []
    for sess, M in ((root, np.eye(4)), (other, T)):
        res = process_session(sess, sess / "processed", report=False)
        found = [{"target": t.index, "position_mm": (M @ [*t.position_mm, 1.0])[:3].tolist()} for t in res.found]
        out.append([float(np.linalg.norm(np.subtract(f["position_mm"], tt["position_mm"])))
                    if f is not None else float("nan") for tt, f in match_targets(found, truth)])
    return out[0], out[1]


def corner_errors(true_map, got, ids) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Corner errors (mm) of markers ``ids`` of the built map ``got`` against ``true_map``: after
    the transform fixed by the origin marker (its pose in both maps), and after the best
    similarity; the similarity's scale and the origin marker."""
    origin = min(ids, key=lambda i: np.linalg.norm(got.poses[i][:3, 3]))        # the one at the world origin
    T = true_map.poses[origin] @ np.linalg.inv(got.poses[origin])                  # built world -> true world
    A = np.concatenate([got.corners(i) for i in ids])
    B = np.concatenate([true_map.corners(i) for i in ids])
    e_sim, scale = similarity_errors(A, B)
    return np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1), e_sim, scale, origin


def moved_survey(args, unmoved: tuple, unmoved_rms: float) -> None:
    """--moved: the survey with marker ``args.moved`` moved halfway, beside the unmoved one (its
    corner errors ``unmoved``, its reprojection RMS, px)."""
    from tracking.mapadjust import fit_marker  # the builder's own fit, for the pose before
    from tracking.markermap import marker_corners_world
    from tracking.markers import MarkerDetector, split_repeated
    from wearable_gaze.formats.camera import load_camera
    from wearable_gaze.formats.truth import read_truth_moved_markers
    from wearable_gaze.pipeline.steps.calibrate import read_frames

    i = args.moved
    true_map, out, built, dt = survey_map(args.work, args.seed, args.seconds, args.frames, i, args.camera)
    root = args.work / f"survey-{survey_tag(args.seed, args.seconds, i, args.camera)}"
    (mv,) = read_truth_moved_markers(root / "truth" / "moved_markers.json")
    got = load_marker_map(out)
    others = sorted(set(got.poses) & set(true_map.poses) - {i})
    e_origin, e_sim, scale, origin = corner_errors(true_map, got, others)
    u_origin, u_sim = unmoved
    # which of the views the map used saw the marker before and after the move (frame times)
    n_video = len(np.loadtxt(root / "scene_timestamps.csv", delimiter=",", skiprows=1, ndmin=2))
    fps = json.loads((root / "session.json").read_text())["fps"]
    det = MarkerDetector(true_map.dictionary)
    cam = load_camera(root / "truth" / "camera.json")
    views, t_view = [], []
    for name, gray in read_frames([root / "scene.mp4"], args.frames):
        views.append(split_repeated(det.detect(gray))[0])
        t_view.append(int(name.rsplit("#", 1)[1]) / fps)
    before = [k for k, v in enumerate(views) if i in v and t_view[k] < mv["at_s"]]
    after = [k for k, v in enumerate(views) if i in v and t_view[k] >= mv["at_s"]]
    flagged = {j: inf.flags for j, inf in built.info.items() if inf.flags}
    moved_flag = [f for f in flagged.get(i, []) if f.startswith("moved")]
    print(f"\nmoved survey: marker {i} moved {MOVED_SHIFT_MM} mm (its frame) at {mv['at_s']:g} s; in {len(before)} "
          f"of the {len(views)} frames used before the move and {len(after)} after ({n_video} in the video); "
          f"{len(built.cameras)} views posed, RMS {built.rms_px:.3f} px after the splits ({built.rms_unsplit_px:.3f} "
          f"before; unmoved survey {unmoved_rms:.3f}), flagged {flagged}")
    print(f"marker {i} flagged as moved: {'yes: ' + moved_flag[0] if moved_flag else 'NO'}; "
          f"other markers flagged: {sorted(j for j in flagged if j != i) or 'none'}")
    A = np.concatenate([got.corners(j) for j in others])
    B = np.concatenate([true_map.corners(j) for j in others])
    e_after, _ = similarity_errors(np.concatenate([A, got.corners(i)]), np.concatenate([B, mv["corners_after_mm"]]))
    cams = {k: np.linalg.inv(T) for k, T in built.cameras.items()}
    keys = [k for k in before if k in cams]
    obs = [{j: cam.undistort_points(c) for j, c in v.items()} for v in views]
    side = got.size_of(i)
    if len(keys) >= 1:
        T_before = fit_marker(obs, side, i, got.poses[i], cams, keys)[0]
        e_before, _ = similarity_errors(np.concatenate([A, marker_corners_world(side, T_before)]),
                                        np.concatenate([B, mv["corners_before_mm"]]))
        before_txt = f"max {e_before[-4:].max():.2f} mm (fitted to the {len(keys)} posed views before the move)"
    else:
        before_txt = "no posed view before the move"
    print(f"marker {i}'s corners after the best similarity of all: after the move (the map's pose) max "
          f"{e_after[-4:].max():.2f} mm; before it {before_txt}")
    print(f"the other {len(others)} markers, after the origin marker's transform (marker {origin}): median "
          f"{np.median(e_origin):.2f} mm, max {e_origin.max():.2f} mm (unmoved survey: {np.median(u_origin):.2f}, "
          f"{u_origin.max():.2f})")
    print(f"the other {len(others)} markers, after the best similarity: median {np.median(e_sim):.2f} mm, max "
          f"{e_sim.max():.2f} mm, scale {scale:.5f} (unmoved survey: {np.median(u_sim):.2f}, {u_sim.max():.2f}; "
          f"ratio of medians {np.median(e_sim) / np.median(u_sim):.2f})")
    print(f"time: {dt:.1f} s for {args.frames} frames on one core")


def rough_survey(args) -> None:
    """--rough N: the survey calibrated from its own N board views, mapped with the true intrinsics,
    the rough ones as they are and the rough ones refined (docs/tracking.md, "Building a map")."""
    from wearable_gaze.formats.board import read_board
    from wearable_gaze.formats.camera import (
        load_camera,
        write_camera,
    )
    from wearable_gaze.formats.images import read_gray_image
    from wearable_gaze.pipeline.steps.calibrate import calibrate_camera_views, camera_json

    n = args.rough
    true_map, _, _, _ = survey_map(args.work, args.seed, args.seconds, args.frames, camera=args.camera,
                                   board_views=n, refine=False, name="-true")
    root = args.work / f"survey-{survey_tag(args.seed, args.seconds, None, args.camera)}-board{n}"
    rec = read_board(root / "calibration" / "camera")
    cal = calibrate_camera_views(((f.name, read_gray_image(f)) for f in rec.views), rec.spec).calibration
    rough = args.work / f"rough-{n}-views-{survey_tag(args.seed, args.seconds, None, args.camera)}.json"
    write_camera(rough, camera_json(cal))
    K, Kt = cal.camera_matrix, load_camera(root / "truth" / "camera.json").camera_matrix
    print(f"\n{n}-view calibration ({sum(v['used'] for v in cal.views)} views used, RMS {cal.rms_px:.3f} px): "
          f"fx {K[0, 0] - Kt[0, 0]:+.2f}, fy {K[1, 1] - Kt[1, 1]:+.2f}, cx {K[0, 2] - Kt[0, 2]:+.2f}, "
          f"cy {K[1, 2] - Kt[1, 2]:+.2f} px off the true K; dist {np.round(cal.dist_coeffs, 4).tolist()}")
    for label, path, refine in (("true intrinsics, as they are", None, False),
                                (f"rough {n}-view intrinsics, as they are", rough, False),
                                (f"rough {n}-view intrinsics, refined", rough, True)):
        _, out, built, dt = survey_map(args.work, args.seed, args.seconds, args.frames, camera=args.camera,
                                       board_views=n, camera_path=path, refine=refine,
                                       name=f"-{'true' if path is None else 'rough'}{'-refined' if refine else ''}")
        got = load_marker_map(out)
        common = sorted(set(got.poses) & set(true_map.poses))
        e_origin, e_sim, scale, origin = corner_errors(true_map, got, common)
        flagged = {i: inf.flags for i, inf in built.info.items() if inf.flags}
        intr = built.intrinsics
        K1 = intr.camera_matrix
        print(f"{label}: corners after the best similarity median {np.median(e_sim):.2f} mm, max {e_sim.max():.2f} mm;"
              f" after the origin marker's transform {np.median(e_origin):.2f} / {e_origin.max():.2f} mm; RMS "
              f"{built.rms_px:.3f} px; flagged {flagged or 'none'}; {dt:.1f} s")
        print(f"    intrinsics used: fx {K1[0, 0] - Kt[0, 0]:+.2f}, fy {K1[1, 1] - Kt[1, 1]:+.2f}, cx "
              f"{K1[0, 2] - Kt[0, 2]:+.2f}, cy {K1[1, 2] - Kt[1, 2]:+.2f} px off the true K"
              + ("" if intr.refined else f" (not refined: {intr.reason})"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="survey length (default 60)")
    ap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ap.add_argument("--frames", type=int, default=300, help="frames used, evenly spaced (default 300)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/wg-bench-map"), help="folder kept between runs")
    ap.add_argument("--walkabout", type=int, default=0, help="lab-walkabout sessions processed with each map")
    ap.add_argument("--moved", type=int, nargs="?", const=15, default=None, metavar="ID",
                    help="also the survey with marker ID (default 15) moved halfway through")
    ap.add_argument("--resolution", type=str, default=None, metavar="WxH", help="scene camera size (default 1280x720)")
    ap.add_argument("--fps", type=float, default=None, help="scene camera rate (default 30)")
    ap.add_argument("--rough", type=int, default=None, metavar="N",
                    help="also: the survey calibrated from N board views of its own, mapped with and without "
                         "refining the intrinsics (needs --resolution or --fps)")
    args = ap.parse_args()
    args.camera = None
    if args.resolution or args.fps:
        w, h = (int(v) for v in (args.resolution or "1280x720").lower().split("x"))
        args.camera = {"resolution": [w, h], "fps": args.fps or 30.0}
    if args.rough is not None:
        if args.camera is None:
            ap.error("--rough needs --resolution or --fps (the surveys rendered as the tests render them)")
        rough_survey(args)
        return
    true_map, out, built, dt = survey_map(args.work, args.seed, args.seconds, args.frames, camera=args.camera)
    got = load_marker_map(out)
    common = sorted(set(got.poses) & set(true_map.poses))
    e_origin, e_sim, scale, origin = corner_errors(true_map, got, common)
    flagged = {i: inf.flags for i, inf in built.info.items() if inf.flags}
    print(f"survey {args.seconds:g} s, seed {args.seed}: {len(common)} of {len(true_map.poses)} markers from "
          f"{len(built.cameras)} views ({len(built.unposed)} unposed), RMS {built.rms_px:.2f} px, flagged {flagged}")
    print(f"corners after the origin marker's transform (marker {origin}): median {np.median(e_origin):.2f} mm, "
          f"max {e_origin.max():.2f} mm (targets <= 1.5, <= 5)")
    print(f"corners after the best similarity: median {np.median(e_sim):.2f} mm, max {e_sim.max():.2f} mm, "
          f"scale {scale:.5f}")
    print(f"time: {dt:.1f} s for {args.frames} frames on one core (target <= 60 s)")
    if args.moved is not None:
        others = [j for j in common if j != args.moved]
        moved_survey(args, corner_errors(true_map, got, others)[:2], built.rms_px)
    all_true, all_built = [], []
    for seed in range(args.seed, args.seed + args.walkabout):
        path = out if seed == args.seed else survey_map(args.work, seed, args.seconds, args.frames)[1]
        e_true, e_built = walkabout_errors(args.work, seed, path)
        all_true += e_true
        all_built += e_built
        print(f"lab-walkabout seed {seed}: target errors, true map {np.round(e_true, 1).tolist()} mm, built map "
              f"{np.round(e_built, 1).tolist()} mm")
    if all_true:
        ratio = np.nanmedian(all_built) / np.nanmedian(all_true)
        print(f"median target error: true map {np.nanmedian(all_true):.1f} mm, built map "
              f"{np.nanmedian(all_built):.1f} mm, ratio {ratio:.2f} (target <= 1.2); mean "
              f"{np.nanmean(all_true):.1f} / {np.nanmean(all_built):.1f} mm")


if __name__ == "__main__":
    main()
