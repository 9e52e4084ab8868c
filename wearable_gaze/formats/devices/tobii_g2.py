"""Tobii Pro Glasses 2 recordings (``--format tobii-g2``; docs/importers.md).

Files read: a recording folder (``recording.json``, ``segments/1/``) or a Tobii project folder
holding one recording (``recordings/<id>/``). In ``segments/1``: ``livedata.json.gz`` (the data),
``et.tslv.gz`` (only its TSLV type-300 record: the scene camera's calibration) and
``fullstream.mp4`` (the scene video, when there is one).

Fields used (``livedata.json.gz``, one JSON object per line; the lines of one eye sample share
``gidx`` and come in any order, interleaved with IMU lines): per eye (``eye`` left/right) ``pc``
(pupil centre, the view line's origin, mm) and ``gd`` (unit gaze direction), each with its status
``s`` (0 = valid); ``gp3`` (the device's 3D gaze point, mm: comparison only); ``gp`` (its 2D gaze,
normalised, only to confirm the frame mapping); ``vts`` lines (scene-video time, us, at glasses
time ``ts``, us): the clock. ``pd``, ``l``, ``pts``/``pv``, ``ac``, ``gy`` and ``dir``/``sig``
are counted and not used.

Frames: ``pc``, ``gd``, ``gp3`` are in the glasses frame (x to the wearer's left, y up, z forward,
mm). They are mapped to our head frame (the scene camera, OpenCV axes) by the unit's own
extrinsics from the type-300 record (``tobii_common.t_cam_from_glasses``; the nominal flip
``tobii_common.T_CAM_FROM_GLASSES_NOMINAL`` only when ``et.tslv`` has no calibration), checked on
the recording by reprojecting ``gp3`` onto ``gp`` (import_report.json ``frames.position_convention``).

Clock: the session clock is the scene video's: a sample at glasses time ``ts`` gets
t = (vts_k + ts - ts_k) / 1e6 s with the latest sync pair (ts_k, vts_k) at or before it (the
pairs seen so far in the file; a recording without any ``vts`` line uses ts - first sample's ts and
says so). ``clock_offset_s`` in the manifest is (ts_0 - vts_0) / 1e6 of the first pair.

Dropped and counted (import_report.json): per eye, a non-zero status (by code: 16 eye lost, 1, 4;
Tobii zeroes the values), non-finite values, a pupil centre over 100 mm from the scene camera, a
direction that is not unit or points backwards; per sample, no valid eye, an incomplete ``gidx``
group (an eye's ``pc`` or ``gd`` line missing: the last sample of a recording), a sample before the
first ``vts`` (before the video started), a time that does not increase, and an unparsable line.
Gaps in the device's time stamps count the samples they lost.

What the device does not give: head poses (they come from tracking the scene video against a
marker map, ``--markers``; without both the head is taken as still and the estimate is vergence
only), eye rotation centres (``pc`` is the pupil centre), the meaning of status codes and of TSLV
types other than 300. Recordings with several segments are refused.
"""

from __future__ import annotations

import gzip
import json
import logging
import shutil
import struct
import zlib
from collections import Counter
from pathlib import Path

import numpy as np

from ...errors import UserError
from .tobii_common import (
    CHUNK,
    NAN3,
    GapCounter,
    GlassesCamera,
    JsonLines,
    RayChunks,
    choose_convention,
    finish_import,
    frames_report,
    orthonormal,
    project_norm,
    sim_in_glasses,
    t_cam_from_glasses,
    vec,
    video_frame_times,
    writer_camera,
)

NAME = "tobii-g2"
log = logging.getLogger(__name__)

WINDOW = 64
"""A ``gidx`` group is complete when the stream has moved this many samples past it."""
PREPASS_PAIRS = 200
EYE_KEYS = ("pc_left", "gd_left", "pc_right", "gd_right")
TSLV_HEADER = struct.Struct("<hhi")
TSLV_CAMERA = struct.Struct("<bb2x3f9f2ff2f3f3f2h")   # type 300, 100 bytes (glassesTools getCameraFromTSLV)
WRITER_TS_OFFSET_US = 84_000_000


# --- the folder --------------------------------------------------------------------------------

def _recordings(src: Path) -> list[Path]:
    if (src / "segments").is_dir():
        return [src]
    return sorted(p for p in (src / "recordings").glob("*") if (p / "segments").is_dir())


