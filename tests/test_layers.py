"""The design's layering: estimator < calibration < tracking < wearable_gaze, the three libraries
do no printing (they report through return values, logging and callbacks), and inside the
application data flows one way: formats < sim < pipeline < live, paper < cli
(docs/architecture.md)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["estimator", "calibration", "tracking", "wearable_gaze"]

# Inside wearable_gaze: a module may import modules of a lower rank, and its own subpackage.
# Rank 0 holds the few modules everything may use (errors, progress bars, the version).
APP_RANK = {"__init__": 0, "errors": 0, "progress": 0, "formats": 1, "sim": 2, "pipeline": 3,
            "live": 4, "paper": 4, "cli": 5, "__main__": 6}


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


def _app_part(dotted: list) -> str:
    """'wearable_gaze.formats.session' -> 'formats'; 'wearable_gaze.cli' -> 'cli'."""
    return dotted[1] if len(dotted) > 1 else "__init__"


def _app_imports(path: Path):
    """(imported part of wearable_gaze, line) for every import of the application in ``path``."""
    rel = path.relative_to(ROOT).with_suffix("").parts
    pkg = list(rel[:-1]) if rel[-1] != "__init__" else list(rel[:-1])
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - node.level + 1]
                mod = base + (node.module.split(".") if node.module else [])
                if not node.module:                         # from . import x: x a module or a name
                    for a in node.names:
                        sub = ROOT.joinpath(*mod, a.name)
                        is_module = sub.with_suffix(".py").is_file() or sub.is_dir()
                        yield _app_part(mod + [a.name] if is_module else mod), node.lineno
                    continue
            elif node.module and node.module.split(".")[0] == "wearable_gaze":
                mod = node.module.split(".")
            else:
                continue
            yield _app_part(mod), node.lineno
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "wearable_gaze":
                    yield _app_part(a.name.split(".")), node.lineno


def test_every_part_of_the_application_has_a_rank():
    parts = {p.stem if p.is_file() else p.name for p in (ROOT / "wearable_gaze").iterdir()
             if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists()))}
    assert parts <= set(APP_RANK), f"give these a rank in APP_RANK and docs/architecture.md: {parts - set(APP_RANK)}"


def test_the_application_imports_only_downward():
    bad = []
    for p in (ROOT / "wearable_gaze").rglob("*.py"):
        own = _app_part(list(p.relative_to(ROOT).with_suffix("").parts))
        for part, line in _app_imports(p):
            if part != own and APP_RANK.get(part, 99) >= APP_RANK[own]:
                bad.append(f"{p.relative_to(ROOT)}:{line} ({own}) imports {part}")
    assert not bad, bad


def test_docs_architecture_names_every_module():
    """docs/architecture.md is where a newcomer finds the one file for each concept: every module
    of the four packages is named there."""
    doc = (ROOT / "docs" / "architecture.md").read_text()
    missing = [str(p.relative_to(ROOT)) for pkg in ORDER for p in (ROOT / pkg).rglob("*.py")
               if p.stem != "__init__" and p.name not in doc]
    assert not missing, f"name these in docs/architecture.md's table: {missing}"


MAX_FUNCTION_LINES = 60
"""The longest function (its whole ``def``, docstring included) docs/architecture.md allows."""


def test_no_module_over_500_lines_and_no_function_over_60():
    """Small modules and functions (docs/architecture.md): a module over 500 lines holds more than
    one concept, a function over 60 lines more than one step."""
    big = []
    for pkg in ORDER:
        for p in (ROOT / pkg).rglob("*.py"):
            src = p.read_text()
            rel = p.relative_to(ROOT)
            if len(src.splitlines()) > 500:
                big.append(f"{rel}: {len(src.splitlines())} lines")
            for node in ast.walk(ast.parse(src)):
                if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    continue
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    big.append(f"{rel}:{node.lineno} {node.name}: {lines} lines")
    assert not big, big


STEP_MODULES = ("pipeline/process/session.py", "pipeline/process/session_steps.py", "pipeline/process/session_cache.py",
                "pipeline/steps/aoi.py")


def test_process_and_its_steps_are_short_flat_functions():
    """``process_session`` and every step function (``run``, ``run_<step>``, process's
    ``_<step>_step``) are under 40 lines, and no function in process or its steps defines a
    function inside it: steps are composed by calls, not nested closures (issue 30)."""
    long, nested, steps = [], [], []
    for rel in STEP_MODULES:
        tree = ast.parse((ROOT / "wearable_gaze" / rel).read_text())
        for node in ast.walk(tree):
            if not isinstance(node, ast.FunctionDef):
                continue
            inner = [n.name for n in ast.walk(node) if n is not node and isinstance(n, ast.FunctionDef)]
            nested += [f"{rel}:{node.name} defines {name}" for name in inner]
            is_step = (node.name in ("process_session", "run") or node.name.startswith("run_")
                       or (rel.endswith("process/session.py") and node.name.endswith("_step")))
            length = node.end_lineno - node.lineno + 1
            steps += [node.name] if is_step else []
            if is_step and length >= 40:
                long.append(f"{rel}:{node.name}: {length} lines")
    assert not long and not nested, (long, nested)
    assert {"process_session", "run", "run_camera", "run_eyes", "run_tracking", "run_viewlines", "run_targets",
            "run_export", "run_aoi", "run_report", "_tracking_step", "_report_step"} <= set(steps), steps


PIPELINE_ROOMS = {"batch", "maps", "process", "report", "steps"}
PIPELINE_TOP = {"__init__", "demo", "importer", "types"}


def test_every_pipeline_module_is_in_a_room():
    """pipeline/ is divided into rooms a reader can name (issue 30; docs/architecture.md, "The rooms
    of pipeline/"): a new module goes into the room of its concept, not beside the rooms, and every
    room is described there."""
    pipe = ROOT / "wearable_gaze" / "pipeline"
    loose = sorted(p.name for p in pipe.glob("*.py") if p.stem not in PIPELINE_TOP)
    rooms = {p.name for p in pipe.iterdir() if (p / "__init__.py").is_file()}
    doc = (ROOT / "docs" / "architecture.md").read_text()
    undescribed = sorted(r for r in rooms if f"### `pipeline/{r}/`" not in doc)
    assert not loose and rooms == PIPELINE_ROOMS and not undescribed, (loose, rooms, undescribed)
