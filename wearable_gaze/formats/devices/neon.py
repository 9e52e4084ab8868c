"""Pupil Labs Neon, native recording format ("pupil-neon"; docs/importers.md, research in
docs/devices/tobii-pupil.md section 4).

Files read. Pupil Labs' reader ``pupil_labs.neon_recording`` (the optional extra
``wearable-gaze[neon]``) finds and orders the multi-part files ``ps1, ps2, ...`` and reads
``info.json``, ``calibration.bin`` and the scene video; the streams (eye_state, gaze, worn
in chunks; blinks whole) are read by ``neon_streams``, with each stream's ``.dtype`` file (which
changed across data-format versions) or the reader's built-in layout:

- ``info.json``: ``gaze_frequency`` (Hz), ``start_time`` (ns) for the report;
- ``eye_state ps*.raw/.time`` + ``eye_state.dtype`` (required): per eye the eyeball centre (mm)
  and optical axis in the scene camera's frame, and the eyelid aperture (mm);
- ``worn ps*.raw``, ``blinks ps*.raw/.time`` (optional): samples not worn or inside a blink;
- ``gaze ps*.raw/.time`` (or ``gaze_200hz``) + ``calibration.bin``: the 2D gaze (px) and the
  scene camera's K and distortion, for the kappa offset (b) below and for ``camera.json``;
- ``Neon Scene Camera v1 ps1.mp4`` + ``.time`` (optional): the scene video and its frame times.

``ImportOptions.camera`` replaces calibration.bin's camera in ``camera.json`` (and stands in for
a missing calibration.bin). Memory is flat in the recording's length: the large streams are
memory-mapped and read ``CHUNK`` records at a time (``neon_streams``: the reader itself loads a
stream whole); the kappa fit (a first pass) and the report's vergence use at most
``MAX_FIT_SAMPLES`` evenly spread binocular samples; the rays go out in a second pass.

Frames. Neon reports the eye states in the scene camera's frame with OpenCV axes (x right,
y down, z forward), mm; ``calibration.bin`` holds the scene camera's extrinsics, identity in
every recording seen. That frame is our head frame: ``T_HEAD_FROM_NEON_SCENE`` = identity.

Kappa. The eye states are optical axes: they diverge (median 4.1 deg on the demo recording)
and the rays meet behind the head. The import turns them into visual axes with a constant
per-eye Fick-angle offset (``calibration.kappa``), fitted either
(a) ``targets``: from ``ImportOptions.kappa_recording`` (or the imported folder itself when it
    holds the file), a Neon recording folder holding ``targets.csv`` (``t_start, t_end`` s on
    that recording's session clock, ``x, y, z`` mm in its scene-camera frame: the point looked at
    during each interval), or
(b) ``cyclopean-ray``: from Neon's own 2D gaze, undistorted through the scene camera's K and
    distortion, taken as the cyclopean gaze ray from the scene camera, each eye's axis made to
    meet it at the fixed depth ``KAPPA_DEPTH_MM`` (the depth is an assumption: see
    ``calibration.kappa``; the report records it).

Clock. Neon timestamps are Unix ns; session t = (t_ns - t_first) / 1e9 with t_first the first
eye-state record, so ``clock_offset_s`` = t_first / 1e9 (Unix s). The report also gives the
first sample's offset from ``info.json`` ``start_time`` (2.247 s in the demo recording). Without
``gaze_frequency`` in info.json, the eye rate is the median interval of the first
``MAX_FIT_SAMPLES`` records.

Dropped and counted: records cut because a part's ``.raw`` and ``.time`` differ in length
(per part: later parts keep their own times); times that do not increase; samples not worn,
inside a blink, with implausible eye centres (beyond ``MAX_CENTER_MM`` or an eye distance
outside ``IED_RANGE_MM``) or no valid eye; per eye: non-finite values, an axis not pointing
forward, a closed lid (aperture below ``MIN_APERTURE_MM``).

What Neon lacks: a 3D gaze point (no ``device_gaze.csv``: its 2D gaze has no depth) and head
poses (poses come from tracking the scene video with ``--markers``, else a still head).
"""

