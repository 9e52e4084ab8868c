"""The second real Tobii Pro Glasses 2 recording (gazeMapper example 2, ``data/lead/``; its
PROVENANCE.md) through ``import`` and ``process`` (issue 25): its export and report used to fail
because target_paths.csv was written with a path covariance of 4.9e10 mm^2 that its own reader
refused (the reader's bound was one for mm, not mm^2); now every step succeeds, exit 0."""

import csv
import json
import statistics
from pathlib import Path

import numpy as np
import pytest

from estimator.merge import STILL_HEAD_MERGE_S
from wearable_gaze.cli import main
from wearable_gaze.formats.gaze_export import read_gaze_csv
from wearable_gaze.formats.outputs import check_output
from wearable_gaze.formats.targets import read_target_paths, read_targets
from wearable_gaze.pipeline.steps import fixations

G2B = Path("gazemapper_example2")
FPS = 25.0          # coding.tsv counts scene-video frames at 25 fps; session time is scene-video time


@pytest.fixture(scope="module")
def g2b(tmp_path_factory, real_data_module):
    lead = real_data_module / G2B / "data" / "lead"
    if not (lead / "ixinraw" / "project.json").is_file():
        pytest.skip(f"{lead}/ixinraw: the second G2 recording (gazeMapper example 2) is not there")
    base = tmp_path_factory.mktemp("g2b")
    assert main(["import", str(lead / "ixinraw"), "-o", str(base / "s")]) == 0
    merged = fixations.merge_fixations
    with pytest.MonkeyPatch.context() as mp:         # the merge's inputs kept for the test below
        mp.setattr(fixations, "merge_fixations", lambda *a: MERGE_INPUTS.append(a) or merged(*a))
        rc = main(["process", str(base / "s")])
    return base / "s", rc


MERGE_INPUTS = []


def test_the_second_g2_recording_is_processed_with_no_failed_step(g2b, capsys):
    s, rc = g2b
    out = s / "processed"
    assert rc == 0
    assert (out / "gaze.csv").is_file() and (out / "report.html").is_file()
    for p in sorted(out.iterdir()):
        if p.suffix in (".csv", ".json"):
            check_output(p)                      # every value as its writer checked it
    # every path read back as written; the case that broke it (a knot's covariance beyond MAX_ABS,
    # 4.9e10 mm^2 on this recording before issue 27's segmentation) depends on how the fixations
    # fall, so it is planted in test_process_status's
    # test_a_writer_refuses_what_its_reader_would_and_a_path_covariance_in_mm2_is_read_back
    paths = read_target_paths(out / "target_paths.csv")
    assert paths and all(np.all(np.isfinite(c)) for _, _, c in paths.values())
    assert len(read_gaze_csv(out / "gaze.csv")["sample"]) == 6048         # every eye sample kept


def test_the_second_g2_targets_during_validation_are_at_the_poster(g2b, real_data_module):
    """The targets estimated during the coded Validate episode (the poster at a nominal 60 cm;
    the device's own gp3 depth there has median 591 mm, PROVENANCE.md) are at arm's length."""
    s, _ = g2b
    with open(real_data_module / G2B / "coding" / "lead" / "coding.tsv", newline="") as fh:
        rows = [r for r in csv.reader(fh, delimiter="\t") if r and r[0] == "Validate"]
    start, end = (float(v) / FPS for v in rows[0][1:3])
    ok = [t["depth"]["distance_mm"] for t in read_targets(s / "processed" / "targets.json")
          if start <= t["t_start"] and t["t_end"] <= end and t["status"] == "ok"]
    assert len(ok) >= 5 and 450 < statistics.median(ok) < 750, ok


def test_the_recordings_parent_folder_imports_the_one_recording_in_it_and_says_so(real_data, tmp_path, capsys):
    """Issue 26: data/lead/ holds the G2 project ixinraw/: that folder is read, and the import says
    which."""
    lead = real_data / G2B / "data" / "lead"
    if not lead.is_dir():
        pytest.skip(f"{lead}: the second G2 recording (gazeMapper example 2) is not there")
    assert main(["import", str(lead), "-o", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "holds one recording, ixinraw/" in out, out
    rep = json.loads((tmp_path / "s" / "import_report.json").read_text())
    assert rep["device"] == "tobii-g2" and any("ixinraw" in n for n in rep["notes"])


def test_the_linear_merge_gives_the_full_reruns_groups_on_the_recording(g2b):
    """Issue 27: the targets step's merge (each target's test and estimate kept as a form and an
    estimator fed each fixation's own lines) groups this recording's fixations (a still head, so
    depth from vergence alone, 1 deg noise) as the full re-run does (every group's lines tested
    and estimated again on each join), and each target's estimate lies within 0.1 sd of the full
    re-run's (per axis of its covariance). The form quadratic in the point's position (not its
    inverse depth) grouped them otherwise: 4 targets in the Validate episode where the full
    re-run has 9."""
    from tests.test_merge_linear import _sd_frame_error, full_rerun_groups

    assert len(MERGE_INPUTS) == 1
    fixes, samples, method, sigma_deg, error_model, within_s = MERGE_INPUTS[0]
    assert within_s == STILL_HEAD_MERGE_S                # no head poses: revisits merged within it only
    ref = full_rerun_groups(fixes, samples, method, sigma_deg, error_model, within_s)
    groups = fixations.merge_fixations(fixes, samples, method, sigma_deg, error_model, within_s)
    assert [g.fixations for g in groups] == [m for m, _ in ref]
    for g, (_, e) in zip(groups, ref, strict=True):
        assert np.all(_sd_frame_error(g.estimate.position_mm, e.position_mm, e.covariance_mm2) < 0.1)
