"""``wearable-gaze map``: a marker map built from a survey video or photos of the room's markers
(issue 16; docs/tracking.md, "Building a map"). Reads the inputs and the camera, detects the
markers, calls ``tracking.mapbuild.build_marker_map`` and writes the map with each marker's
views, residual, covariance and flags."""

from __future__ import annotations

import itertools
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibration.camera import aruco_dictionary
from tracking.mapbuild import BuiltMap, build_marker_map
from tracking.markers import MarkerDetector, split_repeated

from ...errors import UserError
from ...formats.camera import load_camera
from ...formats.images import IMAGE_EXT
from ...formats.markermap import load_marker_map, marker_map_dict, read_map_intrinsics, write_marker_map
from ...progress import staged
from ..steps.calibrate import check_frame_size, input_files, read_frames
from ..steps.track import no_marker_error

log = logging.getLogger(__name__)

DEFAULT_DICT = "DICT_4X4_50"


def parse_sizes(text: str | None) -> dict:
    """``ID=MM,ID=MM,...`` -> {id: mm} (empty for None).

    Raises:
        UserError: a malformed entry or a size that is not a positive number of millimetres.
    """
    out = {}
    for part in (text or "").split(","):
        if not part.strip():
            continue
        try:
            k, v = part.split("=")
            out[int(k)] = float(v)
        except ValueError:
            raise UserError(f"--sizes: {part.strip()!r} is not ID=MM; write e.g. --sizes 0=150,7=80") from None
        if not out[int(k)] > 0:
            raise UserError(f"--sizes: marker {k} has size {v}; sizes are positive millimetres")
    return out


def build_map_files(inputs, camera_path, out, dictionary: str | None = None, size_mm: float | None = None,
                    sizes=None, origin: int | None = None, max_frames: int = 300, progress=None,
                    extend=None, refine: bool = True) -> BuiltMap:
    """Build and write the marker map of ``inputs`` (and its top view beside it, ``map_plot_path``)
    (images, folders of images, videos: at most
    ``max_frames`` evenly spaced frames of each) seen by the camera of ``camera_path`` (our JSON
    or an OpenCV YAML/XML calibration), markers of ``dictionary`` printed ``size_mm`` wide or
    as ``sizes`` {id: mm} says (which wins), the world fixed by marker ``origin``. ``extend``: an
    earlier map to extend or refine (its world, markers, dictionary and size, unless given).
    ``progress(done, total)``: over the frames read, then over the bundle adjustments' steps
    (``tracking.mapbuild.build_marker_map``). ``refine``: refine the camera's intrinsics from the
    survey when it can (``tracking.mapintrinsics``; the map's ``camera_intrinsics`` says what was
    done). An ``extend`` map built with this calibration and refined gives its refined intrinsics
    as the start (``start_intrinsics``).

    Raises:
        UserError: unreadable inputs, an unknown dictionary, images of another size than the
            camera's, no marker seen, a seen id without a size, the origin never seen.
    """
    prior, dictionary, size_mm, sizes = _with_prior(extend, dictionary, size_mm, sizes)
    cam = load_camera(Path(camera_path))
    files = input_files(inputs)
    detecting, adjusting = staged(progress, "detecting markers"), staged(progress, "adjusting the map")
    views, names, repeated = _detect_views(files, max_frames, cam, dictionary, detecting)
    seen = sorted({i for v in views for i in v})
    if views and not seen:
        source, fix = (("the --extend map", 'write "dictionary": "{}" in it') if prior is not None
                       else ("--dict", "pass --dict {}"))
        sample = [g for _, g in itertools.islice(read_frames(files, 5), 5)]       # to name the dictionary
        raise no_marker_error(dictionary, sample, "map", source, fix)
    size = {i: size_mm for i in seen if size_mm is not None}
    size.update({i: s for i, s in (sizes or {}).items() if i in seen})
    if progress:
        adjusting(0, 0)                           # chaining the views, before the first adjustment step
    try:
        K, dist, start = start_intrinsics(cam, extend if refine else None)
        built = build_marker_map(views, K, dist, dictionary, size, origin, cam.model, prior,
                                 tuple(cam.image_size), refine, adjusting)
        assert built.intrinsics is not None      # build_marker_map always says what it did
        built.intrinsics = replace(built.intrinsics, given_camera_matrix=cam.camera_matrix,
                                   given_dist_coeffs=cam.dist_coeffs, start=start)
    except ValueError as exc:
        raise UserError(f"map: {exc} (--size-mm, --sizes, --origin-marker, --dict)") from None
    for i, n in repeated.items():
        if i in built.info:
            built.info[i].flags.append(f"id detected twice in {n} view(s) (a duplicate print?)")
    extra = {i: _extra(inf) for i, inf in built.info.items()}
    write_marker_map(out, marker_map_dict(dictionary, built.marker_map.marker_size_mm, built.marker_map.poses,
                                          extra=extra, sizes=built.marker_map.sizes,
                                          camera=intrinsics_json(built.intrinsics)))
    write_map_plot(built, map_plot_path(out))
    log.info("views: %s", ", ".join(names[:5]) + (" ..." if len(names) > 5 else ""))
    return built