from __future__ import annotations

import json
import logging
import shutil
import zlib
from pathlib import Path

import numpy as np

from calibration.camera import CameraCalibration
from calibration.kappa import apply_kappa, fit_kappa_cyclopean, fit_kappa_targets, vergence_summary

from ...errors import UserError
from ..camera import load_camera
from ..tables import read_table, write_table
from . import neon_streams as streams
from .common import ImportOptions, SessionImport, SimulatedRecording

log = logging.getLogger(__name__)

NAME = "pupil-neon"

T_HEAD_FROM_NEON_SCENE = np.eye(4)
"""Neon's scene-camera frame -> our head frame: identity. Neon's eye states are "relative to the
scene camera in mm" (pupil_labs.neon_recording ``timeseries/eyeball.py``) with OpenCV axes
(measured on the demo recording: left eye at -x, eyes below (+y) and behind (-z) the camera,
axes with z ~ +0.98), and ``calibration.bin`` scene extrinsics are identity
(docs/devices/tobii-pupil.md 4.3)."""

KAPPA_DEPTH_MM = 1000.0     # kappa (b): the depth at which each eye's axis meets the 2D gaze ray
MIN_APERTURE_MM = 1.0       # eyelid aperture below this: the eye is closed
MAX_CENTER_MM = 100.0       # an eyeball centre farther than this from the scene camera is implausible
IED_RANGE_MM = (45.0, 85.0)
SCENE_VIDEO = "Neon Scene Camera v1"
SCENE_SIZE = (1600, 1200)   # Neon's scene camera, px, when there is no video to read it from
TARGETS = "targets.csv"
CHUNK = 4096                # eye samples per chunk
MAX_FIT_SAMPLES = 10000     # the kappa fits and the report's vergence use at most this many samples, evenly spread
MAX_TARGET_ROWS = 2000      # the writer's targets.csv
EYE_FIELDS = [f"{q}_{s}_{x}" for q in ("eyeball_center", "optical_axis") for s in ("left", "right") for x in "xyz"]
EYE_FIELDS += ["eyelid_aperture_left_mm", "eyelid_aperture_right_mm"]
# the reader's built-in record layouts, for a stream without its .dtype file (eye_state's has no lids)
EYE_STATE_FALLBACK = np.dtype([(f"{f}_{s}{x}", "<f4") for s in ("left", "right") for f, x in
                               (("pupil_diameter", "_mm"), *((q, f"_{a}") for q in ("eyeball_center", "optical_axis")
                                                            for a in "xyz"))])
GAZE_FALLBACK = np.dtype([("x", "<f4"), ("y", "<f4")])
WORN_FALLBACK = np.dtype([("worn", "u1")])
BLINKS_FALLBACK = np.dtype([("start_timestamp_ns", "<i8"), ("end_timestamp_ns", "<i8")])   # the reader's


def detect(src: Path) -> bool:
    """A Neon native folder: ``info.json`` and ``eye_state ps*.raw``."""
    src = Path(src)
    return (src / "info.json").is_file() and any(src.glob("eye_state ps*.raw"))


def _stream(rec, name: str):
    """The vendor's (small) stream ``name``, or None when the recording lacks it."""
    try:
        return getattr(rec, name)
    except rec.SensorError:
        return None


def _missing(src: Path, name: str, files: str) -> UserError:
    return UserError(f"{src}: the Neon '{name}' stream is missing or unreadable ({files}); copy the complete "
                     "recording folder from the Companion device or Pupil Cloud's native export")


def _open(src: Path):
    nr = streams.vendor()
    try:
        rec = nr.open(src)
        rec.info  # noqa: B018 (info.json is read lazily: fail here, not halfway)
    except (FileNotFoundError, json.JSONDecodeError) as exc:
        raise UserError(f"{src}: not a readable Neon recording ({exc.__class__.__name__}: info.json); pass the "
                        "recording's folder") from None
    except UnicodeDecodeError as exc:
        raise UserError(f"{src / 'info.json'}: not UTF-8 text (byte {exc.object[exc.start]:#04x} at offset "
                        f"{exc.start}; a damaged copy); copy info.json again from the recording") from None
    return rec


