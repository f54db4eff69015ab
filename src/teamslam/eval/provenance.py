"""Where a measured table comes from: one header line naming the commit, date, command and machine.

Every Markdown table a measuring command writes (``teamslam paper … --out``, the benchmarks'
``--markdown FILE``) starts with :func:`measured_header`::

    measured on commit `abc1234` (clean), 2026-01-31 12:00 UTC, `teamslam paper all --out DIR`;
    2 cores, BLAS threads 1, load average 1.9

``clean``/``dirty`` says whether the code that made the numbers (``src/`` and ``pyproject.toml``,
and the benchmark script that ran) had uncommitted changes; outside a git checkout the commit is
``unknown`` and the version is named. The command is the one that ran, with absolute paths made
relative to the source tree.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

__all__ = ["CODE", "HEADER_PREFIX", "command_line", "measured_header", "source_root"]

#: the start of every header line (what ``tests`` look for in a generated table)
HEADER_PREFIX = "measured on commit `"

# the files whose changes change a number (a benchmark adds its own script)
CODE = ("src", "pyproject.toml")


def source_root() -> Path:
    """The directory holding ``src/teamslam`` (the checkout, when run from one)."""
    return Path(__file__).resolve().parents[3]


def _git(root: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=30
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def _commit(root: Path, code: tuple[str, ...]) -> str:
    commit = _git(root, "rev-parse", "--short", "HEAD")
    if commit is None:
        from teamslam._version import __version__

        return f"`unknown` (teamslam {__version__}, not a git checkout)"
    changes = _git(root, "status", "--porcelain", "--", *code)
    return f"`{commit}` ({'dirty' if changes else 'clean'})"


def _blas_threads() -> str:
    import numpy  # noqa: F401  (loads the BLAS whose threads are counted)
    from threadpoolctl import threadpool_info

    threads = sorted({p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"})
    return ", ".join(map(str, threads)) or "none loaded"


def command_line(program: str, argv: list[str] | None = None) -> str:
    """``program`` and the arguments (``sys.argv[1:]`` by default), shell-quoted, with absolute
    paths made relative to the source tree (:func:`source_root`)."""
    root = source_root()
    args = [_relative(a, root) for a in (sys.argv[1:] if argv is None else argv)]
    return " ".join([program, *map(shlex.quote, args)])


def _relative(arg: str, root: Path) -> str:
    """An absolute path as it is seen from ``root`` (no path of the machine in a header)."""
    if not os.path.isabs(arg):
        return arg
    return os.path.relpath(arg, root)


def measured_header(command: str, code: tuple[str, ...] = CODE) -> str:
    """The one-line header of a measured table: commit (``dirty`` if a path of ``code``, relative
    to the source tree, has uncommitted changes), UTC date, the exact command, the machine's
    cores, BLAS threads and the 1-minute load average when called."""
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (
        f"measured on commit {_commit(source_root(), code)}"
        f", {date}, `{command}`; {os.cpu_count()} cores, BLAS threads {_blas_threads()}, "
        f"load average {load:.1f}"
    )
