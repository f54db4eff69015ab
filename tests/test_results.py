"""The results pages hold no table typed by hand: every generated table names the command that
wrote it, from a commit of this repository, and the pages only include generated files."""

from __future__ import annotations

import importlib.util
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from teamslam.eval.provenance import HEADER_PREFIX, command_line, measured_header

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
GENERATED = RESULTS / "generated"

HEADER = re.compile(
    r"^measured on commit `(?P<commit>[0-9a-f]{7,40})` \((?P<state>clean|dirty)\), "
    r"(?P<date>\d{4}-\d\d-\d\d \d\d:\d\d UTC), `(?P<command>[^`]+)`; (?P<cores>\d+) cores, "
    r"BLAS threads (?P<blas>[^,]+), load average (?P<load>\d+\.\d)$"
)


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(path.parent))
    return module


@pytest.fixture(scope="module")
def commands() -> dict[str, tuple[str, str]]:
    return _module("results_commands", ROOT / "benchmarks" / "results.py").COMMANDS


def _generated() -> list[Path]:
    return sorted(GENERATED.rglob("*.md"))


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True)


def test_the_header_names_commit_command_and_machine():
    line = measured_header(command_line("teamslam", ["paper", "all", "--out", str(ROOT / "x")]))
    match = HEADER.match(line)
    assert match and line.startswith(HEADER_PREFIX), line
    # an absolute path is written as seen from the source tree: no path of the machine
    assert match["command"] == "teamslam paper all --out x"
    assert int(match["cores"]) >= 1


def test_the_benchmarks_helper_writes_the_header_then_the_tables(tmp_path, monkeypatch):
    helper = _module("_markdown", ROOT / "benchmarks" / "_markdown.py")
    monkeypatch.setattr(sys, "argv", ["benchmarks/some.py", "run", "--markdown", "t.md"])
    md = helper.Markdown(tmp_path / "t.md")
    md.table("A title", ["case", "value"], note="a note")
    md.row("a|b", "1.5")
    with pytest.raises(ValueError, match="a row of 1 cells"):
        md.row("only one")
    md.end()
    lines = md.write().read_text().splitlines()
    match = HEADER.match(lines[0])
    assert match and match["command"] == "python benchmarks/some.py run --markdown t.md"
    assert "| a\\|b | 1.5 |" in lines and "**A title**" in lines and "a note" in lines
    assert helper.Markdown(None).write() is None


def test_there_are_generated_tables():
    assert _generated(), f"no Markdown under {GENERATED.relative_to(ROOT)}"


@pytest.mark.parametrize("path", _generated(), ids=lambda p: str(p.relative_to(GENERATED)))
def test_a_generated_table_names_its_command_and_commit(path, commands):
    first = path.read_text().splitlines()[0]
    match = HEADER.match(first)
    assert match, f"{path.relative_to(ROOT)} does not start with the measured-on header: {first}"
    assert match["state"] == "clean", "measured with uncommitted code: not reproducible"
    command = match["command"]
    listed = {c for c, _ in commands.values()}
    assert command in listed, f"{command!r} is not one of benchmarks/results.py's commands"
    writes = next(w for c, w in commands.values() if c == command)
    assert path.relative_to(ROOT).as_posix().startswith(writes)
    words = shlex.split(command)
    if words[0] == "python":
        assert (ROOT / words[1]).is_file()
    else:
        from teamslam.cli import build_parser

        args = build_parser().parse_args(words[1:])
        assert args.handler is not None
    if _git("rev-parse", "--git-dir").returncode == 0:
        known = _git("cat-file", "-e", f"{match['commit']}^{{commit}}")
        assert known.returncode == 0, f"commit {match['commit']} is not in this repository"


def test_the_pages_include_generated_tables_only():
    pages = sorted(RESULTS.glob("*.md"))
    assert {p.name for p in pages} >= {
        "index.md",
        "papers.md",
        "consensus.md",
        "association.md",
        "tracking.md",
        "consistency.md",
        "speed.md",
    }
    included = set()
    for page in pages:
        for number, line in enumerate(page.read_text().splitlines(), 1):
            where = f"{page.relative_to(ROOT)}:{number}"
            # a table row typed into a page: tables come from generated files only
            assert not line.lstrip().startswith("|"), f"{where}: a table typed by hand"
            for snippet in re.findall(r'--8<-- "([^"]+)"', line):
                assert (ROOT / snippet).is_file(), f"{where}: {snippet} does not exist"
                included.add((ROOT / snippet).resolve())
    for path in _generated():
        if path.parent == GENERATED:
            assert path.resolve() in included, f"{path.relative_to(ROOT)} is on no page"


def test_paper_all_only_names_known_tables(tmp_path, capsys):
    from teamslam.cli import main

    assert main(["paper", "all", "--only", "dvi-table-9", "--out", str(tmp_path)]) == 2
    assert "--only: no table or figure dvi-table-9" in capsys.readouterr().err
