"""The documents hold as written (README.md, docs/*.md): every ``wearable-gaze COMMAND --option``
they show names a real command and one of its options (read from the argparse parsers, not run),
every option of every command is documented, every ``python benchmarks/X.py --opt`` names a script
that takes that option, and every relative link and docs/ path they cite resolves. Cheap: nothing
is run but the parser's construction."""

from __future__ import annotations

import argparse
import itertools
import re
from pathlib import Path

import pytest

from wearable_gaze.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^(\s*)```")
SPAN = re.compile(r"`([^`\n]+)`")
OPTION = re.compile(r"(?<![\w-])(--?[A-Za-z][\w-]*)")
# where a command line ends: a shell separator, a comment, a pipe to another program
END = re.compile(r"\s(?:&&|;|&|#|>)(?:\s|$)|\s\|\|\s")


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """Every command's parser by its name ('' for the top level, 'reproduce table1' for a sub-choice
    of a positional with choices)."""
    out: dict[str, argparse.ArgumentParser] = {}

    def walk(p, name):
        out[name] = p
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub, sp in a.choices.items():
                    walk(sp, f"{name} {sub}".strip())

    walk(build_parser(), "")
    return out


PARSERS = _parsers()
COMMANDS = {name for name in PARSERS if name}


def options_of(name: str) -> set[str]:
    return {o for a in PARSERS[name]._actions for o in a.option_strings}


def _logical_lines(text: str):
    """(line number, text) of each logical line: a fenced block's lines with their continuations
    (a trailing backslash, or a more indented line after a command) joined, and each inline code
    span outside the blocks."""
    lines = text.splitlines()
    in_block, cur, cur_no = False, None, 0
    for no, line in enumerate(lines, 1):
        if FENCE.match(line):
            if cur is not None:
                yield cur_no, cur
            in_block, cur = not in_block, None
            continue
        if in_block:
            cont = cur is not None and (cur.endswith("\\") or (line[:1].isspace() and line.strip()))
            if cont:
                cur = cur.rstrip("\\") + " " + line.strip()
            else:
                if cur is not None:
                    yield cur_no, cur
                cur, cur_no = line.strip(), no
        else:
            for m in SPAN.finditer(line):
                yield no, m.group(1)


def command_uses(path: Path):
    """(line number, command, [options], text) of every ``wearable-gaze COMMAND ...`` in a document,
    and of every code span that starts with a command's name and an option (``process --map``)."""
    for no, text in _logical_lines(path.read_text(encoding="utf-8")):
        starts = [m.end() for m in re.finditer(r"(?:^|[\s(/])wearable-gaze(?= )", text)]
        pieces = [text[s:e] for s, e in itertools.pairwise([*starts, len(text)])]
        if not starts:
            first = text.split(" ", 1)[0]
            if first in COMMANDS and re.match(r"\S+ \[?-", text):
                pieces = [" " + text]
        for piece in pieces:
            piece = END.split(piece)[0]
            words = piece.split()
            top, i = [], 0
            while i < len(words) and words[i].startswith("-"):
                top.append(words[i])
                i += 1
            if i == len(words):
                continue
            cmd = words[i]
            if cmd.endswith(":"):                   # an error message quoted: "wearable-gaze estimate: ..."
                yield no, cmd[:-1], [], text
                continue
            if cmd == "reproduce" and i + 1 < len(words) and f"reproduce {words[i + 1]}" in COMMANDS:
                cmd = f"reproduce {words[i + 1]}"
            opts = [m.group(1) for m in OPTION.finditer(" ".join(words[i + 1:]))]
            yield no, cmd, top + opts, text


def _all_uses():
    for path in DOCS:
        for no, cmd, opts, text in command_uses(path):
            yield f"{path.relative_to(ROOT)}:{no}", cmd, opts, text


USES = list(_all_uses())


def test_the_extraction_finds_the_commands_it_should(tmp_path):
    """The extraction itself: a usage line continued over indented lines, a recipe with a backslash,
    an inline span and a quoted error message all come out with their options."""
    text = ("x `process --map sfm/` and `wearable-gaze estimate: lines.csv line 7`\n\n```\n"
            "wearable-gaze live --serial socket://h:1 \\\n   --eyes e.json &\n"
            "wearable-gaze batch S -o OUT [--workers N]\n       [--force]\n```\n")
    p = tmp_path / "probe.md"
    p.write_text(text)
    got = [(cmd, opts) for _, cmd, opts, _ in command_uses(p)]
    assert got == [("process", ["--map"]), ("estimate", []), ("live", ["--serial", "--eyes"]),
                   ("batch", ["-o", "--workers", "--force"])]
    assert len(USES) > 100, "the documents' commands were not found"


def test_every_documented_command_and_option_exists():
    bad = []
    for where, cmd, opts, text in USES:
        if cmd not in COMMANDS:
            bad.append(f"{where}: no command {cmd!r}: {text}")
            continue
        known = options_of(cmd) | options_of("")
        if cmd.startswith("reproduce "):
            known |= options_of("reproduce")
        bad += [f"{where}: {cmd} has no option {o}: {text}" for o in opts if o not in known]
    assert not bad, "\n".join(bad)


def test_every_option_of_every_command_is_documented():
    """Each option of ``wearable-gaze CMD --help`` appears with its command somewhere in the docs
    (README's table or a doc's usage line), so nobody has to read the code to find it."""
    shown: dict[str, set[str]] = {}
    for _, cmd, opts, _ in USES:
        shown.setdefault(cmd, set()).update(opts)
    missing = []
    for cmd in sorted(COMMANDS):
        if cmd.startswith("reproduce "):
            continue
        doc = shown.get(cmd, set()) | {o for c in shown if c.startswith(cmd + " ") for o in shown[c]}
        for a in PARSERS[cmd]._actions:
            if "-h" in a.option_strings or not a.option_strings or a.help == argparse.SUPPRESS:
                continue
            if not doc & set(a.option_strings):
                missing.append(f"{cmd} {'/'.join(a.option_strings)}")
    assert not missing, "options in --help that no document shows with their command: " + ", ".join(missing)


BENCH = re.compile(r"python3? (benchmarks/[\w/]+\.py)([^`\n]*)|python3? ([\w]+\.py)([^`\n]*)")


def test_every_documented_benchmark_exists_with_its_options():
    """``python benchmarks/X.py --opt`` (or ``cd benchmarks && ... python X.py``): the script exists
    and defines the option."""
    bad = []
    for path in DOCS:
        for no, text in _logical_lines(path.read_text(encoding="utf-8")):
            for m in BENCH.finditer(text):
                script = m.group(1) or ("benchmarks/" + m.group(3))
                rest = END.split(m.group(2) if m.group(1) else m.group(4))[0]
                if not m.group(1) and "benchmarks" not in text:
                    continue
                f = ROOT / script
                if not f.is_file():
                    bad.append(f"{path.relative_to(ROOT)}:{no}: no {script}")
                    continue
                src = f.read_text(encoding="utf-8")
                bad += [f"{path.relative_to(ROOT)}:{no}: {script} has no option {o}"
                        for o in OPTION.findall(rest) if f'"{o}"' not in src]
    assert not bad, "\n".join(bad)


LINK = re.compile(r"\]\(([^)\s]+)\)")
DOC_PATH = re.compile(r"(?<![\w/.])((?:docs|tests|benchmarks|assets|wearable_gaze|estimator|calibration|tracking)"
                      r"/[\w./-]*\w)")


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_links_and_cited_paths_resolve(path):
    """Markdown links to files, and repository paths a document cites (``docs/x.md``,
    ``tests/test_x.py``, ``wearable_gaze/pipeline/x.py``), exist."""
    text = path.read_text(encoding="utf-8")
    bad = []
    for m in LINK.finditer(text):
        target = m.group(1).split("#")[0]
        if not target or re.match(r"[a-z]+:", target):
            continue
        if not (path.parent / target).exists():
            bad.append(f"link {m.group(1)}")
    if path.parent.name == "devices":
        return _assert_none(path, bad)          # research notes: links only (their paths: docs/importers.md's)
    for m in DOC_PATH.finditer(text):
        cited = m.group(1)
        if text[m.end():m.end() + 1] == "*":     # tests/test_import_*.py
            if not list(ROOT.glob(cited + "*")):
                bad.append(f"path {cited}*")
            continue
        if re.search(r"[A-Z]{3,}", cited) or (cited.startswith("calibration/") and "." not in cited):
            continue                            # a placeholder (NAME), or a session's calibration/ folder
        if not ((ROOT / cited).exists() or (path.parent / cited).exists()):
            bad.append(f"path {cited}")
    _assert_none(path, bad)


def _assert_none(path, bad):
    assert not bad, f"{path.relative_to(ROOT)}: " + ", ".join(sorted(set(bad)))


# --- commands as a user types them, run --------------------------------------------------------

def test_a_named_scenario_is_no_input_file(tmp_path, monkeypatch):
    """``simulate --scenario calibration-only -o calibration-only``: the scenario is a name, not
    a file the output would overwrite (it was refused as 'also an input')."""
    from wearable_gaze.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--scenario", "calibration-only", "-o", "calibration-only",
                 "--resolution", "320x180"]) == 0
    assert (tmp_path / "calibration-only" / "session.json").is_file()


