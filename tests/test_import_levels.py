"""import from any folder level (formats/devices/__init__.py ``locate_recording``): the recording
itself, its parent when that holds exactly one recording, a folder inside it (a Tobii G2
``segments/1``), and a parent with several recordings (listed, exit 2). On the real samples in
../shared/data/real."""

import shutil

import pytest

from wearable_gaze.cli import main
from wearable_gaze.errors import UserError
from wearable_gaze.formats.devices import locate_recording
from wearable_gaze.pipeline.importer import import_recording

G2 = "glassesvalidator_tobii_g2_example"


@pytest.fixture
def g2(real_data):
    root = real_data / G2
    if not root.is_dir():
        pytest.skip(f"Tobii G2 sample not found at {root}")
    return root


def test_one_level_up_the_parent_holding_one_recording_is_read_and_the_report_says_so(g2, tmp_path):
    """glassesvalidator_tobii_g2_example/ holds the G2 project folder recording/ (and the poster's
    configuration, no recording): import reads recording/ and its report says which."""
    loc = locate_recording(g2)
    assert (loc.format, loc.folder) == ("tobii-g2", g2 / "recording") and "recording/" in loc.how
    manifest, rep = import_recording(g2, tmp_path / "s")
    assert rep["eye_samples_written"] == 940 and manifest["source"]["path"] == str((g2 / "recording").resolve())
    assert [n for n in rep["notes"] if "holds one recording" in n] == [loc.how]


def test_one_level_down_a_g2_segment_folder_finds_its_recording(g2, tmp_path):
    rec = g2 / "recording" / "recordings" / "t3ic6aq"
    for inside, up in ((rec / "segments" / "1", "2 levels up"), (rec / "segments", "1 level up")):
        loc = locate_recording(inside)
        assert (loc.format, loc.folder.resolve()) == ("tobii-g2", rec.resolve()) and up in loc.how
    assert locate_recording(rec / "segments" / "1", "tobii-g2").folder.resolve() == rec.resolve()  # --format given
    assert locate_recording(g2 / "recording" / "recordings").folder == rec           # the one below
    manifest, rep = import_recording(rec / "segments" / "1", tmp_path / "s")
    assert rep["eye_samples_written"] == 940 and any("2 levels up" in n for n in rep["notes"])


def test_a_copied_gen2_folder_is_found_from_its_parent_and_an_aria_subfolder_from_inside(real_data, tmp_path):
    src = real_data / "aria_gen2_mps_eye_gaze"
    if not src.is_dir():
        pytest.skip(f"Aria Gen2 sample not found at {src}")
    shutil.copytree(src, tmp_path / "parent" / "gen2")
    (tmp_path / "parent" / "notes").mkdir()
    _, rep = import_recording(tmp_path / "parent", tmp_path / "s")
    assert rep["device"] == "aria-gen2" and any("holds one recording, gen2/" in n for n in rep["notes"])
    gen1 = real_data / "aria_mps_sample_gen1"
    if gen1.is_dir():
        loc = locate_recording(gen1 / "trajectory")
        assert (loc.format, loc.folder.resolve()) == ("aria-mps", gen1.resolve())


def test_a_parent_with_several_recordings_lists_them_and_asks_for_one(real_data, tmp_path, capsys):
    for name in ("aria_gen2_mps_eye_gaze", "eyedentify3d_tobii_g3"):
        if not (real_data / name).is_dir():
            pytest.skip(f"{name} not found in {real_data}")
        shutil.copytree(real_data / name, tmp_path / "two" / name)
    with pytest.raises(UserError, match=r"holds 2 recordings \(aria_gen2_mps_eye_gaze \(aria-gen2\), "
                                        r"eyedentify3d_tobii_g3 \(tobii-g3\)\); pass one of them"):
        locate_recording(tmp_path / "two")
    assert main(["import", str(real_data), "-o", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "recordings (" in err and "eyedentify3d_tobii_g3 (tobii-g3)" in err
    assert not (tmp_path / "s").exists()
    (tmp_path / "a" / "b").mkdir(parents=True)                   # no recording at any level: as before
    with pytest.raises(UserError, match="none of the known formats"):
        locate_recording(tmp_path / "a")