def _fields(rec: np.ndarray, names: list[str], shape) -> np.ndarray:
    """The named float32 fields of structured records as one float64 array of ``shape``."""
    return np.stack([rec[f] for f in names], axis=-1).astype(float).reshape(shape)


class _Eyes:
    """One recording's eye states, read in chunks of ``CHUNK`` records with their validity
    (shared by the import and the kappa recording); memory does not grow with the length."""

    def __init__(self, src: Path, imp: SessionImport | None):
        self.src, self.imp = src, imp
        self.rec = _open(src)
        self.eyes = streams.open_stream(src, "eye_state", EYE_STATE_FALLBACK)
        if self.eyes is None:
            raise _missing(src, "eye_state", "eye_state ps*.raw/.time")
        lacking = [f for f in EYE_FIELDS if f not in (self.eyes.dtype.names or ())]
        if lacking:
            raise UserError(f"{src}: the eye_state records have no {lacking[0]} field (eye_state.dtype is missing "
                            "or from an older data format); copy the complete recording folder")
        self.n, self.truncated = self.eyes.n, self.eyes.cut
        if not self.n:
            raise UserError(f"{src}: the eye_state stream has no records; record again or check the copy")
        self.t0 = int(self.eyes.read(0, 1)[0][0])
        self.worn = streams.open_stream(src, "worn", WORN_FALLBACK)
        if self.worn is not None and (not self.worn.n or "worn" not in (self.worn.dtype.names or ())):
            self.worn = None
        blinks = streams.open_stream(src, "blinks", BLINKS_FALLBACK)        # a part cut mid-record: one line
        ends = None if blinks is None else blinks.read(0, blinks.n)[1]
        self.blinks = None if ends is None else (ends["start_timestamp_ns"], ends["end_timestamp_ns"])
        self.notes = [f"no '{n}' stream: not checked" for n, s in (("worn", self.worn), ("blinks", blinks))
                      if s is None]
        if blinks is not None and blinks.cut:
            self.notes.append(f"blinks: {blinks.cut} records or times cut (.raw and .time differ in length)")

    def _drop(self, reason: str, n: int) -> None:
        if self.imp is not None and self.count:
            self.imp.drop(reason, n)

    def chunk(self, a: int, b: int, t_max: int | None) -> dict:
        """Records a..b-1 (``t_max``: the latest time before a, None at the start): ``t`` (s, session
        clock), ``center``/``axis`` (2, n, 3) per eye (left, right), ``eye_ok`` (2, n) and ``keep`` (n,)
        with each exclusion counted."""
        t_ns, part = self.eyes.read(a, b)
        c = _fields(part, EYE_FIELDS[:6], (len(t_ns), 2, 3)).transpose(1, 0, 2)
        d = _fields(part, EYE_FIELDS[6:12], (len(t_ns), 2, 3)).transpose(1, 0, 2)
        aperture = _fields(part, EYE_FIELDS[12:], (len(t_ns), 2)).T
        keep, self.t_latest = streams.in_time_order(t_ns, self.eyes.read(b, b + streams.LOOKAHEAD)[0], t_max)
        self._drop("time not increasing", int((~keep).sum()))
        if self.worn is not None:
            i = np.clip(self.worn.searchsorted(t_ns, side="right") - 1, 0, self.worn.n - 1)
            off = keep & ~(self.worn.take(i)[1]["worn"] != 0)
            self._drop("not worn", int(off.sum()))
            keep &= ~off
        if self.blinks is not None and len(self.blinks[0]):
            j = np.searchsorted(self.blinks[0], t_ns, side="right") - 1
            inside = keep & (j >= 0) & (t_ns <= self.blinks[1][np.clip(j, 0, None)])
            self._drop("inside a blink (Neon's blinks stream)", int(inside.sum()))
            keep &= ~inside
        eye_ok = np.ones((2, len(t_ns)), bool)
        for e, side in enumerate(("left", "right")):
            finite = np.all(np.isfinite(c[e]), axis=1) & np.all(np.isfinite(d[e]), axis=1)
            forward = finite & (np.nan_to_num(d[e][:, 2]) > 0)
            closed = forward & ~(np.nan_to_num(aperture[e], nan=np.inf) >= MIN_APERTURE_MM)
            for reason, bad in (("non-finite eye state", ~finite), ("optical axis not pointing forward",
                                                                      finite & ~forward),
                                (f"eyelid closed (aperture < {MIN_APERTURE_MM:g} mm)", closed)):
                self._drop(f"{side} eye: {reason}", int((keep & bad).sum()))
            eye_ok[e] = forward & ~closed
        ied = np.linalg.norm(c[1] - c[0], axis=1)
        far = np.nan_to_num(np.linalg.norm(c, axis=2), nan=0.0).max(axis=0) > MAX_CENTER_MM
        odd = keep & (far | (eye_ok.all(axis=0) & ~((ied >= IED_RANGE_MM[0]) & (ied <= IED_RANGE_MM[1]))))
        self._drop(f"implausible eye centres (beyond {MAX_CENTER_MM:g} mm, or eye distance outside "
                   f"{IED_RANGE_MM[0]:g}-{IED_RANGE_MM[1]:g} mm)", int(odd.sum()))
        keep &= ~odd
        none = keep & ~eye_ok.any(axis=0)
        self._drop("no valid eye", int(none.sum()))
        keep &= ~none
        return {"t": (t_ns - self.t0) / 1e9, "t_ns": t_ns, "center": c, "axis": d, "eye_ok": eye_ok & keep,
                "keep": keep}

    def chunks(self, count: bool = True):
        """(a, chunk a..a+CHUNK-1) over the whole recording; with ``count`` the drops go to the import."""
        self.count, t_max = count, None
        for a in range(0, self.n, CHUNK):
            ch = self.chunk(a, min(a + CHUNK, self.n), t_max)
            t_max = self.t_latest
            yield a, ch