def _with_prior(extend, dictionary: str | None, size_mm: float | None, sizes):
    """(the map to extend or None, the dictionary, size and sizes to use): an ``extend`` map's
    own unless given (its dictionary must agree); the dictionary checked.

    Raises:
        UserError: another dictionary than the extended map's, an unknown dictionary.
    """
    prior = None
    if extend is not None:
        prior = load_marker_map(Path(extend))
        if dictionary not in (None, prior.dictionary):
            raise UserError(f"--dict {dictionary}: the map to extend, {extend}, is of "
                            f"{prior.dictionary}")
        dictionary = prior.dictionary
        size_mm = prior.marker_size_mm if size_mm is None else size_mm
        sizes = {**prior.sizes, **(sizes or {})}
    dictionary = dictionary or DEFAULT_DICT
    try:
        aruco_dictionary(dictionary)
    except ValueError as exc:
        raise UserError(f"--dict: {exc}") from None
    return prior, dictionary, size_mm, sizes


def _detect_views(files, max_frames: int, cam, dictionary: str, progress=None):
    """The markers seen in each frame read from ``files`` (at most ``max_frames`` of each): the
    views [{id: (4, 2) corners, px}], the frames' names, and {id: views it was seen twice in}
    (a repeated id is left out of that view). ``progress(done, total)`` over the frames."""
    detector = MarkerDetector(dictionary)
    total = frames_total(files, max_frames)
    views, names = [], []
    repeated: dict[int, int] = {}
    for k, (name, gray) in enumerate(read_frames(files, max_frames, "the room's markers")):
        check_frame_size(name, gray, cam)
        unique, rep, _ = split_repeated(detector.detect(gray))
        for i in rep:
            repeated[i] = repeated.get(i, 0) + 1
        views.append(unique)
        names.append(name)
        if progress:
            progress(k + 1, max(k + 1, total))
    return views, names, repeated


def start_intrinsics(cam, extend=None) -> tuple[np.ndarray, np.ndarray, str]:
    """The intrinsics a map starts from: (K (3, 3), dist, 'calibration'), the camera calibration's,
    or (..., 'extended map') the refined ones of the map ``extend`` when it was built from this
    calibration (its ``given_camera_matrix`` and ``given_dist_coeffs`` are the calibration's): a
    few new views that cannot refine them alone then keep what the earlier survey found."""
    intr = read_map_intrinsics(Path(extend)) if extend is not None else None
    if intr and intr["refined"] and intr.get("model", "pinhole") == cam.model:
        same = np.allclose(intr.get("given_camera_matrix", np.zeros((3, 3))), cam.camera_matrix, atol=1e-5) and \
            len(intr.get("given_dist_coeffs", [])) == len(cam.dist_coeffs) and \
            np.allclose(intr["given_dist_coeffs"], cam.dist_coeffs, atol=1e-8)
        if same:
            return np.asarray(intr["camera_matrix"], float), np.asarray(intr["dist_coeffs"], float), "extended map"
    return cam.camera_matrix, cam.dist_coeffs, "calibration"


def frames_total(files, max_frames: int) -> int:
    """About how many frames ``read_frames`` yields of ``files``: an image one, a video
    ``max_frames`` (fewer when it is shorter), for a progress bar's total."""
    return sum(1 if f.suffix.lower() in IMAGE_EXT else max_frames for f in files)


def map_plot_path(out) -> Path:
    """Where ``build_map_files`` puts the map's top view: beside the map, ``NAME_top_view.png``."""
    out = Path(out)
    return out.with_name(out.stem + "_top_view.png")