def test_the_import_command_export_recording_prints_runs(tmp_path, capsys):
    """``export-recording`` prints the ``import`` command for its recording; run as printed, it
    imports (a Pupil Core export's head poses are in marker sides: the command gives the size)."""
    import shlex

    from wearable_gaze.cli import main

    s, rec = tmp_path / "s", tmp_path / "rec"
    assert main(["simulate", "-o", str(s), "--duration", "1", "--resolution", "320x180"]) == 0
    capsys.readouterr()
    assert main(["export-recording", str(s), "-o", str(rec), "--format", "pupil-core"]) == 0
    printed = capsys.readouterr().out.split("import it with: ", 1)[1].strip()
    argv = shlex.split(printed.replace("SESSION", str(tmp_path / "imported")))
    assert argv[:2] == ["wearable-gaze", "import"]
    assert main(argv[1:]) == 0, capsys.readouterr().err
    assert (tmp_path / "imported" / "head_poses.csv").is_file()


def test_the_way_out_of_a_session_without_a_map_can_be_taken(tmp_path, capsys):
    """``process`` on a session without a marker map says what to do instead; every command and
    option the line names exists, and the poses of ``track --reference`` go somewhere that takes
    them (``viewlines --poses``; process has no option for poses: 'pass the poses' led nowhere)."""
    import json

    from wearable_gaze.cli import main

    s = tmp_path / "s"
    assert main(["simulate", "-o", str(s), "--duration", "1", "--resolution", "320x180"]) == 0
    manifest = json.loads((s / "session.json").read_text())
    (s / manifest["files"].pop("marker_map")).unlink()
    (s / "session.json").write_text(json.dumps(manifest))
    capsys.readouterr()
    assert main(["process", str(s), "--camera", str(s / "truth" / "camera.json"),
                 "--eyes", str(s / "truth" / "eyes.json")]) == 2
    line = next(ln for ln in capsys.readouterr().err.splitlines() if "no marker map" in ln)
    named = re.findall(r"'wearable-gaze (\S+)([^']*)'", line)
    assert ("viewlines", " --poses") in named, line
    for cmd, rest in named:
        assert set(OPTION.findall(rest)) <= options_of(cmd), line
    loose = re.sub(r"'wearable-gaze [^']*'", "", line)
    assert set(OPTION.findall(loose)) <= options_of("process"), line