def _gaze_rays(gaze: streams.Stream, t_ns: np.ndarray, cam: CameraCalibration) -> np.ndarray:
    """Neon's 2D gaze stream at the eye-state times ``t_ns`` (the nearest record within 5 ms),
    undistorted by ``cam`` into (n, 3) ray directions from the scene camera (NaN where none)."""
    out = np.full((len(t_ns), 3), np.nan)
    if not gaze.n or not len(t_ns):
        return out
    j = gaze.searchsorted(t_ns)
    lo, hi = np.clip(j - 1, 0, gaze.n - 1), np.clip(j, 0, gaze.n - 1)
    t_lo, t_hi = gaze.take(lo)[0], gaze.take(hi)[0]
    k = np.where(np.abs(t_lo - t_ns) <= np.abs(t_hi - t_ns), lo, hi)
    tg, rec = gaze.take(k)
    px = _fields(rec, list(rec.dtype.names), (len(k), 2))
    ok = (np.abs(tg - t_ns) <= 5_000_000) & np.all(np.isfinite(px), axis=1)
    if ok.any():
        out[ok] = np.column_stack([cam.undistort_points(px[ok]), np.ones(int(ok.sum()))])
    return out


def _binocular_sample(eyes: _Eyes, cam: CameraCalibration | None = None):
    """At most ``MAX_FIT_SAMPLES`` binocular samples evenly spread over the recording (every
    valid one when there are fewer; the choice does not depend on ``CHUNK``): centres and optical
    axes (2, n, 3) and, with ``cam``, Neon's 2D gaze rays (n, 3) (else None)."""
    gaze = None
    if cam is not None:
        gaze = streams.open_stream(eyes.src, "gaze", GAZE_FALLBACK)
        if gaze is None or len(gaze.dtype.names or ()) != 2:
            raise _missing(eyes.src, "gaze", "gaze ps*.raw/.time, needed for the kappa offset without "
                                             "--kappa-recording")
        if eyes.imp is not None:
            eyes.imp.count("gaze", gaze.n)
    rows, seen, rate = [], 0, min(1.0, MAX_FIT_SAMPLES / eyes.n)
    for _, ch in eyes.chunks(count=False):     # counted once, when the rays are written
        ok = np.flatnonzero(ch["eye_ok"].all(axis=0))
        v = seen + np.arange(len(ok), dtype=float)
        sel = ok[np.floor((v + 1) * rate) > np.floor(v * rate)]   # the valid samples where a rate-counter ticks
        seen += len(ok)
        rows.append((ch["center"][:, sel], ch["axis"][:, sel],
                     None if gaze is None else _gaze_rays(gaze, ch["t_ns"][sel], cam)))
    c = np.concatenate([r[0] for r in rows], axis=1)
    d = np.concatenate([r[1] for r in rows], axis=1)
    return c, d, None if gaze is None else np.concatenate([r[2] for r in rows])


