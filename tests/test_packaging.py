"""The wheel a user installs (`pip install .`, not editable) holds every module and data file of
the source tree, and the console script points at the CLI. An editable install hides a missing
package, so this builds the real wheel."""

import configparser
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ["estimator", "calibration", "tracking", "wearable_gaze"]
DATA_SUFFIXES = {".json", ".js"}


def _source_files():
    """Every module and package-data file under the four packages, as wheel paths."""
    out = set()
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*"):
            if "__pycache__" in p.parts or not p.is_file():
                continue
            if p.suffix == ".py" or p.suffix in DATA_SUFFIXES:
                out.add(p.relative_to(ROOT).as_posix())
    return out


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    # build from a clean copy: setuptools reuses a stale build/ folder, which can hide a missing package
    src = tmp_path_factory.mktemp("src")
    for name in ["pyproject.toml", "README.md", *PACKAGES]:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy(ROOT / name, src / name)
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                           "-q", "-w", str(out), str(src)], capture_output=True, text=True)
    if proc.returncode != 0 and "No module named" in proc.stderr and "setuptools" in proc.stderr:
        pytest.skip("setuptools is not installed in this environment (pip install '.[test]' brings it)")
    assert proc.returncode == 0, proc.stderr[-2000:]
    wheels = list(out.glob("wearable_gaze-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def test_wheel_holds_every_module_of_the_source_tree(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = sorted(_source_files() - names)
    assert not missing, f"left out of the wheel: {missing}"
    # the subpackages a fixed package list once dropped
    assert "wearable_gaze/sim/simulate.py" in names and "wearable_gaze/live/app.py" in names


def test_wheel_installs_the_console_script(wheel):
    z = zipfile.ZipFile(wheel)
    (entry,) = [n for n in z.namelist() if n.endswith(".dist-info/entry_points.txt")]
    cp = configparser.ConfigParser()
    cp.read_string(z.read(entry).decode())
    assert cp["console_scripts"]["wearable-gaze"] == "wearable_gaze.cli:main"
    # and nothing but our four packages at the top level (no tests/, benchmarks/ in site-packages)
    tops = {n.split("/")[0] for n in z.namelist() if not n.split("/")[0].endswith(".dist-info")}
    assert tops == set(PACKAGES), tops


def _requirement_floors(lines) -> dict:
    """{name: version} of 'name>=version' (pyproject) or 'name==version' (a constraints file)."""
    import re

    out = {}
    for line in lines:
        m = re.match(r'\s*"?([A-Za-z0-9_.-]+)(?:\[[^\]]*\])?\s*(>=|==)\s*([0-9][0-9A-Za-z.]*)', line)
        if m:
            out[m.group(1).lower()] = m.group(3)
    return out


def test_the_floors_ci_installs_are_the_declared_minimum_versions():
    """constraints/floors.txt pins each dependency at exactly pyproject.toml's floor, so that what
    .ci/run tests at the low end is what the project declares; the lock file pins every
    dependency of the newest run."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib is in the standard library from Python 3.11")
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    declared = _requirement_floors(d.split(";")[0] for d in deps if "sys_platform != 'linux'" not in d)
    floors = _requirement_floors(ln for ln in (ROOT / "constraints" / "floors.txt").read_text().splitlines()
                                 if not ln.startswith("#"))
    assert declared == floors
    lock = _requirement_floors((ROOT / "constraints" / "lock.txt").read_text().splitlines())
    assert set(declared) <= set(lock) and lock["opencv-contrib-python-headless"].startswith("5.")