SECTION = re.compile(r'(docs/[\w/-]+\.md),? (?:"([^"]+)"|([A-Z][A-Za-z ]+[a-z])\))')
LEAD = re.compile(r"^(?:#+ +(.+)|\s*(?:- )?\*\*(.+?)\*\*|\| *([^|]+))", re.M)


def test_sections_cited_by_name_exist():
    """``docs/x.md, "A section"`` names a heading (or a bold lead, or a table row) of that document."""
    bad = []
    for path in DOCS:
        for m in SECTION.finditer(path.read_text(encoding="utf-8")):
            doc, title = ROOT / m.group(1), (m.group(2) or m.group(3)).lower()
            leads = [next(g for g in m.groups() if g).lower() for m in LEAD.finditer(doc.read_text(encoding="utf-8"))]
            if not any(ln.startswith(title) and (ln[len(title):][:1] in ("", " ", "(", ":", ",")
                                                 or ln[len(title):] == ".") for ln in leads):
                bad.append(f"{path.relative_to(ROOT)}: {m.group(0)}")
    assert not bad, "\n".join(bad)


def test_formats_lists_every_schema():
    """docs/formats.md, "How files are checked", lists the schemas there are."""
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    listed = text.split("Every JSON format has a JSON Schema", 1)[1].split("A schema refers", 1)[0]
    names = set(re.findall(r"`([a-z-]+)`", listed))
    schemas = (ROOT / "wearable_gaze" / "formats" / "schemas").glob("*.schema.json")
    files = {p.name.removesuffix(".schema.json") for p in schemas}
    assert names == files, f"missing: {files - names}, not schemas: {names - files}"


