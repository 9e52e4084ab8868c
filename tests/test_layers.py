"""The design's layering: estimator < calibration < tracking < wearable_gaze, and the three
libraries do no printing (they report through return values, logging and callbacks)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["estimator", "calibration", "tracking", "wearable_gaze"]


def _imports(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name.split(".")[0], node.lineno
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module.split(".")[0], node.lineno


@pytest.mark.parametrize("package", ORDER)
def test_no_package_imports_one_above_it(package):
    above = set(ORDER[ORDER.index(package) + 1:])
    bad = [f"{p.relative_to(ROOT)}:{line} imports {mod}"
           for p in (ROOT / package).rglob("*.py") for mod, line in _imports(p) if mod in above]
    assert not bad, bad


@pytest.mark.parametrize("package", ORDER[:3])
def test_libraries_do_not_print(package):
    bad = []
    for p in (ROOT / package).rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("print", "open", "input"):
                bad.append(f"{p.relative_to(ROOT)}:{node.lineno} calls {node.func.id}")
    assert not bad, bad
