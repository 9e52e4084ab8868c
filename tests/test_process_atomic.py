"""Atomic writes (wearable_gaze.formats.atomic), which every writer of ``process`` uses: a writer that
fails leaves no temporary file and the earlier file untouched; a killed writer's temporary file
is recognised by its exact pattern and nothing else is."""

import os

import pytest

from wearable_gaze.formats.atomic import atomic_path, remove_temporaries, write_text


@pytest.mark.parametrize("error", [RuntimeError("writer failed"), KeyboardInterrupt()])
def test_a_failing_writer_leaves_the_earlier_file_and_no_temporary(tmp_path, error):
    p = tmp_path / "targets.json"
    p.write_text("earlier")
    with pytest.raises(type(error)), atomic_path(p) as tmp:
        tmp.write_text("half of the new")
        raise error
    assert p.read_text() == "earlier" and os.listdir(tmp_path) == ["targets.json"]


def test_a_writer_that_never_writes_is_not_committed_on_error(tmp_path):
    p = tmp_path / "overlay.webp"
    with pytest.raises(ValueError), atomic_path(p):
        raise ValueError("the encoder refused the frames")
    assert os.listdir(tmp_path) == []


def test_success_replaces_the_file_with_the_usual_mode(tmp_path):
    p = tmp_path / "sub" / "summary.json"
    write_text(p, "new")
    umask = os.umask(0)
    os.umask(umask)
    assert p.read_text() == "new" and (p.stat().st_mode & 0o777) == 0o666 & ~umask
    assert os.listdir(p.parent) == ["summary.json"]


def test_remove_temporaries_takes_only_the_pattern_atomic_path_makes(tmp_path):
    gen = atomic_path(tmp_path / "overlay.webp")
    tmp = gen.__enter__()                      # a writer killed here: its temporary stays
    assert tmp.name.startswith(".overlay.webp.") and tmp.exists()
    odd = tmp_path / ".[x].csv.abcdefgh.csv"                # a name with glob characters: taken literally
    odd.write_text("")
    keep = [tmp_path / n for n in (".overlay.webp.notes", "overlay.webp.abcdefgh.webp", ".overlay.webp.abcdefgh.png",
                                   ".overlay.webp.ABCDEFGH.webp", ".x.csv.abcdefgh.csv", ".[x].csv.abcdefg.csv")]
    for p in keep:
        p.write_text("mine")
    removed = remove_temporaries(tmp_path, ["overlay.webp", "[x].csv", "targets.json"])
    assert sorted(removed) == sorted([tmp, odd]) and not tmp.exists() and not odd.exists()
    assert all(p.read_text() == "mine" for p in keep)
    with pytest.raises(FileNotFoundError):                 # the writer, were it to go on, finds it gone
        gen.__exit__(None, None, None)
