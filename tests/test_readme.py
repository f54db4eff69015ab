"""The README works as written: its Python runs, its commands are valid, its links resolve."""

from __future__ import annotations

import math
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 250


def code_blocks(text: str, language: str) -> list[str]:
    """The bodies of the fenced code blocks of ``language`` in Markdown ``text``."""
    return re.findall(rf"^```{language}\n(.*?)^```", text, re.S | re.M)


def shell_commands(block: str, program: str) -> list[list[str]]:
    """The commands of a shell block that start with ``program``, continuation lines joined,
    comments dropped, each split into its arguments as a POSIX shell would."""
    joined = re.sub(r"\\\n", " ", block)
    commands = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if words and words[0] == program:
            commands.append(words[1:])
    return commands


def check_teamslam_command(argv: list[str], where: str) -> None:
    """``teamslam ARGV`` parses with the CLI's own parser and names only real settings."""
    from teamslam.cli import build_parser
    from teamslam.msckf.settings.sources import parse_assignments

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"{where}: `teamslam {shlex.join(argv)}` does not parse (exit {exc.code})")
    assignments = getattr(args, "set", None) or []
    if assignments:
        parse_assignments(assignments)  # an unknown setting raises, naming it


def test_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines (at most {MAX_LINES})"


def test_readme_commands_parse():
    text = README.read_text()
    commands = [c for block in code_blocks(text, "sh") for c in shell_commands(block, "teamslam")]
    assert len(commands) >= 5, "the README shows the commands used most"
    for argv in commands:
        check_teamslam_command(argv, "README.md")


def test_readme_make_targets_exist():
    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    text = README.read_text()
    used = {c[0] for block in code_blocks(text, "sh") for c in shell_commands(block, "make")}
    used |= set(re.findall(r"`make (\w+)`", text))
    assert {"run", "test", "docs"} <= used
    assert used <= targets, f"the README names make targets the Makefile lacks: {used - targets}"


def test_readme_install_lines_are_quoted():
    """Extras in brackets are quoted, so the lines work in zsh as well as in bash."""
    installs = [
        line
        for block in code_blocks(README.read_text(), "sh")
        for line in block.splitlines()
        if line.startswith("pip install")
    ]
    with_extras = [line for line in installs if "[" in line.split("#")[0]]
    assert with_extras
    for line in with_extras:
        words = shlex.split(line, comments=True)
        assert any("[" in w for w in words)  # the quotes kept the brackets in one word
        assert "'" in line.split("#")[0], f"unquoted extras: {line}"


def test_readme_links_resolve():
    text = README.read_text()
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if "://" not in t]
    assert local
    missing = [t for t in local if not (ROOT / t).exists()]
    assert not missing, f"README links to missing files: {missing}"


def test_readme_python_runs(tmp_path, monkeypatch):
    blocks = code_blocks(README.read_text(), "python")
    assert blocks, "README has no Python example"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(README), "exec"), namespace)
    run = namespace["run"]
    assert set(run.by_mode) == {"separate", "consensus"}
    for metrics in run.by_mode.values():
        assert math.isfinite(metrics["trajectory_rmse_avg_m"])
    written = run.written["directory"]
    assert (tmp_path / written / "metrics.json").is_file()
    assert (tmp_path / written / "report.html").is_file()
    assert list((tmp_path / written).rglob("robot_0.tum"))
