"""Every table and figure of both papers, reproduced, with the paper's numbers beside ours.

* :mod:`~teamslam.paper.values` — the papers' own numbers (one data file, ``values.json``);
* :mod:`~teamslam.paper.experiments` — the runs behind the tables (also used by the
  benchmarks);
* :mod:`~teamslam.paper.reproduce` — which tables and figures there are, and building them;
* :mod:`~teamslam.paper.compare` — a reproduced table: cells, text, Markdown, JSON;
* :mod:`~teamslam.paper.figures`, :mod:`~teamslam.paper.report` — PNG figures and
  ``report.html``.

Example::

    from teamslam.paper import PaperSettings, Reproducer

    table = Reproducer(PaperSettings.quick(), data="data").build("fej-table-1")
    print(table.text())
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = [
    "ITEMS",
    "Cell",
    "PaperSettings",
    "PaperValue",
    "Reproducer",
    "Reproduction",
    "item_key",
    "paper_values",
    "reproduce_all",
]

__getattr__, __dir__ = attach(
    __name__,
    ("compare", "experiments", "figures", "report", "reproduce", "values"),
    {
        "ITEMS": "teamslam.paper.reproduce",
        "Reproducer": "teamslam.paper.reproduce",
        "item_key": "teamslam.paper.reproduce",
        "reproduce_all": "teamslam.paper.reproduce",
        "Cell": "teamslam.paper.compare",
        "Reproduction": "teamslam.paper.compare",
        "PaperSettings": "teamslam.paper.experiments",
        "PaperValue": "teamslam.paper.values",
        "paper_values": "teamslam.paper.values",
    },
)

if TYPE_CHECKING:
    from teamslam.paper.compare import Cell, Reproduction
    from teamslam.paper.experiments import PaperSettings
    from teamslam.paper.reproduce import ITEMS, Reproducer, item_key, reproduce_all
    from teamslam.paper.values import PaperValue, paper_values