def _fit_cyclopean(eyes: _Eyes, c, d, g):
    """Kappa (b): each eye's axis meets Neon's 2D gaze ray at ``KAPPA_DEPTH_MM``."""
    try:
        return fit_kappa_cyclopean(c[0], d[0], c[1], d[1], g, KAPPA_DEPTH_MM)
    except ValueError as exc:
        raise UserError(f"{eyes.src}: cannot fit the kappa offset from Neon's 2D gaze ({exc}); give a recording "
                        "of known targets (--kappa-recording)") from None


def _fit_targets(folder: Path):
    """Kappa (a) from a Neon recording of known targets with ``targets.csv`` (module docstring)."""
    tab = read_table(folder / TARGETS, ["t_start", "t_end", "x", "y", "z"], what="kappa targets CSV",
                     fix=f"put {TARGETS} (t_start,t_end,x,y,z: s, mm in the scene-camera frame) in the recording")
    order = np.argsort(tab["t_start"])
    t0, t1 = tab["t_start"][order], tab["t_end"][order]
    P = np.column_stack([tab["x"], tab["y"], tab["z"]])[order]
    if np.any(t1 < t0) or np.any(t0[1:] <= t1[:-1]):
        raise UserError(f"{folder / TARGETS}: target intervals must have t_end >= t_start and must not overlap")
    eyes, rows = _Eyes(folder, None), []
    for _, ch in eyes.chunks():
        j = np.searchsorted(t0, ch["t"], side="right") - 1
        on = (j >= 0) & (ch["t"] <= t1[np.clip(j, 0, None)])
        ok = ch["eye_ok"] & on
        r = ok.any(axis=0)            # only samples on a target with a valid eye: the rest would not count
        rows.append([np.where(ok[e][r, None], x[e][r], np.nan) for e in (0, 1) for x in (ch["center"], ch["axis"])]
                    + [P[np.clip(j[r], 0, None)]])
    cols = [np.concatenate(r) for r in zip(*rows, strict=True)]
    try:
        return fit_kappa_targets(*cols)
    except ValueError as exc:
        raise UserError(f"{folder}: cannot fit the kappa offset from its targets ({exc}); check that the "
                        f"{TARGETS} intervals cover valid eye samples (times in s from the first eye sample)") from None


def _camera(rec, imp: SessionImport, options: ImportOptions, src: Path):
    """The scene camera: ``camera.json`` from ``--camera`` or else calibration.bin, the scene
    video if present, the marker map. Returns (the camera Neon's 2D gaze was mapped through:
    calibration.bin's, or ``--camera`` without it; image size; fps; the vendor's scene stream)."""
    cal = streams.read_calibration(rec, src)
    user = load_camera(options.camera) if options.camera is not None else None
    if cal is None and user is None:
        raise UserError(f"{src}: no calibration.bin (the scene camera's intrinsics); copy it from the recording or "
                        "give the scene camera's calibration with --camera")
    scene = _stream(rec, "scene")
    size, fps = SCENE_SIZE, None
    if scene is not None:
        size = (int(scene.width), int(scene.height))
        t = np.asarray(scene.time, np.int64) / 1e9
        fps = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else None
    if cal is not None:
        if not np.allclose(np.asarray(cal.scene_extrinsics_affine_matrix, float), np.eye(4), atol=1e-6):
            imp.note("calibration.bin scene extrinsics are not identity; the eye states are taken as given in the "
                     "scene camera's frame")
        device = CameraCalibration(np.asarray(cal.scene_camera_matrix, float),
                                   np.asarray(cal.scene_distortion_coefficients, float), size)
    if user is not None:
        imp.set_camera(user.camera_matrix, user.dist_coeffs, user.image_size, user.model)
        also = "" if cal is not None else " (no calibration.bin; also used for Neon's 2D gaze)"
        imp.note(f"scene camera from --camera {options.camera}{also}")
    else:
        imp.set_camera(device.camera_matrix, device.dist_coeffs, size, serial=str(cal.serial))
    if options.markers is not None:
        imp.set_marker_map(options.markers)
    return (device if cal is not None else user), size, fps, scene