def detect(src: Path) -> bool:
    """A G2 recording or a project holding recordings: ``segments/*/livedata.json.gz``."""
    return any(any(rec.glob("segments/*/livedata.json.gz")) for rec in _recordings(Path(src)))


def segment_folder(src: Path) -> Path:
    """The one segment folder of the recording in ``src``.

    Raises:
        UserError: no recording, several recordings or segments, or no ``livedata.json.gz``.
    """
    recs = _recordings(src)
    if len(recs) != 1:
        what = "no recording (segments/ or recordings/*/segments/)" if not recs else \
            f"{len(recs)} recordings ({', '.join(r.name for r in recs)})"
        raise UserError(f"{src}: holds {what}; pass one recording's folder")
    segs = sorted((p for p in (recs[0] / "segments").iterdir() if p.is_dir()), key=lambda p: p.name)
    if len(segs) != 1:
        raise UserError(f"{recs[0]}: {len(segs)} segments in segments/; importing a paused recording (several "
                        "segments) is not supported: import one segment's copy (a folder with segments/1 only)")
    if not (segs[0] / "livedata.json.gz").is_file():
        raise UserError(f"{segs[0]}: no livedata.json.gz (the eye data); copy the whole recording from the SD card")
    return segs[0]


# --- et.tslv: the scene camera ------------------------------------------------------------------

def read_tslv_camera(path: Path) -> GlassesCamera | None:
    """The scene camera from the first TSLV type-300 record of ``et.tslv.gz`` (None: no such record).

    Records: int16 type, int16 status, int32 length, payload padded to 4 bytes. Type 300: int8 id,
    int8 location, 2 pad, float32 position[3], rotation[9] (row-major), focal_length[2], skew,
    principal_point[2], radial[3], tangential[3], int16 resolution[2] (glassesTools
    ``getCameraFromTSLV``). Read as a stream; the other records are skipped.
    """
    try:
        with gzip.open(path, "rb") as fh:
            while len(head := fh.read(TSLV_HEADER.size)) == TSLV_HEADER.size:
                kind, _, length = TSLV_HEADER.unpack(head)
                payload = fh.read((length + 3) // 4 * 4)
                if kind == 300 and len(payload) >= TSLV_CAMERA.size:
                    v = TSLV_CAMERA.unpack(payload[:TSLV_CAMERA.size])
                    return _camera_from_record(v, path)
    except (OSError, EOFError, zlib.error) as exc:
        log.warning("%s: %s", path, exc)
    return None


def _camera_from_record(v, path) -> GlassesCamera:
    position, rotation, focal, skew, pp = v[2:5], v[5:14], v[14:16], v[16], v[17:19]
    radial, tangential, res = v[19:22], v[22:25], v[25:27]
    K = np.array([[focal[0], skew, pp[0]], [0.0, focal[1], pp[1]], [0.0, 0.0, 1.0]])
    dist = np.array([radial[0], radial[1], tangential[0], tangential[1], radial[2]])
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and min(res) > 0):
        raise UserError(f"{path}: the scene-camera record (TSLV type 300) is damaged (focal length or resolution "
                        "not positive); give --camera camera.json")
    return GlassesCamera(orthonormal(np.reshape(rotation, (3, 3))), np.array(position, float), K, dist,
                         (int(res[0]), int(res[1])), f"{path.name} TSLV type 300")


# --- livedata.json.gz ---------------------------------------------------------------------------

def sync_pair(obj: dict) -> tuple[int, int] | None:
    """A valid ``vts`` line's (ts, vts), us; None for any other line, or one whose status is not 0 or
    whose ``ts`` or ``vts`` is not an integer (a damaged line is skipped, not a crash)."""
    ts, vts = obj.get("ts"), obj.get("vts")
    ok = obj.get("s") == 0 and all(isinstance(v, int) and not isinstance(v, bool) for v in (ts, vts))
    return (ts, vts) if ok else None


