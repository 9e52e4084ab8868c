"""The report of the real samples in headless Chromium (issue 28; Debian's chromium driven by
playwright, skipped without them or without the data): the real Tobii G2 (12 targets, its
poster's areas of interest) and the real Aria gen1 import (its SLAM point cloud, areas on its
floor): no console error, the areas and the point cloud drawn in the 3D view, every target in a
colour of its own in the legend, the table and the view, and no video element where the session
has no scene video. The simulated session's overlay video plays: tests/test_process.py."""

import json

import numpy as np
import pytest
from conftest import AOIS

from tests.helpers import chromium_page, color_pixels, screenshot_bgr
from wearable_gaze.pipeline.steps.aoi import AOI_COLOR

ARIA = "aria_mps_sample_gen1"


@pytest.fixture(scope="module")
def aria_processed(tmp_path_factory, real_data_module):
    """The real Aria gen1 sample imported and processed with areas on its floor (tests/data/aois)."""
    from wearable_gaze.pipeline.importer import import_recording
    from wearable_gaze.pipeline.process.session import process_session

    if not (real_data_module / ARIA).is_dir():
        pytest.skip(f"the real Aria sample is not at {real_data_module / ARIA}")
    base = tmp_path_factory.mktemp("aria")
    import_recording(real_data_module / ARIA, base / "s")
    return base, process_session(base / "s", base / "out", aois=AOIS / "aria_gen1_mps_sample.json")


def browse(report) -> dict:
    """What headless Chromium shows of ``report``: console errors, the 3D view's scene and what
    each of its layers drew, the colours of the legend's and the table's swatches, the canvas
    as an image (BGR), the number of video elements."""
    swatches = "els => els.map(e => getComputedStyle(e).backgroundColor)"
    with chromium_page(report) as (page, seen):
        page.wait_for_function("document.body.dataset.images !== undefined")
        canvas = page.locator("#view3d")
        canvas.scroll_into_view_if_needed()
        got = {"errors": seen["errors"], "images": page.evaluate("document.body.dataset.images"),
               "scene": json.loads(page.text_content("#view3d-data")),
               "drawn": {k: int(canvas.get_attribute(f"data-drawn{k}") or -1) for k in ("", "-points", "-aois")},
               "legend": page.eval_on_selector_all("p.legend .swatch", swatches),
               "table": page.eval_on_selector_all("#targets .swatch", swatches),
               "videos": page.eval_on_selector_all("video", "els => els.length"),
               "shot": screenshot_bgr(canvas)}
    return got


def _rgb(css: str) -> str:
    """'rgb(r, g, b)' as '#rrggbb'."""
    return "#" + "".join(f"{int(v):02x}" for v in css[css.index("(") + 1:-1].split(","))


def _lab_distance(colors: list) -> float:
    """The least CIE76 colour difference between two of ``colors`` ('#rrggbb'; 2.3 is one just
    noticeable difference, over 10 two colours no one confuses side by side)."""
    import cv2

    rgb = np.array([[[int(c[k:k + 2], 16) for k in (1, 3, 5)] for c in colors]], np.uint8)
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB)[0].astype(float)
    lab[:, 0] *= 100 / 255
    lab[:, 1:] -= 128
    return min(float(np.linalg.norm(a - b)) for i, a in enumerate(lab) for b in lab[i + 1:])


def _check_targets(got: dict, n: int) -> None:
    """``n`` targets, each in a colour of its own, the same in the legend, the table and the view."""
    colors = [t["colour"] for t in got["scene"]["targets"]]
    assert len(colors) == n and len(set(colors)) == n, colors
    assert n < 2 or _lab_distance(colors) > 10
    assert [_rgb(c) for c in got["legend"]] == colors and [_rgb(c) for c in got["table"]] == colors
    for t in got["scene"]["targets"]:
        assert color_pixels(got["shot"], t["colour"], tol=20) >= 10, t["label"]


def test_real_tobii_g2_report_draws_its_poster_areas_and_twelve_targets_apart(g2_processed):
    base, res = g2_processed
    got = browse(base / "out" / "report.html")
    loaded, total = map(int, got["images"].split("/"))
    assert got["errors"] == [] and loaded == total >= 7                # with the AOI dwell and timeline plots
    _check_targets(got, 12)
    names = json.loads((AOIS / "tobii_g2_glassesvalidator_poster.json").read_text())["aois"]
    assert [a["name"] for a in got["scene"]["aois"]] == [a["name"] for a in names]
    assert got["drawn"]["-aois"] >= 9 * 4 and color_pixels(got["shot"], AOI_COLOR) > 50
    assert got["videos"] == 0                                        # no scene video, no overlay


def test_real_aria_report_draws_its_point_cloud_and_floor_areas(aria_processed):
    base, res = aria_processed
    got = browse(base / "out" / "report.html")
    assert got["errors"] == []
    _check_targets(got, len(res.targets))
    assert got["drawn"]["-points"] > 1000 and got["drawn"]["-aois"] > 0
    assert [a["name"] for a in got["scene"]["aois"]] == ["floor", "low surface", "ceiling (nobody)"]
    assert got["videos"] == 0
