"""The papers' own numbers, read from the one data file ``values.json`` of this package.

Every value carries the paper it comes from (``dvi``: the distributed-MSCKF paper; ``fej``: the
first-estimate-Jacobian multi-robot EKF paper), its table, row and column as the paper prints
them, its unit, and the number as printed (a string, so that its digits are kept). ``source`` is
``paper`` for a number printed in the paper and ``published code`` for one measured with the
authors' published code (the FEJ paper prints no numbers for Victoria Park).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources

__all__ = ["PaperValue", "paper_values"]


@dataclass(frozen=True)
class PaperValue:
    """One number of a paper's table.

    Attributes
    ----------
    paper
        ``dvi`` or ``fej``.
    table
        The table's number as the paper writes it (``I`` … ``IV``, ``1``, ``2``), or
        ``victoria-park``.
    row, column
        The row and column labels as the paper prints them.
    unit
        ``m``, ``rad``, ``s`` or ``""`` (unit-free, e.g. NEES).
    text
        The number as printed.
    source
        ``paper`` or ``published code``.
    """

    paper: str
    table: str
    row: str
    column: str
    unit: str
    text: str
    source: str

    @property
    def value(self) -> float:
        """The number."""
        return float(self.text)

    @property
    def digits(self) -> int:
        """Decimals the paper prints."""
        return len(self.text.split(".")[1]) if "." in self.text else 0


@cache
def _load() -> dict:
    return json.loads(resources.files("teamslam.paper").joinpath("values.json").read_text())


def paper_values(paper: str | None = None, table: str | None = None) -> list[PaperValue]:
    """The values of ``paper`` (and of its ``table``), in the paper's order; all without
    arguments."""
    out = []
    for r in _load()["values"]:
        if (paper is None or r["paper"] == paper) and (table is None or r["table"] == table):
            out.append(
                PaperValue(
                    r["paper"],
                    r["table"],
                    r["row"],
                    r["column"],
                    r["unit"],
                    r["value"],
                    r["source"],
                )
            )
    return out
