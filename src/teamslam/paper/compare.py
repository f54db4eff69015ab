"""A table or figure of a paper as reproduced: the paper's value and ours per cell, side by side.

A :class:`Reproduction` holds the cells (:class:`Cell`), the lines saying what differs in the
setting, an optional figure, and writes itself as Markdown, JSON and PNG.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from teamslam.paper.values import PaperValue

__all__ = ["Cell", "Reproduction"]


def _number(value: float | None, digits: int) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:.{digits}f}"


@dataclass
class Cell:
    """One cell of a table: the paper's value and ours.

    Attributes
    ----------
    paper, table, row, column, unit
        Where the value is (:class:`~teamslam.paper.values.PaperValue`).
    paper_value
        The paper's number (``None`` where the paper has none).
    ours
        Our number (``None`` where we cannot compute it, e.g. a sequence whose data is not
        published).
    digits
        Decimals to print (the paper's).
    own_data
        Ours was computed on the paper's own data: the difference means something.
    source
        ``paper`` or ``published code``: where ``paper_value`` comes from.
    """

    paper: str
    table: str
    row: str
    column: str
    unit: str
    paper_value: float | None
    ours: float | None
    digits: int = 3
    own_data: bool = False
    source: str = "paper"

    @classmethod
    def of(cls, value: PaperValue, ours: float | None, own_data: bool = False) -> Cell:
        """The cell of one of the paper's values, with ours beside it."""
        return cls(
            value.paper,
            value.table,
            value.row,
            value.column,
            value.unit,
            value.value,
            ours,
            value.digits,
            own_data=own_data,
        )

    @property
    def difference(self) -> float | None:
        """``ours − paper`` on the paper's own data, else ``None``."""
        if not self.own_data or self.paper_value is None or self.ours is None:
            return None
        if not math.isfinite(self.ours):
            return None
        return self.ours - self.paper_value

    def record(self) -> dict[str, Any]:
        """The JSON record: ``paper``, ``ours``, ``difference``, ``unit``, ``row``, ``column``,
        ``table``, ``document`` (which paper) and ``source``."""
        ours = self.ours if self.ours is None or math.isfinite(self.ours) else None
        return {
            "document": self.paper,
            "table": self.table,
            "row": self.row,
            "column": self.column,
            "unit": self.unit,
            "paper": self.paper_value,
            "ours": ours,
            "difference": self.difference,
            "source": self.source,
        }

    def text(self) -> str:
        """``paper / ours`` and, on the paper's own data, ``(±difference)``."""
        out = f"{_number(self.paper_value, self.digits)} / {_number(self.ours, self.digits)}"
        if self.difference is not None:
            shown = round(self.difference, self.digits) + 0.0  # no "-0.00"
            out += f" ({shown:+.{self.digits}f})"
        return out


@dataclass
class Reproduction:
    """A table or figure of a paper, reproduced.

    Attributes
    ----------
    key
        ``dvi-table-1``, ``fej-figure-6``, ``fej-victoria-park`` …
    title
        The paper's caption, shortened.
    cells
        The table's cells in the paper's order (a figure may carry the numbers it plots, with
        ``paper_value`` ``None``).
    setting
        What differs from the paper's setting, and what was run: one line each.
    figure
        PNG bytes of the figure, if any.
    seconds
        Wall time of the experiments it needed (shared experiments counted once, where first
        run).
    """

    key: str
    title: str
    cells: list[Cell] = field(default_factory=list)
    setting: list[str] = field(default_factory=list)
    figure: bytes | None = None
    seconds: float = 0.0

    def records(self) -> list[dict[str, Any]]:
        """One JSON record per cell."""
        return [c.record() for c in self.cells]

    def _grid(self) -> tuple[list[str], list[str], dict[tuple[str, str], Cell]]:
        rows: list[str] = []
        columns: list[str] = []
        grid = {}
        for c in self.cells:
            if c.row not in rows:
                rows.append(c.row)
            if c.column not in columns:
                columns.append(c.column)
            grid[c.row, c.column] = c
        return rows, columns, grid

    def header(self) -> str:
        """What the cells hold."""
        own = any(c.own_data for c in self.cells)
        source = "published code" if all(c.source != "paper" for c in self.cells) else "paper"
        return f"cells: {source} / ours" + (" (ours − theirs on their own data)" if own else "")

    def text(self) -> str:
        """The table as plain text, the paper's value and ours side by side."""
        lines = [f"{self.key}: {self.title}"]
        if self.cells:
            rows, columns, grid = self._grid()
            body = [[grid[r, c].text() if (r, c) in grid else "" for c in columns] for r in rows]
            first = max(len(r) for r in rows)
            widths = [max(len(c), *(len(b[k]) for b in body)) for k, c in enumerate(columns)]
            lines.append(self.header())
            lines.append(
                " " * first
                + "  "
                + "  ".join(f"{c:>{w}}" for c, w in zip(columns, widths, strict=True))
            )
            for r, b in zip(rows, body, strict=True):
                cells = "  ".join(f"{t:>{w}}" for t, w in zip(b, widths, strict=True))
                lines.append(f"{r:<{first}}  {cells}")
        lines += [f"  - {s}" for s in self.setting]
        return "\n".join(lines)

    def markdown(self) -> str:
        """The table as Markdown (with the setting as a list below)."""
        out = [f"### {self.key}: {self.title}", ""]
        if self.cells:
            rows, columns, grid = self._grid()
            units = {c.column: c.unit for c in self.cells}
            head = [f"{c} [{units[c]}]" if units[c] else c for c in columns]
            out.append(f"{self.header()}")
            out.append("")
            out.append("| | " + " | ".join(head) + " |")
            out.append("|---|" + "---:|" * len(columns))
            for r in rows:
                cells = [grid[r, c].text() if (r, c) in grid else "" for c in columns]
                out.append(f"| {r} | " + " | ".join(cells) + " |")
            out.append("")
        out += [f"- {s}" for s in self.setting]
        return "\n".join(out) + "\n"

    def write(self, out: str | Path, header: str | None = None) -> list[Path]:
        """Write ``KEY.md``, ``KEY.json`` and, with a figure, ``KEY.png`` into ``out``.

        ``header``, if given, is the first line of ``KEY.md`` (where the numbers come from:
        :func:`teamslam.eval.provenance.measured_header`).
        """
        from teamslam.eval.outputs import write_json, writing

        out = Path(out)
        written = []
        with writing(out):
            out.mkdir(parents=True, exist_ok=True)
            md = out / f"{self.key}.md"
            md.write_text(self.markdown() if header is None else f"{header}\n\n{self.markdown()}")
            written.append(md)
            if self.figure is not None:
                png = out / f"{self.key}.png"
                png.write_bytes(self.figure)
                written.append(png)
        path = out / f"{self.key}.json"
        write_json(
            path,
            {
                "key": self.key,
                "title": self.title,
                "setting": self.setting,
                "seconds": self.seconds,
                "cells": self.records(),
            },
        )
        written.append(path)
        return written
