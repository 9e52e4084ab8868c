"""``wearable-gaze map --markerless``: a map of a textured room from a survey video, without
markers (issue 16; docs/tracking.md, "A map without markers").

Evenly spaced frames of the video get the features ``tracking.localise`` uses for every frame
(SIFT at half size, RootSIFT); pycolmap matches them (every pair, geometrically verified) and
reconstructs the views and 3D points (incremental mapping with bundle adjustment, the camera's
intrinsics held fixed). The reconstruction's arbitrary scale and frame are then fixed by markers
seen in the frames: one marker of known side (the world is its frame), or the markers of a map
(the world is that map's, fitted by all of them or by the one ``origin`` names). The result
(``formats.sfmmap``) carries each 3D point with the descriptors of the views that saw it, for
``track --map`` and ``process --map`` to localise frames against.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.camera import CameraCalibration, aruco_dictionary
from estimator.frames import similarity_transform
from tracking.localise import (
    FEATURE_SCALE,
    MAX_FEATURES,
    FeatureLocalizer,
    FeatureMap,
    colmap_descriptors,
    image_features,
    triangulate,
)
from tracking.markermap import MarkerMap, square_corners
from tracking.markers import MarkerDetector, unique_by_id

from ...errors import UserError
from ...formats.atomic import atomic_folder
from ...formats.camera import load_camera
from ...formats.images import IMAGE_EXT, write_image
from ...formats.markermap import load_marker_map
from ...formats.sfmmap import write_sfm_map
from ...formats.video import gray_frames_at, video_fps
from ...progress import staged
from ..steps.calibrate import check_frame_size, input_files, read_frames
from .markers import DEFAULT_DICT, frames_total

log = logging.getLogger(__name__)

MIN_MARKER_VIEWS = 3
"""A marker is used for the scale only when seen in at least this many reconstructed views."""
DESCRIPTORS_PER_POINT = 4
"""Each 3D point keeps the descriptors of at most this many of its views, spread along its track
(the survey sees a point from up to dozens of nearly equal views; all of them would triple the
matching time a frame for no more matches)."""


@dataclass
class SfmBuild:
    """What ``build_sfm_files`` made: the map, views selected and registered, the reprojection RMS
    (px), how the world was fixed (``scaled_by``: kind, markers, their corners' residual after the
    fit, mm), the survey's camera poses {frame name ('VIDEO#FRAME' or the image's): T_world_from_cam}."""

    feature_map: FeatureMap
    selected: int
    registered: int
    rms_px: float
    scaled_by: dict
    cameras: dict


def build_sfm_files(inputs, camera_path, out_dir, max_frames: int = 150, dictionary: str | None = None,
                    size_mm: float | None = None, origin: int | None = None, markers=None,
                    progress=None, distance: tuple | None = None) -> SfmBuild:
    """Reconstruct the room of ``inputs`` (videos, images, folders of images; at most
    ``max_frames`` evenly spaced frames of each video) seen by the camera of ``camera_path``, and
    write the map folder ``out_dir`` (docs/formats.md, "Markerless map"; built beside it and
    renamed when complete). The world: marker ``origin``'s frame, its printed side ``size_mm``
    (markers of ``dictionary``, default ``DEFAULT_DICT``); or with ``markers`` (a marker map), that map's world, fitted
    to all its markers seen or to ``origin`` alone; or, without markers, ``distance`` (t_a s,
    t_b s, mm): the camera moved that far between those two times of the (one) video, and the
    world is the camera's frame at t_a. ``progress(done, total)``: over the frames (their
    features), then (0, 0) while pycolmap matches them (one call), then over the views registered;
    a ``progress_bar``'s callback also names each stage.

    Raises:
        UserError: unreadable inputs, images of another size than the camera's, no way to fix the
            scale, a reconstruction that fails, too few views of the markers that fix the world.
    """
    cam = load_camera(Path(camera_path))
    marker_map = load_marker_map(Path(markers)) if markers is not None else None
    if (distance is not None) == (marker_map is not None or origin is not None) or (
            distance is None and marker_map is None and size_mm is None):
        raise UserError("map --markerless: fix the scale and the world with one of --origin-marker ID --size-mm MM "
                        "(a marker in view), --markers MAP.json (the room's marker map) or --distance T1,T2,MM")
    files = input_files(inputs)
    if distance is not None and (len(files) != 1 or files[0].suffix.lower() in IMAGE_EXT):
        raise UserError("map --markerless --distance: give one survey video (the times are in it)")
    dictionary = marker_map.dictionary if marker_map is not None else (dictionary or DEFAULT_DICT)
    try:
        aruco_dictionary(dictionary)
    except ValueError as exc:
        raise UserError(f"--dict: {exc}") from None
    with atomic_folder(out_dir) as tmp:
        frames = _frames(files, cam, MarkerDetector(dictionary), max_frames, tmp / "images",
                         staged(progress, "features"))
        rec = _reconstruct(tmp, cam, frames, progress)
        if progress:
            staged(progress, "placing and writing the map")(0, 0)
        in_sfm = _feature_map(rec, frames)
        if distance is not None:
            T_world_from_sfm, scaled_by = _world_by_distance(in_sfm, cam, files[0], *distance)
        else:
            T_world_from_sfm, scaled_by = _world(rec, frames, cam, marker_map, origin, size_mm)
        fmap = FeatureMap(in_sfm.points_world @ T_world_from_sfm[:3, :3].T + T_world_from_sfm[:3, 3],   # a similarity
                          in_sfm.descriptors, in_sfm.point_of)
        cameras = {frames["names"][k]: T for k, T in _cameras(rec, T_world_from_sfm).items()}
        (tmp / "colmap").mkdir()
        rec.write(str(tmp / "colmap"))
        rms = float(rec.compute_mean_reprojection_error())
        build = SfmBuild(fmap, len(frames["names"]), len(cameras), rms, scaled_by, cameras)
        write_sfm_map(tmp, fmap, _meta(build, cam, T_world_from_sfm))
        write_sfm_plot(build, tmp / "sfm_top_view.png")
        shutil.rmtree(tmp / "images")
        (tmp / "database.db").unlink()
    return build