def read_recording(src: Path, imp: SessionImport, options: ImportOptions, progress=None) -> None:
    """Import a Neon native recording folder into ``imp`` (module docstring)."""
    src = Path(src)
    eyes = _Eyes(src, imp)
    rec = eyes.rec
    imp.count("eye_state", eyes.n)
    imp.drop("eye_state: records cut by the reader (.raw and .time differ in length)", eyes.truncated)
    for n in eyes.notes:
        imp.note(n)
    cam, size, fps, scene = _camera(rec, imp, options, src)
    kappa_src = options.kappa_recording or (src if (src / TARGETS).is_file() else None)
    if kappa_src is not None:
        if Path(kappa_src) == src:
            imp.note(f"the recording holds {TARGETS}: the kappa offset is fitted on its own target intervals")
        kappa = _fit_targets(Path(kappa_src))
        sample = _binocular_sample(eyes)
    else:
        sample = _binocular_sample(eyes, cam)
        kappa = _fit_cyclopean(eyes, *sample)
    n = eyes.n
    for a, ch in eyes.chunks():
        k = ch["keep"]
        vis = [apply_kappa(ch["axis"][e][k], kap.kappa_deg) for e, kap in enumerate((kappa.left, kappa.right))]
        imp.add_rays(ch["t"][k], ch["center"][0][k], vis[0], ch["eye_ok"][0][k], ch["center"][1][k], vis[1],
                     ch["eye_ok"][1][k])
        if progress is not None:
            progress(min(a + CHUNK, n), n)
    pose_source = "still_head"
    if scene is not None:
        t_frames = (np.asarray(scene.time, np.int64) - eyes.t0) / 1e9
        imp.add_scene_video(sorted(src.glob(f"{SCENE_VIDEO} ps*.mp4"))[0], t_frames)
        if options.markers is not None:
            pose_source = "scene_video"
        else:
            imp.note("scene video without a marker map (--markers): no head poses; the head is taken as still")
    else:
        imp.note(f"no scene video ('{SCENE_VIDEO} ps1.mp4'): no head poses; the head is taken as still")
    imp.note("Neon gives no 3D gaze point (its 2D gaze has no depth): no device_gaze.csv")
    _finish(imp, rec, eyes, kappa, sample, pose_source, size, fps)


def _finish(imp, rec, eyes: _Eyes, kappa, sample, pose_source, size, fps) -> None:
    rate = rec.info.get("gaze_frequency") or 1e9 / np.median(np.diff(eyes.eyes.read(0, MAX_FIT_SAMPLES)[0]))
    k_report = {"method": kappa.method, "left_deg": kappa.left.kappa_deg.round(4).tolist(),
                "right_deg": kappa.right.kappa_deg.round(4).tolist(),
                "spread_deg": {"left": kappa.left.spread_deg.round(4).tolist(),
                               "right": kappa.right.spread_deg.round(4).tolist()},
                "samples": {"left": kappa.left.n, "right": kappa.right.n},
                "convention": "degrees added to the optical axis's Fick angles (h + toward the wearer's right, "
                              "v + down), head frame",
                "depth_mm": kappa.depth_mm,
                "source": ("Neon's 2D gaze ray at a fixed depth" if kappa.depth_mm is not None
                           else "a recording of known targets")}
    (c, d), kl, kr = sample[:2], kappa.left.kappa_deg, kappa.right.kappa_deg
    k_report["rays_before"] = vergence_summary(c[0], d[0], c[1], d[1])
    k_report["rays_after"] = vergence_summary(c[0], apply_kappa(d[0], kl), c[1], apply_kappa(d[1], kr))
    imp.note(f"kappa offset by {kappa.method}" + (f" at {kappa.depth_mm:g} mm" if kappa.depth_mm else "")
             + f": left {k_report['left_deg']} deg, right {k_report['right_deg']} deg")
    start = rec.start_time
    clock = {"device_clock": "Unix ns", "session_t": "(t_ns - first eye_state t_ns) / 1e9",
             "first_sample_ns": eyes.t0,
             "first_sample_after_start_time_s": (eyes.t0 - start) / 1e9 if start else None}
    frames = {"head": "Neon scene camera (OpenCV axes: x right, y down, z forward; mm)",
              "T_head_from_neon_scene": T_HEAD_FROM_NEON_SCENE.tolist()}
    imp.finish(float(rate), eyes.t0 / 1e9, pose_source, frames, image_size=size, fps=fps, kappa=k_report,
               clock=clock)


