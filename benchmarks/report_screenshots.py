"""Screenshots of report.html in headless Chromium (Debian's /usr/bin/chromium, driven by
playwright; never a browser of playwright's own): the targets' table, the 3D view the reader
turns (as it opens, and turned from above) and the still plots (3D, top view), each as a PNG, for
the eye to check that the credible regions and the axes fit the scene (issue 27).

    python benchmarks/report_screenshots.py [--demo] [--aria] [--out /work/tmp/shots]
        [--report DIR/report.html --name NAME ...]

``--demo`` runs ``wearable-gaze demo`` into a fresh folder; ``--aria`` imports the real Aria gen1
MPS sample (``../shared/data/real/aria_mps_sample_gen1``) and processes it; ``--report`` shoots a
report already made. Each set of shots is ``OUT/NAME_{page,table,view3d,view3d_above,plot_3d,
plot_top_view}.png``; the scene's box and each target's region are printed.
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


def make_aria(work: Path) -> Path:
    """report.html of the real Aria gen1 MPS sample, imported and processed in ``work``."""
    src = REAL / "aria_mps_sample_gen1"
    if not src.is_dir():
        raise SystemExit(f"{src}: not there; set WEARABLE_GAZE_REAL_DATA to the folder of the real recordings")
    cli("import", str(src), "-o", str(work / "aria"))
    cli("process", str(work / "aria"), "-o", str(work / "aria" / "out"))
    return work / "aria" / "out" / "report.html"


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
        finally:
            browser.close()
    for plot in ("plot_3d.png", "plot_top_view.png"):
        if (report.parent / plot).is_file():
            shots.append(out / f"{name}_{plot}")
            shutil.copyfile(report.parent / plot, shots[-1])
    print(f"{name}: {report}")
    print(f"  console errors: {errors or 'none'}")
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
    if args.aria:
        jobs.append((make_aria(work), "aria"))
    for report, name in jobs:
        for s in shoot(report, name, args.out):
            print(f"  {s}")


if __name__ == "__main__":
    main()