def _frames(files, cam: CameraCalibration, detector: MarkerDetector, max_frames: int, folder: Path, progress) -> dict:
    """The selected frames of ``files``: names, features (positions px, descriptors), markers
    {id: corners px}; each written to ``folder`` as NNNNN.jpg for pycolmap (which reads their
    sizes)."""
    folder.mkdir()
    total = frames_total(files, max_frames)
    out: dict[str, list] = {"names": [], "features": [], "markers": []}
    for k, (name, gray) in enumerate(read_frames(files, max_frames, "the room")):
        check_frame_size(name, gray, cam)
        write_image(folder / f"{k:05d}.jpg", gray)
        out["names"].append(name)
        out["features"].append(image_features(gray))
        out["markers"].append(unique_by_id(detector.detect(gray)))
        if progress:
            progress(k + 1, max(k + 1, total))
    if len(out["names"]) < 3:
        raise UserError(f"{len(out['names'])} frame(s) in the inputs; a markerless map needs a survey video (or "
                        "photos) with many views of the room")
    return out


def _reconstruct(tmp: Path, cam: CameraCalibration, frames: dict, progress):
    """pycolmap's largest reconstruction of the frames, in its own frame and scale. The
    keypoints are undistorted onto a pinhole camera of the calibration's K (COLMAP's pixel
    centres are at +0.5)."""
    import pycolmap

    if not log.isEnabledFor(logging.DEBUG):                # COLMAP's own log lines: with -vv only
        pycolmap.logging.minloglevel = 2                   # glog's ERROR
    db_path, images = tmp / "database.db", tmp / "images"
    K = cam.camera_matrix
    opts = pycolmap.ImageReaderOptions()
    opts.camera_model = "PINHOLE"
    opts.camera_params = ",".join(f"{v:.10g}" for v in (K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5))
    pycolmap.Database.open(str(db_path)).close()
    pycolmap.import_images(str(db_path), str(images), pycolmap.CameraMode.SINGLE, options=opts)
    with contextlib.closing(pycolmap.Database.open(str(db_path))) as db:
        for im in db.read_all_images():
            xy, desc = frames["features"][int(Path(im.name).stem)]
            uv = cam.undistort_points(xy) * K[[0, 1], [0, 1]] + K[:2, 2] + 0.5 if len(xy) else np.zeros((0, 2))
            db.write_keypoints(im.image_id, uv.astype(np.float32))
            db.write_descriptors(im.image_id, pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT,
                                                                          colmap_descriptors(desc)))
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads, mo.use_gpu = 1, False
    n, done, matching, mapping = len(frames["names"]), [0], staged(progress, "matching"), staged(progress, "mapping")
    if progress:
        matching(0, 0)                                    # one call of unknown length: the bar's clock runs
    pycolmap.match_exhaustive(str(db_path), matching_options=mo, device=pycolmap.Device.cpu)
    po = pycolmap.IncrementalPipelineOptions()
    po.num_threads, po.extract_colors, po.random_seed = 1, False, 0
    po.ba_refine_focal_length = po.ba_refine_principal_point = po.ba_refine_extra_params = False

    def registered(views: int = 1):
        done[0] += views
        if progress:
            mapping(min(done[0], n), n)
    registered(0)
    (tmp / "sparse").mkdir()
    recs = pycolmap.incremental_mapping(str(db_path), str(images), str(tmp / "sparse"), options=po,
                                        initial_image_pair_callback=lambda: registered(2),
                                        next_image_callback=registered)
    shutil.rmtree(tmp / "sparse")
    if not recs:
        raise UserError(f"no reconstruction from the {n} frames: the room's surfaces may lack texture, or the "
                        "views overlap too little; survey slowly, facing textured walls, with more --max-frames")
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    log.info("reconstruction: %d of %d views, %d points", rec.num_reg_images(), n, rec.num_points3D())
    return rec