def prepass(path: Path) -> dict:
    """From the start of ``livedata.json.gz`` (streamed; stops when it has what it needs): the first
    valid sync pair (ts, vts), the eye rate (median step of the first samples, Hz) and up to
    ``PREPASS_PAIRS`` valid (gp3, gp) pairs for ``choose_convention``."""
    gp, gp3, ts, first_vts = {}, {}, set(), None
    for obj in JsonLines(path, Counter()):
        if first_vts is None:
            first_vts = sync_pair(obj)
        if "gidx" in obj and isinstance(obj.get("ts"), int):
            if len(ts) < PREPASS_PAIRS:
                ts.add(obj["ts"])
            if obj.get("s") == 0 and "gp" in obj:
                gp[obj["gidx"]] = vec(obj["gp"], 2)
            elif obj.get("s") == 0 and "gp3" in obj:
                gp3[obj["gidx"]] = vec(obj["gp3"])
        both = gp.keys() & gp3.keys()
        if first_vts is not None and len(both) >= PREPASS_PAIRS and len(ts) >= PREPASS_PAIRS:
            break
    both = sorted(gp.keys() & gp3.keys())
    steps = np.diff(np.sort(np.fromiter(ts, float))) / 1e6
    rate = 1.0 / float(np.median(steps)) if len(steps) else 50.0
    return {"first_vts": first_vts, "rate_hz": rate, "first_ts": min(ts) if ts else 0,
            "gp3": np.array([gp3[g] for g in both], float).reshape(-1, 3),
            "gp": np.array([gp[g] for g in both], float).reshape(-1, 2)}


