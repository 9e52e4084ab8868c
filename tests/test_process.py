"""``wearable-gaze process`` end to end (issue 6): targets found and accurate on a session the
code has not seen, every output written, re-runs skip unchanged steps, bad input is reported
and does not stop the steps that can run, the report loads in a headless browser."""

import json
import re
import shutil

import numpy as np

from tests.helpers import chromium_page, color_pixels, screenshot_bgr
from wearable_gaze.cli import main
from wearable_gaze.formats.tables import read_table
from wearable_gaze.pipeline.report.truth_match import match_targets

# the fixture ``processed`` (tests/conftest.py): a simulated session processed once per test run


def test_every_fixated_target_is_found_near_the_bound(processed):
    root, out, res = processed
    assert res.problems == []
    truth = json.loads((root / "truth" / "targets.json").read_text())["targets"]
    fixated = [t for t in truth if sum(b - a for a, b in t["fixations_s"]) >= 1.0]
    pairs = match_targets(res.targets, fixated)
    assert len(pairs) == 3 and all(f is not None for _, f in pairs)
    for tt, f in pairs:
        err = np.linalg.norm(np.array(f["position_mm"]) - tt["position_mm"])
        # one draw per target here; the 1.5x criterion is on the RMS over many sessions
        # (benchmarks/process_accuracy.py), a single error passes 3x but for 1 % of draws
        assert err < 3.0 * f["crb_mm"], (tt["index"], err, f["crb_mm"])
    assert len(res.targets) == len(fixated)               # no spurious targets


def test_outputs_are_written_in_their_formats(processed):
    _, out, res = processed
    for name in ("camera.json", "eyes.json", "poses.csv", "viewlines.csv", "estimates.csv", "targets.csv",
                 "summary.json", "report.html", "plot_depth_vs_observations.png", "plot_density_slices.png",
                 "plot_3d.png", "plot_top_view.png", "overlay.mp4"):
        assert (out / name).is_file(), name
    vl = read_table(out / "viewlines.csv", ["t", "segment"])
    assert set(np.unique(vl["segment"])) >= {0, 1, 2}
    tg = read_table(out / "targets.csv", ["x_mm", "y_mm", "z_mm", "ellipsoid95_r1_mm", "ellipsoid95_r2_mm",
                                          "ellipsoid95_r3_mm", "cov_zz_mm2", "n_samples", "t_start", "t_end", "crb_mm"],
                    ("fixations", "method", "status"))
    assert len(tg["x_mm"]) == len(res.targets) and set(tg["method"]) == {"voxel"}
    est = read_table(out / "estimates.csv", ["t", "segment", "x", "y", "z", "radius95_mm"])
    assert np.all(np.diff(est["t"][est["segment"] == 0]) > 0)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["targets"] == res.targets and summary["problems"] == []
    # the running estimate converges: its last value is the target's fixation estimate
    assert est["radius95_mm"][est["segment"] == 0][-1] < est["radius95_mm"][est["segment"] == 0][0]


