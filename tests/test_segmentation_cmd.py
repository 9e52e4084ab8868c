"""Segmentation as its own step and command (issue 15): ``viewlines`` -> ``fixations`` ->
``estimate --targets`` gives the targets of ``process`` on the same session; segment -1 is never
estimated; an unsegmented file of several fixations is not silently estimated as one point."""

import json
import shutil

import numpy as np
import pytest

from estimator import BinocularSamples
from estimator.segments import SegmentConfig
from wearable_gaze.cli import main
from wearable_gaze.formats.tables import read_table
from wearable_gaze.formats.viewlines import write_viewlines_csv
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.steps.segmentation import fixations_file, measured_rate_hz, segment_config
from wearable_gaze.sim.protocol import simulate_lines
from wearable_gaze.sim.simulate import simulate_scenario

SCENARIO = {"base": "lab-walkabout", "duration_s": 8.0,
            "room": {"size_mm": [4500.0, 2700.0, 5500.0], "markers_per_wall": 5},
            "targets": {"random_count": 3, "random_depth_mm": [700.0, 3000.0]},
            "eyes": {"fixation_s": [1.6, 2.4]},
            "calibration": {"camera_views": 10}}
"""Four fixations in 8 s, the first target's seen again at the end: a revisit to merge."""


@pytest.fixture(scope="module")
def steps(tmp_path_factory):
    """A short walkabout processed by ``process`` (ml), then the same session step by step with
    process's eyes.json and poses.csv: ``viewlines`` and ``fixations``."""
    base = tmp_path_factory.mktemp("segcmd")
    s, out = base / "s", base / "out"
    simulate_scenario(SCENARIO, s, seed=5)
    shutil.copy(s / "truth" / "camera.json", base / "camera.json")
    res = process_session(s, out, method="ml", camera=base / "camera.json", overlay=False, report=False)
    assert res.problems == []
    vl, fx = base / "vl.csv", base / "fx.csv"
    assert main(["viewlines", str(s / "eye.csv"), "--eyes", str(out / "eyes.json"), "--poses",
                 str(out / "poses.csv"), "-o", str(vl)]) == 0
    assert main(["fixations", str(vl), "-o", str(fx)]) == 0
    return base, out, vl, fx


def _labels(path) -> np.ndarray:
    """The segment column of a view-line CSV, row by row."""
    return np.asarray(read_table(path, ["segment"])["segment"], float)


def _json_lines(capsys):
    return [json.loads(ln) for ln in capsys.readouterr().out.splitlines() if ln.strip()]


def test_step_by_step_gives_the_targets_of_process(steps, capsys):
    base, out, vl, fx = steps
    capsys.readouterr()
    assert main(["estimate", str(fx), "--targets", "--method", "ml", "--json"]) == 0
    got = _json_lines(capsys)
    want = json.loads((out / "targets.json").read_text())["targets"]
    assert any(len(t["fixations"]) > 1 for t in want), "the session must have a revisit to merge"
    targets = [r for r in got if "target" in r]
    assert len(targets) == len(want) >= 3
    for g, w in zip(targets, want, strict=True):
        assert np.allclose(g["position_mm"], w["position_mm"], rtol=0, atol=1e-6)
        assert g["fixations"] == w["fixations"]
        assert list(g) == [*w, "covariance_model"]           # one record: targets.json's fields, in its order
        assert np.shape(g["covariance_mm2"]) == np.shape(w["covariance_mm2"]) == (3, 3)   # (error models differ)
        assert (g["n_samples"], g["status"], g["t_start"], g["t_end"]) == (w["n_samples"], w["status"],
                                                                            w["t_start"], w["t_end"])
    # the segmentation is process's own: the same labels, row for row
    assert fx.read_bytes() == (out / "viewlines.csv").read_bytes()
    skipped = [r for r in got if r.get("status") == "skipped"]
    labels = _labels(fx)
    assert len(skipped) == 1 and skipped[0]["n_samples"] == int((labels == -1).sum()) > 0


def test_segment_minus_one_is_never_estimated(steps, capsys):
    base, out, vl, fx = steps
    capsys.readouterr()
    assert main(["estimate", str(fx), "--method", "ml", "--json"]) == 0
    got = _json_lines(capsys)
    labels = _labels(fx)
    estimated = [r for r in got if r["status"] != "skipped"]
    assert sorted(r["segment"] for r in estimated) == list(range(int(labels.max()) + 1))
    (minus,) = [r for r in got if r["segment"] == -1]
    assert minus["status"] == "skipped" and minus["position_mm"] is None
    assert minus["n_samples"] == int((labels == -1).sum())
    assert main(["estimate", str(fx), "--method", "ml"]) == 0
    cap = capsys.readouterr()
    assert "skipped" not in cap.out and cap.err.count("\n") == 1
    assert f"{minus['n_samples']} row(s) of segment -1" in cap.err