def _row(g: dict, drops: Counter):
    """One flushed gidx group -> (ts, pcL, gdL, statusL, pcR, gdR, statusR, gp3) or None (incomplete)."""
    if not all(k in g for k in EYE_KEYS):
        drops["sample: incomplete gidx group (an eye's pc or gd line missing)"] += 1
        return None
    g3 = g.get("gp3", (NAN3, 1))
    ts = sorted(g["ts"])[(len(g["ts"]) - 1) // 2]     # the lines' median: one line's damaged ts cannot move it
    return (ts, g["pc_left"][0], g["gd_left"][0], g["pc_left"][1] or g["gd_left"][1],
            g["pc_right"][0], g["gd_right"][0], g["pc_right"][1] or g["gd_right"][1], g3[0] if g3[1] == 0 else NAN3)


class _Clock:
    """Glasses time (us) -> session time (s) from the ``vts`` sync pairs seen so far."""

    def __init__(self, pre: dict, imp):
        self.ts, self.vts = [], []
        self.offsets = []          # (first, min, max) of ts - vts, us
        self.zero = None
        if pre["first_vts"] is None:
            self.zero = pre["first_ts"]
            imp.note("no video sync (vts) line in livedata: the session clock starts at the first eye sample")
        else:
            self.add(*pre["first_vts"])

    def add(self, ts: int, vts: int) -> None:
        if not self.ts or ts > self.ts[-1]:
            self.ts.append(ts)
            self.vts.append(vts)
            off = ts - vts
            self.offsets = [off, off, off] if not self.offsets else \
                [self.offsets[0], min(self.offsets[1], off), max(self.offsets[2], off)]

    def __call__(self, ts: np.ndarray) -> np.ndarray:
        """Session times (n,) s; NaN before the first sync pair."""
        if self.zero is not None:
            return (ts - self.zero) / 1e6
        k = np.searchsorted(np.asarray(self.ts), ts, side="right") - 1
        t = (np.asarray(self.vts)[np.maximum(k, 0)] + ts - np.asarray(self.ts)[np.maximum(k, 0)]) / 1e6
        t[k < 0] = np.nan
        if len(ts) and k.min() > 0:   # pairs before the earliest one still needed are done with
            del self.ts[:k.min()], self.vts[:k.min()]
        return t


def _emit(rows: list, clock: _Clock, gaps: GapCounter, chunks: RayChunks) -> None:
    ts = np.array([r[0] for r in rows], np.int64)
    gaps.feed(ts / 1e6, chunks.drops)
    t = clock(ts)
    before = np.isnan(t)
    chunks.drops["sample: before the first video sync (vts)"] += int(before.sum())
    rows = [r for r, b in zip(rows, before, strict=True) if not b]
    if not rows:
        return
    cols = list(zip(*rows, strict=True))
    eyes = {}
    for side, (o, d, st) in (("left", cols[1:4]), ("right", cols[4:7])):
        st = np.array(st, np.int64)
        for code, n in zip(*np.unique(st[st != 0], return_counts=True), strict=True):
            chunks.drops[f"{side} eye: status {code}"] += int(n)
        eyes[side] = (np.array(o, float), np.array(d, float), st == 0)
    chunks.emit(t[~before], eyes, np.array(cols[7], float))


def stream_livedata(path: Path, clock: _Clock, gaps: GapCounter, chunks: RayChunks, imp, progress=None) -> JsonLines:
    """Group the lines by ``gidx`` over a window of ``WINDOW`` samples and hand the samples to
    ``chunks`` ``CHUNK`` at a time; sync pairs go to ``clock``. Returns the line reader (counts)."""
    lines = JsonLines(path, chunks.drops, progress)
    pending, rows, kinds = {}, [], Counter()
    top = -1

    def flush(upto):
        for gidx in sorted(k for k in pending if k < upto):
            row = _row(pending.pop(gidx), chunks.drops)
            if row is not None:
                rows.append(row)
        if len(rows) >= CHUNK or upto == np.inf:
            _emit(rows, clock, gaps, chunks)
            rows.clear()

    for obj in lines:
        gidx = obj.get("gidx")
        if isinstance(gidx, int) and not isinstance(obj.get("ts"), int):
            chunks.drops["line: eye-sample line without an integer ts"] += 1
            continue
        if not isinstance(gidx, int) or not isinstance(obj.get("ts"), int):
            kinds[next((k for k in ("vts", "pts", "ac", "gy", "sig") if k in obj), "other")] += 1
            if (pair := sync_pair(obj)) is not None:
                clock.add(*pair)
            elif "vts" in obj and obj.get("s") == 0:
                chunks.drops["line: video sync (vts) line without an integer ts or vts"] += 1
            continue
        g = pending.setdefault(gidx, {"ts": []})
        g["ts"].append(obj["ts"])
        s = obj.get("s", 0) if isinstance(obj.get("s", 0), int) else 1
        eye = obj.get("eye")
        for key in ("pc", "gd", "pd", "gp", "gp3"):
            if key in obj:
                kinds[key] += 1
                g[f"{key}_{eye}" if eye in ("left", "right") else key] = (vec(obj[key], 2 if key == "gp" else 3)
                                                                         if key != "pd" else obj[key], s)
        if gidx > top:
            top = gidx
            if len(pending) > 2 * WINDOW:
                flush(top - WINDOW)
    flush(np.inf)
    for kind, n in kinds.items():
        imp.count(f"livedata {kind} lines", n)
    return lines


def read_recording(src: Path, imp, options, progress=None) -> None:
    """Stream a G2 recording into ``imp`` (see the module docstring)."""
    seg = segment_folder(Path(src))
    live = seg / "livedata.json.gz"
    tslv = seg / "et.tslv.gz"
    cam = read_tslv_camera(tslv) if tslv.is_file() else None
    video = seg / "fullstream.mp4"
    video = video if video.is_file() else None
    if video is not None and cam is None and options.camera is None:
        raise UserError(f"{seg}: a scene video but no scene-camera calibration in {tslv.name}; give --camera "
                        "camera.json (calibrate-camera)")
    pre = prepass(live)
    T, convention = choose_convention(cam, pre["gp3"], pre["gp"], imp)
    clock = _Clock(pre, imp)
    chunks = RayChunks(imp, T)
    gaps = GapCounter(pre["rate_hz"])
    lines = stream_livedata(live, clock, gaps, chunks, imp, progress)
    if lines.truncated:
        imp.note(lines.truncated)
    chunks.flush_drops()
    offsets = clock.offsets
    frame_times = None
    if video is not None:
        if clock.zero is None:
            frame_times, _ = video_frame_times(video)
        else:
            imp.note("the scene video cannot be placed on the eye clock (no vts line); it is not imported")
    finish_import(imp, options, cam, video, frame_times, pre["rate_hz"],
                  offsets[0] / 1e6 if offsets else 0.0, frames_report(T, cam, convention),
                  largest_gap_s=round(gaps.largest_s, 6), livedata_lines=lines.n_lines,
                  vts_offset_spread_ms=(offsets[2] - offsets[1]) / 1e3 if offsets else None)


# --- the writer ---------------------------------------------------------------------------------

def _tslv_camera_record(cam: GlassesCamera) -> bytes:
    K, d = cam.camera_matrix, cam.dist_coeffs
    payload = TSLV_CAMERA.pack(4, 0, *cam.position_mm, *cam.rotation.ravel(), K[0, 0], K[1, 1], K[0, 1], K[0, 2],
                               K[1, 2], d[0], d[1], d[4], d[2], d[3], 0.0, *cam.image_size)
    return TSLV_HEADER.pack(300, 0, len(payload)) + payload


def _sample_lines(gidx: int, ts: int, g: dict, i: int, gp) -> list[str]:
    out = []
    for side in ("left", "right"):
        o, d, v = (a[i] for a in g[side])
        s = 0 if v else 16
        o, d = (o, d) if v else ((0, 0, 0), (0, 0, 0))
        out += [f'{{"ts":{ts},"s":{s},"gidx":{gidx},"pc":[{o[0]:.2f},{o[1]:.2f},{o[2]:.2f}],"eye":"{side}"}}',
                f'{{"ts":{ts},"s":{s},"gidx":{gidx},"pd":{3.5 if v else 0:.2f},"eye":"{side}"}}',
                f'{{"ts":{ts},"s":{s},"gidx":{gidx},"gd":[{d[0]:.4f},{d[1]:.4f},{d[2]:.4f}],"eye":"{side}"}}']
    p, q = g["gaze3d"][i], gp[i]
    s = 0 if np.all(np.isfinite(p)) and np.all(np.isfinite(q)) else 1
    p, q = (p, q) if s == 0 else ((0, 0, 0), (0, 0))
    out += [f'{{"ts":{ts},"s":{s},"gidx":{gidx},"l":20000,"gp":[{q[0]:.4f},{q[1]:.4f}]}}',
            f'{{"ts":{ts},"s":{s},"gidx":{gidx},"gp3":[{p[0]:.2f},{p[1]:.2f},{p[2]:.2f}]}}']
    return out


def write_recording(sim, dst: Path) -> None:
    """Write a simulated session as a G2 recording folder ``dst`` (``recording.json``,
    ``segments/1/{livedata.json.gz, et.tslv.gz, fullstream.mp4}``): the unit's camera is the G2
    sample's rotation with position 0 and the simulation's intrinsics; ts = 84 s + t (us); a sync
    pair (vts) every 16th video frame; an invalid eye is written with status 16 and zeros, as the
    device does. Values are rounded as the device rounds them (pc, gp3 0.01 mm; gd, gp 1e-4)."""
    dst = Path(dst)
    seg = dst / "segments" / "1"
    seg.mkdir(parents=True, exist_ok=True)
    cam = writer_camera(sim, np.zeros(3))
    g = sim_in_glasses(sim, t_cam_from_glasses(cam))
    gp = project_norm(np.nan_to_num(sim.gaze_head_mm, nan=1.0), cam)
    gp[~np.all(np.isfinite(sim.gaze_head_mm), axis=1)] = np.nan
    ts = WRITER_TS_OFFSET_US + np.round(np.asarray(sim.t) * 1e6).astype(np.int64)
    vts = np.round(np.asarray(sim.frame_times)[::16] * 1e6).astype(np.int64)
    k = 0
    with gzip.open(seg / "livedata.json.gz", "wt", encoding="utf-8") as fh:
        for i, tsi in enumerate(ts):
            while k < len(vts) and vts[k] + WRITER_TS_OFFSET_US <= tsi:
                fh.write(f'{{"ts":{vts[k] + WRITER_TS_OFFSET_US},"s":0,"vts":{vts[k]}}}\n')
                k += 1
            fh.write("\n".join(_sample_lines(1000 + i, int(tsi), g, i, gp)) + "\n")
    with gzip.open(seg / "et.tslv.gz", "wb") as fh:
        fh.write(TSLV_HEADER.pack(10, 0, 6) + b"\x01\x02\x03\x04\x05\x06\x00\x00")   # another record first
        fh.write(_tslv_camera_record(cam))
    shutil.copyfile(sim.video, seg / "fullstream.mp4")
    n_valid = int(np.sum(np.isfinite(gp[:, 0])))
    (dst / "recording.json").write_text(json.dumps(
        {"rec_id": "sim", "rec_info": {"Name": "simulated"}, "rec_segments": 1,
         "rec_length": int(np.ceil(sim.t[-1] - sim.t[0])), "rec_et_samples": len(ts),
         "rec_et_valid_samples": n_valid}, indent=4) + "\n", encoding="utf-8")
    (seg / "segment.json").write_text(json.dumps({"seg_id": 1, "seg_length_us": int(ts[-1] - ts[0])}) + "\n",
                                      encoding="utf-8")