def _T_cam_from_sfm(image) -> np.ndarray:
    T = np.eye(4)
    T[:3] = image.cam_from_world().matrix()
    return T


def _world(rec, frames: dict, cam: CameraCalibration, marker_map: MarkerMap | None, origin, size_mm
           ) -> tuple[np.ndarray, dict]:
    """``T_world_from_sfm`` (a similarity) and how it was found, from the markers' corners
    triangulated in the reconstruction and their places in the world."""
    views: dict[int, list] = {}
    for im in rec.images.values():
        k = int(Path(im.name).stem)
        for i, c in frames["markers"][k].items():
            views.setdefault(i, []).append((_T_cam_from_sfm(im), cam.undistort_points(c)))
    if marker_map is not None:
        ids = [origin] if origin is not None else sorted(set(views) & set(marker_map.poses))
        world = {i: marker_map.corners(i) for i in ids if i in marker_map.poses}
        kind = "marker_map"
    else:
        ids, world, kind = [origin], {origin: square_corners(size_mm)}, "marker"
    used = [i for i in ids if i in world and len(views.get(i, ())) >= MIN_MARKER_VIEWS]
    if not used:
        which = f"marker {origin}" if origin is not None else "no marker of the map"
        raise UserError(f"{which} is in at least {MIN_MARKER_VIEWS} reconstructed views, so the map's scale and "
                        "world cannot be fixed; survey past the marker, or name one seen (--origin-marker)")
    A = np.vstack([[triangulate([v[0] for v in views[i]], [v[1][j] for v in views[i]]) for j in range(4)]
                   for i in used])
    B = np.vstack([world[i] for i in used])
    T = similarity_transform(A, B)
    res = np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1)
    return T, {"kind": kind, "markers": [int(i) for i in used], "views": {str(i): len(views[i]) for i in used},
               "residual_mm": round(float(np.sqrt(np.mean(res**2))), 3),
               "corners_mm": {str(i): np.round(world[i], 6).tolist() for i in used},   # where the world has them
               **({"size_mm": float(size_mm)} if kind == "marker" else {})}


def _world_by_distance(in_sfm: FeatureMap, cam: CameraCalibration, video: Path, t_a: float, t_b: float, mm: float
                       ) -> tuple[np.ndarray, dict]:
    """``T_world_from_sfm`` from a distance: the video's frames at ``t_a`` and ``t_b`` s (index =
    round(t * fps)) localised in the unscaled reconstruction (``in_sfm``), their camera centres
    ``mm`` apart; the world is the camera's frame at ``t_a`` (x right, y down, z forward), mm."""
    fps = video_fps(video)
    idx = [int(round(t * fps)) for t in (t_a, t_b)]
    gray = gray_frames_at(video, idx)
    localizer = FeatureLocalizer(in_sfm, cam, scale=FEATURE_SCALE)
    poses = []
    for t, i in zip((t_a, t_b), idx, strict=True):
        if i not in gray:
            raise UserError(f"--distance: {video} has no frame at {t:g} s; give times within the video")
        res = localizer.estimate(gray[i])
        if not res.ok or res.T_world_from_cam is None:          # (ok: never None)
            raise UserError(f"--distance: the frame at {t:g} s could not be placed in the reconstruction "
                            f"({res.reason}); choose times when the camera faced the surveyed walls")
        poses.append(res.T_world_from_cam)
    d = float(np.linalg.norm(poses[1][:3, 3] - poses[0][:3, 3]))
    if d < 1e-6:
        raise UserError(f"--distance: the camera did not move between {t_a:g} s and {t_b:g} s; give two times "
                        "between which it moved the distance given")
    T = np.diag([mm / d] * 3 + [1.0]) @ np.linalg.inv(poses[0])
    return T, {"kind": "distance", "markers": [], "times_s": [float(t_a), float(t_b)], "distance_mm": float(mm),
               "residual_mm": 0.0}


def _feature_map(rec, frames: dict) -> FeatureMap:
    """The 3D points (the reconstruction's frame and unit) with the descriptors of up to
    ``DESCRIPTORS_PER_POINT`` views of each."""
    pts, desc, owner = [], [], []
    for p, (pid, point) in enumerate(sorted(rec.points3D.items())):
        del pid
        pts.append(point.xyz)
        els = sorted(point.track.elements, key=lambda e: e.image_id)
        for j in np.unique(np.linspace(0, len(els) - 1, DESCRIPTORS_PER_POINT).round().astype(int)):
            k = int(Path(rec.images[els[j].image_id].name).stem)
            desc.append(frames["features"][k][1][els[j].point2D_idx])
            owner.append(p)
    return FeatureMap(np.asarray(pts, float), np.asarray(desc, np.float32), np.asarray(owner, np.int64))