def test_unsegmented_file_of_several_fixations_is_refused_unless_one_point(steps, capsys):
    base, out, vl, fx = steps
    capsys.readouterr()
    assert main(["estimate", str(vl), "--method", "ml"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no segment column" in err and "wearable-gaze fixations" in err
    assert "--one-point" in err and "5 fixations" in err        # the truth's 5, each found
    assert main(["estimate", str(vl), "--method", "ml", "--targets"]) == 2
    assert "no segment column" in capsys.readouterr().err
    assert main(["estimate", str(vl), "--method", "ml", "--one-point", "--json"]) == 0
    (one,) = _json_lines(capsys)
    n_rows = len(vl.read_text().splitlines()) - 1
    assert one["segment"] is None and one["n_samples"] == n_rows
    assert main(["estimate", str(fx), "--method", "ml", "--one-point"]) == 2
    assert "has a segment column" in capsys.readouterr().err


def test_unsegmented_single_fixation_is_still_one_point(tmp_path, rng, capsys):
    s = simulate_lines([100.0, 0, 1200.0], rng)
    p = tmp_path / "one.csv"
    write_viewlines_csv(p, s)
    assert main(["estimate", str(p), "--method", "ml", "--json"]) == 0
    (one,) = _json_lines(capsys)
    assert one["status"] == "ok" and one["n_samples"] == len(s)
    assert np.linalg.norm(np.array(one["position_mm"]) - [100.0, 0, 1200.0]) < 100


def test_targets_need_fixation_labels(tmp_path, rng, capsys):
    a = simulate_lines([0, 0, 1500.0], rng)
    p = tmp_path / "named.csv"
    write_viewlines_csv(p, a, segment=["near"] * len(a))
    assert main(["estimate", str(p), "--targets"]) == 2
    err = capsys.readouterr().err
    assert "segment 'near'" in err and "wearable-gaze fixations" in err


def _two_fixations(rng, gap_s=0.0):
    """Two 1 s fixations 60 Hz apart by a 20 deg saccade (the second starts ``gap_s`` later)."""
    a = simulate_lines([0, 0, 1500.0], rng)
    b = simulate_lines([600.0, 0, 1500.0], rng)
    n = 60
    a, b = a.select(slice(0, n)), b.select(slice(0, n))
    t = np.arange(2 * n) / 60.0
    t[n:] += gap_s
    both = BinocularSamples.concatenate([a, b])
    return BinocularSamples(t, both.left_origin_mm, both.left_direction, both.right_origin_mm, both.right_direction,
                            both.left_valid, both.right_valid, both.frame)


def test_fixations_file_labels_two_fixations_and_the_saccade(tmp_path, rng):
    p, out = tmp_path / "in.csv", tmp_path / "out.csv"
    write_viewlines_csv(p, _two_fixations(rng))
    r = fixations_file(p, out, None)
    assert r["fixations"] == 2 and r["rows"] == 120 and 0 < r["unlabelled"] < 40
    assert r["config"]["window"] == 8 and abs(r["rate_hz"] - 60.0) < 1e-6
    seg = _labels(out)
    assert set(seg[:50]) <= {0, -1} and set(seg[70:]) <= {1, -1} and (seg[20:40] == 0).all()
    assert (seg[80:100] == 1).all()


def test_fixations_file_ends_a_fixation_at_a_time_gap_to_the_sample(tmp_path, rng):
    """The step on two 1 s fixations at 60 Hz, the second 0.4 s late (over ``max_gap_s`` 0.25;
    jump 40 deg: the 20 deg saccade is no cut here, only the gap is): samples 2-57 and 62-117,
    each stretch less ``trim_s`` 0.03 s at both ends (no time ties at 60 Hz) (issue 30, planted
    fault ``segment-gap-off-by-one``)."""
    p, out = tmp_path / "in.csv", tmp_path / "out.csv"
    write_viewlines_csv(p, _two_fixations(rng, gap_s=0.4))
    r = fixations_file(p, out, SegmentConfig(jump_deg=40.0, max_gap_s=0.25, trim_s=0.03))
    assert r["fixations"] == 2
    want = np.full(120, -1)
    want[2:58], want[62:118] = 0, 1
    np.testing.assert_array_equal(_labels(out), want)


def test_fixations_settings_and_rate(tmp_path, rng, capsys):
    p, out = tmp_path / "in.csv", tmp_path / "out.csv"
    write_viewlines_csv(p, _two_fixations(rng))
    assert main(["fixations", str(p), "-o", str(out), "--eye-rate-hz", "10"]) == 0
    assert "window 2 samples (10 Hz)" in capsys.readouterr().out
    assert main(["fixations", str(p), "-o", str(out), "--eye-rate-hz", "10", "--window", "5", "--jump-deg", "40",
                 "--min-fixation-s", "0.2", "--max-gap-s", "0.25"]) == 0
    text = capsys.readouterr().out
    assert "window 5 samples" in text and "jump 40 deg" in text and "0.2 s or more" in text
    assert "1 fixation(s)" in text          # 20 deg is no saccade at a 40 deg threshold
    write_viewlines_csv(p, _two_fixations(rng, gap_s=0.4))
    assert main(["fixations", str(p), "-o", str(out), "--jump-deg", "40", "--max-gap-s", "0.25"]) == 0
    assert "2 fixation(s)" in capsys.readouterr().out     # but a 0.4 s gap ends one


def test_segment_config_follows_the_rate_and_overrides():
    assert segment_config(None) == SegmentConfig()
    assert segment_config(10.0).window == 2 and segment_config(200.0).window == 8
    assert segment_config(10.0, {"window": 6, "jump_deg": 5.0}) == SegmentConfig(window=6, jump_deg=5.0)
    with pytest.raises(ValueError, match="unknown"):
        segment_config(60.0, {"windw": 3})
    assert measured_rate_hz(np.array([0.0, 0.1, 0.2, 0.5, 0.6])) == pytest.approx(10.0)
    assert measured_rate_hz(np.array([1.0])) is None