def test_every_extra_the_docs_install_exists():
    """``pip install 'wearable-gaze[X]'`` names an extra of pyproject.toml."""
    tomllib = pytest.importorskip("tomllib", reason="tomllib is Python 3.11's")
    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    named = {(p.name, x) for p in DOCS for x in re.findall(r"wearable-gaze\[(\w+)\]", p.read_text(encoding="utf-8"))}
    assert named and {x for _, x in named} <= extras, sorted(n for n in named if n[1] not in extras)


def test_map_markerless_names_its_folder_as_given(tmp_path, monkeypatch, capsys):
    """``map --markerless ... -o sfm/`` (as docs/tracking.md writes it) prints ``sfm/``, not ``sfm//``,
    in the line a user copies from (the reconstruction itself is stubbed: only the printing is tested)."""
    from wearable_gaze.cli import main
    from wearable_gaze.pipeline.maps import sfm

    monkeypatch.setattr(sfm, "build_sfm_files", lambda *a, **k: None)
    monkeypatch.setattr(sfm, "format_sfm_report", lambda build: [])
    monkeypatch.chdir(tmp_path)
    for name in ("survey.mp4", "camera.json"):
        (tmp_path / name).write_bytes(b"x")
    assert main(["map", "--markerless", "survey.mp4", "--camera", "camera.json", "-o", "sfm/",
                 "--origin-marker", "0", "--size-mm", "200"]) == 0
    out = capsys.readouterr().out
    assert "markerless map sfm/ (" in out and out.rstrip().endswith("--map sfm/") and "//" not in out, out


def test_scenario_fields_table_is_the_defaults():
    """docs/scenarios.md's table of fields names every default of the simulator's scenarios
    (``sim.scenario.DEFAULTS``) and nothing else (``moved_marker`` has no default)."""
    from wearable_gaze.sim.scenario import DEFAULTS

    def flat(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict) and k != "camera_board":
                yield from flat(v, f"{prefix}{k}.")
            else:
                yield prefix + k

    text = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8").split("## Fields and defaults", 1)[1]
    rows = re.findall(r"^\| (`[^|]+`) \|", text, re.M)
    documented = {f for row in rows for f in re.findall(r"`([\w.]+)`", row)}
    assert documented - {"moved_marker"} == set(flat(DEFAULTS))