def _cameras(rec, T_world_from_sfm) -> dict:
    """{frame number: T_world_from_cam (4, 4) with a rigid rotation, mm} of the registered views."""
    s = float(np.cbrt(np.linalg.det(T_world_from_sfm[:3, :3])))
    out = {}
    for im in rec.images.values():
        T = T_world_from_sfm @ np.linalg.inv(_T_cam_from_sfm(im))
        T[:3, :3] /= s
        out[int(Path(im.name).stem)] = T
    return dict(sorted(out.items()))


def _meta(build: SfmBuild, cam: CameraCalibration, T_world_from_sfm) -> dict:
    """The JSON fields of the map (formats.sfmmap) besides format and version."""
    kind = build.scaled_by["kind"]
    world = (f"marker {build.scaled_by['markers'][0]}'s frame" if kind == "marker" else
             f"the marker map's world (fitted to markers {build.scaled_by['markers']})" if kind == "marker_map" else
             f"the camera's frame at {build.scaled_by['times_s'][0]:g} s of the survey video")
    return {"world": world, "T_world_from_sfm": np.round(T_world_from_sfm, 9).tolist(), "scaled_by": build.scaled_by,
            "camera": {"camera_matrix": cam.camera_matrix.tolist(), "image_size": list(cam.image_size)},
            "features": {"type": "rootsift", "scale": FEATURE_SCALE, "max_features": MAX_FEATURES},
            "views": {"selected": build.selected, "registered": build.registered},
            "points": len(build.feature_map.points_world), "reprojection_rms_px": round(build.rms_px, 4),
            "survey": [{"name": name, "T_world_from_cam": np.round(T, 6).tolist()}
                       for name, T in build.cameras.items()]}


def write_sfm_plot(build: SfmBuild, path: Path) -> None:
    """A top view (world x, z) of the map's points and the survey's camera path."""
    from ..report.page import _plt, _save  # matplotlib only when plotting

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6))
    P = build.feature_map.points_world
    ax.plot(P[:, 0], P[:, 2], ",", color="#1f77b4", alpha=0.5, label=f"{len(P)} points")
    c = np.array([T[:3, 3] for T in build.cameras.values()])
    ax.plot(c[:, 0], c[:, 2], "-", color="#d62728", lw=0.8, label="survey path (registered views)")
    ax.set_aspect("equal")
    ax.set_xlabel("x, mm (world)")
    ax.set_ylabel("z, mm")
    ax.legend(loc="best", fontsize=8, markerscale=10)
    ax.set_title(f"markerless map, top view: {build.registered} of {build.selected} views, "
                 f"RMS {build.rms_px:.2f} px, scale fixed by {build.scaled_by['kind']} "
                 f"{build.scaled_by['markers'] or build.scaled_by.get('distance_mm')}", fontsize=9)
    _save(fig, path)


LOOSE_PLACEMENT_MM = 5.0
"""A markerless map placed by several markers whose triangulated corners fit their places worse
than this (RMS, mm) is said to be placed loosely: the head poses it gives are meant to be within
15 mm, and a misplaced world moves every one of them (the 60 s simulated survey's marker 0 fits
to 0.3 mm; a 12 s survey's 40 frames fitted its markers to 21.8 mm)."""


def format_sfm_report(build: SfmBuild) -> list[str]:
    """Lines for the terminal."""
    s = build.scaled_by
    lines = [f"{len(build.feature_map.points_world)} points from {build.registered} of {build.selected} views, "
             f"reprojection RMS {build.rms_px:.2f} px",
             (f"world and scale from markers {s['markers']} ({s['kind']}): corners fit to {s['residual_mm']:.1f} mm RMS"
              if s["kind"] != "distance" else f"scale from {s['distance_mm']:g} mm between {s['times_s'][0]:g} s and "
              f"{s['times_s'][1]:g} s; the world is the camera's frame at {s['times_s'][0]:g} s")]
    if s["kind"] != "distance" and len(s["markers"]) > 1 and s["residual_mm"] > LOOSE_PLACEMENT_MM:
        lines.append(f"  the markers' corners fit their places loosely ({s['residual_mm']:.1f} mm RMS): the "
                     "reconstruction is bent, or markers moved since the map; every pose will be off by about as "
                     "much. Survey longer, or place it by one marker (--origin-marker)")
    if build.registered < 0.8 * build.selected:
        lines.append(f"  only {build.registered} of {build.selected} views were placed: frames of the session far "
                     "from the survey's may not localise")
    return lines