def write_map_plot(built: BuiltMap, path: Path) -> None:
    """A top view (world x, z; the origin marker's frame) of the built map: each marker as its
    side seen from above with its id (red: flagged), and the survey's camera path (the posed
    views' positions, in order)."""
    from ..report.page import _plt, _save  # matplotlib only when plotting

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 6))
    c = np.array([T[:3, 3] for _, T in sorted(built.cameras.items())])
    if len(c):
        ax.plot(c[:, 0], c[:, 2], "-", color="#999999", lw=0.8, label="survey path (posed views)")
        ax.plot(c[:1, 0], c[:1, 2], "o", color="#999999", ms=4)
    half = built.marker_map.marker_size_mm / 2
    for i, T in sorted(built.marker_map.poses.items()):
        ends = T[:3, 3] + np.outer([-half, half], T[:3, 0])
        bad = bool(built.info[i].flags)
        ax.plot(ends[:, 0], ends[:, 2], "-", color="#d62728" if bad else "#1f77b4", lw=3)
        ax.annotate(str(i), (T[0, 3], T[2, 3]), textcoords="offset points", xytext=(3, 3), fontsize=7,
                    color="#d62728" if bad else "black")
    ax.set_aspect("equal")
    ax.set_xlabel("x, mm (the origin marker's frame)")
    ax.set_ylabel("z, mm")
    ax.legend(loc="best", fontsize=8)
    flagged = sum(bool(inf.flags) for inf in built.info.values())
    ax.set_title(f"marker map, top view: {len(built.marker_map.poses)} markers ({flagged} flagged, red), "
                 f"RMS {built.rms_px:.2f} px", fontsize=9)
    _save(fig, path)


def _extra(info) -> dict:
    """The JSON fields of one built marker (``MarkerInfo``)."""
    return {"n_views": int(info.n_views), "rms_px": round(float(info.rms_px), 4),
            "covariance": np.round(info.covariance, 12).tolist(), "flags": list(info.flags)}


def intrinsics_json(intr) -> dict | None:
    """The map JSON's ``camera_intrinsics`` object of an ``IntrinsicsRefinement`` (docs/formats.md),
    None for none."""
    if intr is None:
        return None
    out = {"refined": bool(intr.refined), "start": intr.start, "model": intr.model, "n_views": int(intr.n_views),
           "image_cells": int(intr.cells), "camera_matrix": np.round(intr.camera_matrix, 6).tolist(),
           "dist_coeffs": np.round(intr.dist_coeffs, 9).tolist(),
           "given_camera_matrix": np.round(intr.given_camera_matrix, 6).tolist(),
           "given_dist_coeffs": np.round(intr.given_dist_coeffs, 9).tolist()}
    out["change"] = {k: round(v, 9) for k, v in intr.change().items()}
    if intr.refined:
        out["sd"] = {k: round(v, 9) for k, v in intr.sd.items()}
    else:
        out["reason"] = intr.reason
    return out


def format_intrinsics(intr) -> list[str]:
    """Lines for the terminal: the intrinsics refined (each value and its change), and whether
    the calibration's were off by more than the survey's uncertainty; or why they were not
    refined, and that the map depends on them."""
    if not intr.refined and intr.start != "calibration":
        return [f"camera intrinsics of the extended map (refined by its survey), not refined again: {intr.reason}"]
    if not intr.refined:
        return [f"camera intrinsics as calibrated, not refined: {intr.reason}",
                "  the map depends on them: a rough calibration (few board views) bends it and can flag markers "
                "as moved (docs/tracking.md, Building a map)"]
    new, d = intr.values(), intr.change()
    parts = ", ".join(f"{k} {new[k]:.2f} ({d[k]:+.2f})" for k in ("fx", "fy", "cx", "cy"))
    lines = [f"camera intrinsics refined from the survey's {intr.n_views} views: {parts} px; "
             + ", ".join(f"{k} {new[k]:.4f} ({d[k]:+.4f})" for k in list(new)[4:])]
    off = max(abs(d[k]) / max(intr.sd[k], 1e-12) for k in ("fx", "fy", "cx", "cy"))
    if off > 5:
        lines.append(f"  the calibration's were {off:.0f} sd off the survey's: a map built with them as they are "
                     "would be bent; calibrate with more board views (docs/calibration.md) for tracking too")
    return lines


def format_map_report(built: BuiltMap) -> list[str]:
    """Lines for the terminal: the map, the intrinsics it used, then each flagged marker."""
    lines = [f"{len(built.marker_map.poses)} markers from {len(built.cameras)} views "
             f"({len(built.unposed)} without a marker of the map), reprojection RMS {built.rms_px:.2f} px"]
    if built.intrinsics is not None:
        lines += format_intrinsics(built.intrinsics)
    for i, inf in sorted(built.info.items()):
        sd = np.sqrt(np.clip(np.diag(inf.covariance)[3:], 0, None))
        if inf.flags:
            lines.append(f"  marker {i}: {'; '.join(inf.flags)} (views {inf.n_views}, RMS {inf.rms_px:.2f} px, "
                         f"position sd {np.max(sd):.1f} mm)")
    return lines
