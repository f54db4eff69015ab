"""The benchmarks' ``--markdown FILE``: the tables a run printed, as Markdown, with their source.

The first line of the file is :func:`teamslam.eval.provenance.measured_header` — commit (dirty if
``src/``, ``pyproject.toml``, the script or this helper has uncommitted changes), UTC date, the
exact command, cores, BLAS threads, load — taken as the run starts; then
each table the run adds, with its title and notes. Nothing is written without ``--markdown``.
Tables under ``docs/results/generated/`` are written this way only (``tests/test_results.py``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from teamslam.eval.provenance import CODE, command_line, measured_header

__all__ = ["Markdown", "add_option"]


def add_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--markdown FILE`` to a benchmark's parser."""
    parser.add_argument(
        "--markdown",
        type=Path,
        default=None,
        metavar="FILE",
        help="also write the tables as Markdown to FILE, headed by the commit, date, command "
        "and machine",
    )


def _cell(value) -> str:
    return str(value).replace("|", "\\|")


class Markdown:
    """The tables of one benchmark run, written to ``path`` (if not ``None``) by :meth:`write`.

    Parameters
    ----------
    path
        The Markdown file, or ``None`` (collect nothing, write nothing).
    """

    def __init__(self, path: Path | None):
        self.path = path
        program = Path(sys.argv[0]).name
        command = command_line(f"python benchmarks/{program}")
        code = (*CODE, f"benchmarks/{program}", "benchmarks/_markdown.py")
        self.header = measured_header(command, code) if path is not None else ""
        self.parts: list[str] = []
        self._columns: list[str] | None = None

    def table(self, title: str, columns: list[str], note: str | None = None) -> None:
        """Start a table: a bold title line, an optional note, the column heads; rows follow
        with :meth:`row`."""
        self.parts += [f"**{title}**", ""]
        if note:
            self.parts += [note, ""]
        self.parts += [
            "| " + " | ".join(map(_cell, columns)) + " |",
            "|" + "|".join("---" if k == 0 else "---:" for k in range(len(columns))) + "|",
        ]
        self._columns = columns

    def table_of(
        self, title: str, columns: list[str], rows: list[list[str]], note: str | None = None
    ) -> None:
        """A whole table (:meth:`table`, each row, :meth:`end`), printed to the terminal too:
        the column heads, the rows, then the note."""
        self.table(title, columns, note)
        print(" | ".join(columns))
        for row in rows:
            self.row(*row)
            print(" | ".join(row))
        if note:
            print(note)
        self.end()

    def row(self, *cells) -> None:
        """One row of the current table (cells already formatted, or numbers as ``str``)."""
        if self._columns is None or len(cells) != len(self._columns):
            raise ValueError(f"a row of {len(cells)} cells for columns {self._columns}")
        self.parts.append("| " + " | ".join(map(_cell, cells)) + " |")

    def note(self, text: str) -> None:
        """A paragraph after the current table."""
        self.parts += ["", text]

    def end(self) -> None:
        """Close the current table."""
        self.parts.append("")
        self._columns = None

    def write(self) -> Path | None:
        """Write the file (header line, then the tables); ``None`` without a path."""
        if self.path is None:
            return None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = "\n".join(self.parts).rstrip("\n")
        self.path.write_text(f"{self.header}\n\n{body}\n")
        print(f"wrote {self.path}", file=sys.stderr)
        return self.path
