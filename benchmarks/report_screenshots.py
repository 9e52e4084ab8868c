"""Screenshots of report.html in headless Chromium (Debian's /usr/bin/chromium, driven by
playwright; never a browser of playwright's own): the targets' table, the 3D view the reader
turns (as it opens, and turned from above) and the still plots (3D, top view, the AOI plots),
each as a PNG, for the eye to check that the credible regions, the areas of interest, the point
cloud and the axes fit the scene (issues 27, 28); and the checks issue 28 asks for, printed:
console errors, the areas and the point cloud drawn, every target in a colour of its own, the
overlay video playing (its readyState reaches 4 and its time advances).

    python benchmarks/report_screenshots.py [--demo] [--g2] [--aria] [--out /work/tmp/shots]
        [--report DIR/report.html --name NAME ...]

``--demo`` runs ``wearable-gaze demo`` into a fresh folder; ``--g2`` imports the real Tobii G2
sample (``../shared/data/real/glassesvalidator_tobii_g2_example``, 12 targets) and processes it
with its poster's areas (tests/data/aois); ``--aria`` the real Aria gen1 MPS sample
(``aria_mps_sample_gen1``) with areas on its floor; ``--report`` shoots a report already made.
Each set of shots is ``OUT/NAME_{page,table,view3d,view3d_above,plot_3d,plot_top_view,
aoi_dwell,aoi_timeline}.png``; the scene's box and each target's region are printed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("WEARABLE_GAZE_REAL_DATA", REPO.parent / "shared" / "data" / "real"))
AOIS = REPO / "tests" / "data" / "aois"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def cli(*args: str) -> None:
    """``wearable-gaze ARGS`` in this checkout (stdout and stderr shown)."""
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    subprocess.run([sys.executable, "-m", "wearable_gaze", *args], check=True, env=env)


def make_demo(work: Path) -> Path:
    """report.html of ``wearable-gaze demo`` run into ``work``/demo."""
    cli("demo", "--out", str(work / "demo"))
    return work / "demo" / "processed" / "report.html"


def make_real(work: Path, name: str, rel: str, aois: str) -> Path:
    """report.html of the real sample ``rel`` (below the real data's folder), imported and
    processed in ``work``/``name`` with the AOI file ``aois`` (tests/data/aois)."""
    src = REAL / rel
    if not src.is_dir():
        raise SystemExit(f"{src}: not there; set WEARABLE_GAZE_REAL_DATA to the folder of the real recordings")
    cli("import", str(src), "-o", str(work / name))
    cli("process", str(work / name), "-o", str(work / name / "out"), "--aois", str(AOIS / aois))
    return work / name / "out" / "report.html"


def checks(page) -> dict:
    """Issue 28's checks of the open report: what the 3D view's layers drew, the colours of the
    targets (view, legend, table), and the overlay video's state after playing (None: none)."""
    canvas = page.locator("#view3d")
    swatches = "els => els.map(e => getComputedStyle(e).backgroundColor)"
    got = {"drawn": {k: canvas.get_attribute(f"data-drawn{k}") for k in ("", "-points", "-aois")},
           "legend": page.eval_on_selector_all("p.legend .swatch", swatches),
           "table": page.eval_on_selector_all("#targets .swatch", swatches), "video": None}
    if page.eval_on_selector_all("video#overlay", "els => els.length"):
        page.evaluate("document.getElementById('overlay').play()")
        page.wait_for_function("(() => { const v = document.getElementById('overlay'); "
                               "return v.readyState === 4 && v.currentTime > 0.5; })()", timeout=30000)
        got["video"] = page.evaluate("(() => { const v = document.getElementById('overlay'); "
                                     "return {readyState: v.readyState, currentTime: v.currentTime, "
                                     "duration: v.duration, width: v.videoWidth}; })()")
    return got


def shoot(report: Path, name: str, out: Path) -> list[Path]:
    """The screenshots of ``report`` as ``out``/``name``_*.png; the 3D view's scene summarised."""
    from playwright.sync_api import sync_playwright

    shots, errors = [], []
    with tempfile.TemporaryDirectory() as profile, sync_playwright() as p:
        browser = p.chromium.launch_persistent_context(profile, executable_path=CHROMIUM, args=CHROMIUM_ARGS,
                                                       viewport={"width": 1280, "height": 1000})
        try:
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(report.resolve().as_uri(), wait_until="load")
            page.wait_for_function("document.body.dataset.images !== undefined")
            shots.append(out / f"{name}_page.png")
            page.screenshot(path=shots[-1], full_page=True)
            shots.append(out / f"{name}_table.png")
            page.locator("#targets").screenshot(path=shots[-1])
            canvas = page.locator("#view3d")
            canvas.scroll_into_view_if_needed()
            shots.append(out / f"{name}_view3d.png")
            canvas.screenshot(path=shots[-1])
            box = canvas.bounding_box()
            page.mouse.move(box["x"] + box["width"] / 2, box["y"] + 100)
            page.mouse.down()
            page.mouse.move(box["x"] + box["width"] / 2, box["y"] + 200, steps=5)     # tilt to look from above
            page.mouse.up()
            shots.append(out / f"{name}_view3d_above.png")
            canvas.screenshot(path=shots[-1])
            scene = json.loads(page.text_content("#view3d-data"))
            found = checks(page)
        finally:
            browser.close()
    for plot in ("plot_3d.png", "plot_top_view.png", "aoi_dwell.png", "aoi_timeline.png"):
        if (report.parent / plot).is_file():
            shots.append(out / f"{name}_{plot}")
            shutil.copyfile(report.parent / plot, shots[-1])
    print(f"{name}: {report}")
    print(f"  console errors: {errors or 'none'}")
    colors = [t["colour"] for t in scene["targets"]]
    rgb = ["#" + "".join(f"{int(v):02x}" for v in c[c.index("(") + 1:-1].split(",")) for c in found["legend"]]
    print(f"  targets {len(colors)}, distinct colours {len(set(colors))}; legend the same: {rgb == colors}; "
          f"table swatches {len(found['table'])}")
    print(f"  3D view drew {found['drawn']['']} items: {found['drawn']['-points']} cloud points (scene "
          f"{len(scene['points'])}), {found['drawn']['-aois']} AOI segments ({len(scene.get('aois', []))} areas: "
          f"{', '.join(a['name'] for a in scene.get('aois', []))})")
    print(f"  overlay video: {found['video'] or 'none in the page'}")
    print(f"  3D view's box (mm): {scene.get('box')}")
    for t in scene["targets"]:
        r = t.get("region") or {}
        what = ("none" if not r else "open (a ray)" if r["open"] else "closed, cut at the box" if r["cut"]
                else "closed")
        far = r.get("far_mm") if r.get("far_mm") is not None else "no far end"
        print(f"  {t['label']}: position {t['position']}, region {what}"
              + (f", distance {r['near_mm']}-{far} mm, drawn to {r['end_mm']} mm" if r else ""))
    return shots


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", action="store_true", help="run 'wearable-gaze demo' and shoot its report")
    ap.add_argument("--g2", action="store_true", help="import and process the real Tobii G2 sample and shoot it")
    ap.add_argument("--aria", action="store_true", help="import and process the real Aria sample and shoot it")
    ap.add_argument("--report", type=Path, action="append", default=[], help="a report.html already made")
    ap.add_argument("--name", action="append", default=[], help="a name for each --report (default: report<k>)")
    ap.add_argument("--out", type=Path, default=Path("/work/tmp/shots"), help="folder of the PNGs")
    ap.add_argument("--work", type=Path, default=None, help="folder for the demo and the import (default: a "
                    "fresh temporary one, kept)")
    args = ap.parse_args()
    if not Path(CHROMIUM).is_file():
        raise SystemExit(f"{CHROMIUM}: not installed (apt-get install chromium)")
    args.out.mkdir(parents=True, exist_ok=True)
    work = args.work or Path(tempfile.mkdtemp(prefix="report_shots_"))
    jobs = [(r, args.name[k] if k < len(args.name) else f"report{k}") for k, r in enumerate(args.report)]
    if args.demo:
        jobs.append((make_demo(work), "demo"))
    if args.g2:
        jobs.append((make_real(work, "g2", "glassesvalidator_tobii_g2_example/recording",
                               "tobii_g2_glassesvalidator_poster.json"), "g2"))
    if args.aria:
        jobs.append((make_real(work, "aria", "aria_mps_sample_gen1", "aria_gen1_mps_sample.json"), "aria"))
    for report, name in jobs:
        for s in shoot(report, name, args.out):
            print(f"  {s}")


if __name__ == "__main__":
    main()