# --- writer ---------------------------------------------------------------------------------

EYE_STATE_NAMES = [f"{f}_{s}{x}" for s in ("left", "right") for f, x in
                   (("pupil_diameter", "_mm"), ("eyeball_center", "_x"), ("eyeball_center", "_y"),
                    ("eyeball_center", "_z"), ("optical_axis", "_x"), ("optical_axis", "_y"), ("optical_axis", "_z"))]
EYE_STATE_NAMES += [f"eyelid_{k}_{s}" + u for s in ("left", "right") for k, u in
                    (("angle_top", ""), ("angle_bottom", ""), ("aperture", "_mm"))]
CALIBRATION_DTYPE = np.dtype([("version", "u1"), ("serial", "6S"), *[
    (f"{cam}_{k}", t) for cam in ("scene", "right", "left") for k, t in
    (("camera_matrix", "(3,3)f8"), ("distortion_coefficients", "8f8"), ("extrinsics_affine_matrix", "(4,4)f8"))],
    ("crc", "u4")])
"""calibration.bin, 803 bytes (pupil_labs.neon_recording ``calib.py``)."""


def _write_stream(dst: Path, base: str, names_types, columns: dict, t_ns=None) -> None:
    """``<base> ps1.raw`` (records of ``<base>.dtype``), ``<base>.dtype`` and, with ``t_ns``,
    ``<base> ps1.time`` (int64 ns)."""
    dt = np.dtype(names_types)
    rec = np.zeros(len(next(iter(columns.values()))), dt)
    for k, v in columns.items():
        rec[k] = v
    rec.tofile(dst / f"{base} ps1.raw")
    (dst / f"{base}.dtype").write_text("[\n" + "".join(f'("{n}", "{t}"),\n' for n, t in names_types) + "]\n")
    if t_ns is not None:
        np.asarray(t_ns, "<i8").tofile(dst / f"{base} ps1.time")


