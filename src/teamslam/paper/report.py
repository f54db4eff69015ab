"""``report.html`` of ``teamslam paper all``: every table with the paper's values beside ours,
every figure, and what differs in each setting — one self-contained file (figures embedded as
base64 PNG, inline style, no script)."""

from __future__ import annotations

import base64
import html
from pathlib import Path

__all__ = ["paper_report", "write_paper_report"]

_STYLE = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:80em;color:#222}
table{border-collapse:collapse;margin:.5em 0 1em;font-size:90%}
td,th{border:1px solid #ccc;padding:.2em .5em;text-align:right}
td.l,th.l{text-align:left}
img{max-width:100%}
li{margin:.15em 0}
"""


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


def _section(item) -> str:
    out = [f"<section id='{_esc(item.key)}'><h2>{_esc(item.key)}: {_esc(item.title)}</h2>"]
    if item.cells:
        rows, columns, grid = item._grid()
        units = {c.column: c.unit for c in item.cells}
        out.append(f"<p>{_esc(item.header())}</p><table><thead><tr><th class='l'></th>")
        out += [
            f"<th>{_esc(c)}{' [' + _esc(units[c]) + ']' if units[c] else ''}</th>" for c in columns
        ]
        out.append("</tr></thead><tbody>")
        for r in rows:
            cells = "".join(
                f"<td>{_esc(grid[r, c].text()) if (r, c) in grid else ''}</td>" for c in columns
            )
            out.append(f"<tr><td class='l'>{_esc(r)}</td>{cells}</tr>")
        out.append("</tbody></table>")
    if item.figure is not None:
        data = base64.b64encode(item.figure).decode("ascii")
        out.append(f"<figure><img alt='{_esc(item.title)}' src='data:image/png;base64,{data}'>")
        out.append(f"<figcaption>{_esc(item.title)}</figcaption></figure>")
    out.append("<ul>" + "".join(f"<li>{_esc(s)}</li>" for s in item.setting) + "</ul>")
    out.append(f"<p><small>{item.seconds:.1f} s CPU</small></p></section>")
    return "".join(out)


def paper_report(items: list, reproducer) -> str:
    """The HTML text."""
    from teamslam import __version__

    times = reproducer.time_text()
    toc = "".join(
        f"<li><a href='#{_esc(i.key)}'>{_esc(i.key)}</a>: {_esc(i.title)}</li>" for i in items
    )
    body = "".join(_section(i) for i in items)
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>teamslam: the papers reproduced</title><style>{_STYLE}</style></head><body>"
        f"<h1>The papers' tables and figures, reproduced by teamslam {_esc(__version__)}</h1>"
        f"<p>{_esc(reproducer.settings.describe())}</p><p>{_esc(times)}</p>"
        f"<ul>{toc}</ul>{body}</body></html>\n"
    )


def write_paper_report(path: str | Path, items: list, reproducer) -> Path:
    """Write :func:`paper_report` to ``path`` (atomically)."""
    from teamslam.eval.outputs import writing

    path = Path(path)
    with writing(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(paper_report(items, reproducer))
        tmp.replace(path)
    return path