def test_report_in_headless_chromium_loads_shows_the_truth_and_a_3d_view_that_turns(processed):
    """The report in Debian's chromium (driven by playwright, never its own browsers): every
    image loads, no console error, no request leaves the machine, the truth columns are there,
    the 3D view draws the targets in their legend's colours and turns when dragged, and the
    overlay video (H.264) plays: its readyState reaches 4 and its time advances."""
    _, out, res = processed
    with chromium_page(out / "report.html") as (page, seen):
        page.wait_for_function("document.body.dataset.images !== undefined")
        loaded, total = map(int, page.evaluate("document.body.dataset.images").split("/"))
        headers = page.eval_on_selector_all("#targets th", "els => els.map(e => e.textContent)")
        col = {h: k + 1 for k, h in enumerate(headers)}
        errs = page.eval_on_selector_all(f"#targets tr td:nth-child({col['error (mm)']})",
                                         "els => els.map(e => e.textContent)")
        k = col["distance from where it was seen (m): estimate (68 % / 95 % intervals)"]
        depth = page.eval_on_selector_all(f"#targets tr td:nth-child({k})", "els => els.map(e => e.textContent)")
        scene = json.loads(page.text_content("#view3d-data"))
        canvas = page.locator("#view3d")
        canvas.scroll_into_view_if_needed()
        drawn = int(canvas.get_attribute("data-drawn"))
        shot = screenshot_bgr(canvas)
        box = canvas.bounding_box()
        page.mouse.move(box["x"] + 300, box["y"] + 200)
        page.mouse.down()
        page.mouse.move(box["x"] + 450, box["y"] + 260, steps=5)
        page.mouse.up()
        turned = screenshot_bgr(canvas)
        page.evaluate("document.getElementById('overlay').play()")
        page.wait_for_function("(() => { const v = document.getElementById('overlay'); "
                               "return v.readyState === 4 && v.currentTime > 0.5; })()", timeout=20000)
        video = page.evaluate("(() => { const v = document.getElementById('overlay'); "
                              "return [v.duration, v.videoWidth]; })()")
    assert seen["errors"] == [] and seen["remote"] == []
    assert loaded == total and total >= 5                                     # the plots
    assert video[0] > 10.0 and video[1] == 640                  # the whole 12 s session (PROCESS_SCENARIO), 640 px
    for h in ("true position x, y, z (mm)", "error (mm)", "error / bound", "Cramér-Rao bound (mm)"):
        assert h in headers
    assert len(errs) == len(res.targets) and all(re.fullmatch(r"\d+\.\d", e) for e in errs), errs
    iv = r"\d+\.\d\d–(\d+\.\d\d|∞)"
    assert depth and all(re.fullmatch(rf"\d+\.\d\d \({iv} / {iv}\)", x) for x in depth), depth
    assert drawn > 100 and shot.std() > 10                                    # not blank
    assert len(scene["targets"]) == len(res.targets) and len(scene["markers"]) > 0
    for t in scene["targets"]:
        assert color_pixels(shot, t["colour"]) >= 15, t["label"]                 # each target in its colour
    assert np.mean(np.abs(turned.astype(int) - shot.astype(int))) > 1.0        # the drag turned the view


def _copy(root, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(root, dst, ignore=shutil.ignore_patterns("processed"))
    return dst


def test_a_corrupt_video_keeps_the_calibrations_and_says_why(processed, tmp_path, capsys):
    root, _, _ = processed
    s = _copy(root, tmp_path)
    (s / "scene.mp4").write_bytes(b"\x00" * 1000)
    assert main(["process", str(s), "-o", str(tmp_path / "out"), "--no-overlay"]) == 2
    err = capsys.readouterr().err
    assert "tracking:" in err and "Traceback" not in err
    assert (tmp_path / "out" / "camera.json").is_file() and (tmp_path / "out" / "eyes.json").is_file()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert any("tracking" in p for p in summary["problems"])


def test_bad_eye_samples_get_one_clear_line(processed, tmp_path, capsys):
    root, _, _ = processed
    s = _copy(root, tmp_path)
    lines = (s / "eye.csv").read_text().splitlines()
    lines[5], lines[6] = lines[6], lines[5]                                 # unsorted
    (s / "eye.csv").write_text("\n".join(lines) + "\n")
    assert main(["process", str(s), "-o", str(tmp_path / "out"), "--no-overlay"]) == 2
    err = capsys.readouterr().err
    assert "sort" in err and "eye.csv line 7" in err
    assert (tmp_path / "out" / "poses.csv").is_file()                       # tracking still ran
    # samples outside the video's time span: no pose for them, said plainly
    shifted = [lines[0]] + [",".join([f"{float(r.split(',')[0]) + 500:.6f}"] + r.split(",")[1:]) for r in
                            sorted(lines[1:], key=lambda r: float(r.split(",")[0]))]
    (s / "eye.csv").write_text("\n".join(shifted) + "\n")
    assert main(["process", str(s), "-o", str(tmp_path / "out"), "--no-overlay"]) == 2
    assert "no head pose" in capsys.readouterr().err
    (s / "eye.csv").unlink()
    assert main(["process", str(s), "-o", str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "eye.csv" in err and "missing" in err