def write_recording(sim: SimulatedRecording, dst: Path, kappa_deg: dict | None = None, targets: bool = True) -> None:
    """Write a simulated session as a Neon native folder (the files the reader reads).

    The simulated view lines are visual axes; the optical axes written are them with
    ``kappa_deg`` ({'left': (h, v), 'right': (h, v)} degrees, default none) taken off, so an
    import that recovers the offset gives the simulated lines back. The 2D gaze is the true
    gazed point projected through the true scene camera. With ``targets``, ``targets.csv``
    holds the true gazed point (head frame) at up to ``MAX_TARGET_ROWS`` samples, so the
    recording is its own known-target recording (kappa method (a)).
    """
    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    cam = sim.camera
    if cam.model != "pinhole" or len(cam.dist_coeffs) > 8:
        raise ValueError("Neon's calibration.bin holds an 8-coefficient pinhole model; the simulated camera is "
                         f"{cam.model} with {len(cam.dist_coeffs)} coefficients")
    start_ns = 1_700_000_000_000_000_000
    t_ns = start_ns + np.round(np.asarray(sim.t, float) * 1e9).astype(np.int64)
    r = sim.rays
    kappa = kappa_deg or {}
    cols = {}
    for side, o, d, v in (("left", r.left_origin_mm, r.left_direction, r.left_valid),
                          ("right", r.right_origin_mm, r.right_direction, r.right_valid)):
        k = -np.asarray(kappa.get(side, (0.0, 0.0)), float)
        # an invalid (blinking) eye: as Neon writes it, a closed lid with the eye looking ahead
        axis = apply_kappa(np.where(v[:, None] & np.isfinite(d), d, [0.0, 0.0, 1.0]), k)
        o = np.where(np.isfinite(o), o, np.nanmedian(o, axis=0))
        for a, i in zip("xyz", range(3), strict=True):
            cols[f"eyeball_center_{side}_{a}"] = o[:, i]
            cols[f"optical_axis_{side}_{a}"] = axis[:, i]
        cols[f"pupil_diameter_{side}_mm"] = 3.5
        cols[f"eyelid_aperture_{side}_mm"] = np.where(v, 8.0, 0.0)
    _write_stream(dst, "eye_state", [(n, "float32") for n in EYE_STATE_NAMES], cols, t_ns)
    px = cam.project(np.where(np.isfinite(sim.gaze_head_mm), sim.gaze_head_mm, [0.0, 0.0, 1.0]))
    _write_stream(dst, "gaze", [("x", "float32"), ("y", "float32")], {"x": px[:, 0], "y": px[:, 1]}, t_ns)
    _write_stream(dst, "worn", [("worn", "uint8")], {"worn": np.full(len(t_ns), 255)})
    dist = np.zeros(8)
    dist[:len(cam.dist_coeffs)] = cam.dist_coeffs
    calib = np.zeros((), CALIBRATION_DTYPE)
    calib["version"], calib["serial"] = 1, b"SIM001"
    for c in ("scene", "right", "left"):
        calib[f"{c}_camera_matrix"] = cam.camera_matrix if c == "scene" else np.eye(3)
        calib[f"{c}_extrinsics_affine_matrix"] = np.eye(4)
    calib["scene_distortion_coefficients"] = dist
    body = calib.tobytes()[:-4]
    calib["crc"] = zlib.crc32(body)    # Neon's checksum is not documented; the reader does not check it
    (dst / "calibration.bin").write_bytes(calib.tobytes())
    shutil.copyfile(sim.video, dst / f"{SCENE_VIDEO} ps1.mp4")
    np.asarray(start_ns + np.round(np.asarray(sim.frame_times) * 1e9), "<i8").tofile(dst / f"{SCENE_VIDEO} ps1.time")
    ied = np.nanmedian(np.linalg.norm(r.right_origin_mm - r.left_origin_mm, axis=1))
    info = {"recording_id": "simulated", "data_format_version": "2.5", "start_time": start_ns,
            "duration": int(t_ns[-1] - start_ns), "module_serial_number": "SIM001", "gaze_frequency": sim.eye_rate_hz,
            "wearer_ied": round(float(ied), 1), "gaze_mode": "binocular", "gaze_offset": [0.0, 0.0]}
    (dst / "info.json").write_text(json.dumps(info))
    if targets:
        _write_targets(dst / TARGETS, np.asarray(sim.t, float) - float(sim.t[0]), sim.gaze_head_mm)


def _write_targets(path: Path, t, points_mm) -> None:
    """``targets.csv``: one short interval (a quarter of the sample spacing each side) around
    each of up to ``MAX_TARGET_ROWS`` samples with a gazed point."""
    ok = np.flatnonzero(np.all(np.isfinite(points_mm), axis=1))
    ok = ok[:: max(1, len(ok) // MAX_TARGET_ROWS)]
    half = 0.25 * float(np.median(np.diff(t))) if len(t) > 1 else 1e-3
    p = points_mm[ok]
    write_table(path, {"t_start": t[ok] - half, "t_end": t[ok] + half, "x": p[:, 0], "y": p[:, 1], "z": p[:, 2]},
                {"t_start": ".6f", "t_end": ".6f", "x": ".3f", "y": ".3f", "z": ".3f"})
