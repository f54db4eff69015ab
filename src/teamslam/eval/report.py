"""One self-contained HTML report of team runs, with a column per run.

The file needs nothing but itself: figures are embedded as base64 PNG, the style is inline, no
script and no link leaves the page. Sections: the team and its communication graph, accuracy
(APE/RPE of :mod:`teamslam.eval.trajectory` and the run's own metrics), consistency (pose NEES
against its χ² band), sensor health (NIS / dof and gate rejection per sensor), timing per
stage, messages, and every setting with the layer it came from.
"""

from __future__ import annotations

import base64
import html
import math
import re
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.eval.runs import STAGES, TeamRun, load_runs, write_series
from teamslam.eval.trajectory import TeamEvaluation, Trajectory, evaluate_team

__all__ = [
    "build_report",
    "evaluate_runs",
    "evaluation_rows",
    "evaluation_table",
    "graph_adjacency",
    "write_report",
    "write_run_report",
]

_STATS = ("rmse", "mean", "median", "std", "max")


def _fmt(value, digits: int = 4) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "—"
        return f"{value:.{digits}g}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_fmt(v, digits) for v in value) + "]"
    return str(value)


def unique_names(runs: list[TeamRun]) -> list[str]:
    """Column labels, made unique by a suffix where two runs share a name."""
    seen: dict[str, int] = {}
    out = []
    for run in runs:
        count = seen.get(run.name, 0)
        seen[run.name] = count + 1
        out.append(run.name if count == 0 else f"{run.name} ({count + 1})")
    return out


def evaluate_runs(
    runs: list[TeamRun],
    references: list[Trajectory] | None = None,
    **options,
) -> list[TeamEvaluation]:
    """APE/RPE of each run against ``references`` or, if ``None``, its recorded ground truth.

    ``options`` are those of :func:`~teamslam.eval.trajectory.evaluate_team`.
    """
    out = []
    for run in runs:
        refs = references if references is not None else run.references
        if refs is None:
            raise InputError(
                f"{run.name}: no ground truth recorded with the trajectories; give the "
                "reference (--ref DATASET, --ref-tum FILE..., or --ref-kitti FILE...)"
            )
        if len(refs) != len(run.estimates):
            raise InputError(
                f"{run.name}: {len(run.estimates)} robots but {len(refs)} reference trajectories"
            )
        out.append(evaluate_team(run.estimates, refs, **options))
    return out


def evaluation_rows(stats: list[dict]) -> list[tuple[str, list[str]]]:
    """Rows ``(label, one cell per run)`` of the evaluation table."""
    rows: list[tuple[str, list[str]]] = []

    def cells(get) -> list[str]:
        out = []
        for s in stats:
            try:
                out.append(_fmt(get(s)))
            except (KeyError, IndexError):
                out.append("—")
        return out

    def alignment(s: dict) -> str:
        text = f"{s['align']} ({s['scope']})"
        if s["align"] == "sim3" and "alignment" in s["team"]:
            text += f", scale {s['team']['alignment']['scale']:.4g}"
        return text

    rows.append(("alignment", [alignment(s) for s in stats]))
    rows.append(("frames evaluated", cells(lambda s: s["team"]["ape_translation_m"]["count"])))
    unit = {"frames": "frames", "m": "m"}
    for key, label in (
        ("ape_translation_m", "APE translation [m]"),
        ("ape_rotation_deg", "APE rotation [deg]"),
        ("rpe_translation_m", "RPE translation [m]"),
        ("rpe_rotation_deg", "RPE rotation [deg]"),
    ):
        for stat in _STATS:
            suffix = ""
            if key.startswith("rpe") and stat == "rmse":
                suffix = "".join(
                    sorted({f" Δ={_fmt(s['rpe_delta'])} {unit[s['rpe_unit']]}" for s in stats})
                )
            rows.append(
                (f"{label} {stat}{suffix}", cells(lambda s, k=key, t=stat: s["team"][k][t]))
            )
    rows.append(
        ("APE translation RMSE, mean of robots [m]",
         cells(lambda s: s["team"]["ape_translation_rmse_avg_m"]))
    )  # fmt: skip
    n_robots = max(len(s["robots"]) for s in stats)
    for k in range(n_robots):
        rows.append(
            (f"robot {k} APE translation RMSE [m]",
             cells(lambda s, k=k: s["robots"][k]["ape_translation_m"]["rmse"]))
        )  # fmt: skip
    for k in range(n_robots):
        rows.append(
            (f"robot {k} APE rotation RMSE [deg]",
             cells(lambda s, k=k: s["robots"][k]["ape_rotation_deg"]["rmse"]))
        )  # fmt: skip
    for k in range(n_robots):
        rows.append(
            (f"robot {k} RPE translation RMSE [m]",
             cells(lambda s, k=k: s["robots"][k]["rpe_translation_m"]["rmse"]))
        )  # fmt: skip
    return rows


def _text_table(names: list[str], rows: list[tuple[str, list[str]]]) -> str:
    label_width = max(len(label) for label, _ in rows) + 2
    width = max(14, *(len(n) + 2 for n in names), *(len(c) + 2 for _, r in rows for c in r))
    lines = [" " * label_width + "".join(f"{n:>{width}}" for n in names)]
    lines += [f"{label:<{label_width}}" + "".join(f"{c:>{width}}" for c in r) for label, r in rows]
    return "\n".join(lines)


def evaluation_table(names: list[str], stats: list[dict]) -> str:
    """The evaluation as a text table, a column per run."""
    return _text_table(names, evaluation_rows(stats))


# --------------------------------------------------------------------------------------------
# communication graph


def graph_adjacency(run: TeamRun) -> np.ndarray | None:
    """The run's communication links: from its ``team.yaml``, or rebuilt from the graph's name.

    ``None`` when neither tells them (a random graph run in one process).
    """
    from teamslam import graph as graphs

    directory = run.directory
    for candidate in (directory, directory.parent if directory is not None else None):
        if candidate is not None and (candidate / "team.yaml").is_file():
            from teamslam.runtime.team_file import load_team_file

            try:
                return np.asarray(load_team_file(candidate / "team.yaml").adjacency(), dtype=bool)
            except (ValueError, OSError):
                break
    name = (run.metrics or {}).get("graph")
    if not isinstance(name, str):
        return None
    match = re.fullmatch(r"(complete|ring|path|star)\((\d+)\)", name)
    if match is None:
        return None
    return graphs.make(match.group(1), int(match.group(2))).adjacency


# --------------------------------------------------------------------------------------------
# HTML

_STYLE = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;
margin:1.5em auto;max-width:1500px;padding:0 1em;color:#222;background:#fff}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;
margin-top:1.6em}p.sub{color:#666;margin-top:0}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ddd;padding:.25em .6em;text-align:right;white-space:nowrap}
th{background:#f3f5f8}td.l,th.l{text-align:left}tr:nth-child(even) td{background:#fafbfc}
figure{margin:.8em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{color:#555;font-size:.85em}.warn{color:#a40}
.row{display:flex;gap:1.5em;flex-wrap:wrap;align-items:flex-start}
#configuration-table td{white-space:normal;max-width:30em;overflow-wrap:anywhere}
"""


def _esc(text) -> str:
    return html.escape(str(text), quote=True)


def _table(header: list[str], rows: list[tuple[str, list[str]]], table_id: str = "") -> str:
    ident = f' id="{_esc(table_id)}"' if table_id else ""
    out = [f"<table{ident}><thead><tr><th class='l'></th>"]
    out += [f"<th>{_esc(h)}</th>" for h in header]
    out.append("</tr></thead><tbody>")
    for label, cells in rows:
        out.append(f"<tr><td class='l'>{_esc(label)}</td>")
        out += [f"<td>{_esc(c)}</td>" for c in cells]
        out.append("</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _stats_tables(names: list[str], stats: list[dict]) -> str:
    """APE/RPE of the team (a column group of statistics per run) and RMSE per robot."""
    head = "".join(f"<th colspan='{len(_STATS)}'>{_esc(n)}</th>" for n in names)
    sub = "".join(f"<th>{t}</th>" for _ in names for t in _STATS)
    out = [
        f"<table id=\"accuracy-table\"><thead><tr><th class='l'></th>{head}</tr>"
        f"<tr><th class='l'>team, all frames</th>{sub}</tr></thead><tbody>"
    ]
    out.append("<tr><td class='l'>alignment</td>")
    for row in evaluation_rows(stats)[:1]:
        out += [f"<td colspan='{len(_STATS)}'>{_esc(c)}</td>" for c in row[1]]
    out.append("</tr>")
    for key, label in (
        ("ape_translation_m", "APE translation [m]"),
        ("ape_rotation_deg", "APE rotation [deg]"),
        ("rpe_translation_m", "RPE translation [m]"),
        ("rpe_rotation_deg", "RPE rotation [deg]"),
    ):
        if key.startswith("rpe"):
            unit = {"frames": "frames", "m": "m"}[stats[0]["rpe_unit"]]
            label += f", Δ = {_fmt(stats[0]['rpe_delta'])} {unit}"
        cells = "".join(f"<td>{_fmt(s['team'][key][t])}</td>" for s in stats for t in _STATS)
        out.append(f"<tr><td class='l'>{_esc(label)}</td>{cells}</tr>")
    out.append("</tbody></table>")
    parts = (
        ("ape_translation_m", "APE t [m]"),
        ("ape_rotation_deg", "APE r [deg]"),
        ("rpe_translation_m", "RPE t [m]"),
        ("rpe_rotation_deg", "RPE r [deg]"),
    )
    head = "".join(f"<th colspan='{len(parts)}'>{_esc(n)}</th>" for n in names)
    sub = "".join(f"<th>{label}</th>" for _ in names for _, label in parts)
    out.append(
        f"<table id=\"robots-table\"><thead><tr><th class='l'></th>{head}</tr>"
        f"<tr><th class='l'>RMSE per robot</th>{sub}</tr></thead><tbody>"
    )
    for k in range(max(len(s["robots"]) for s in stats)):
        cells = []
        for s in stats:
            for key, _ in parts:
                value = s["robots"][k][key]["rmse"] if k < len(s["robots"]) else None
                cells.append(f"<td>{_fmt(value)}</td>")
        out.append(f"<tr><td class='l'>robot {k}</td>{''.join(cells)}</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _img(png: bytes, alt: str, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (
        f"<figure><img alt='{_esc(alt)}' src='data:image/png;base64,{data}'>"
        f"<figcaption>{_esc(caption)}</figcaption></figure>"
    )


def _ratio(value) -> str:
    """A precision or recall to three decimals; ``—`` when there was nothing to measure."""
    return "—" if value is None else f"{value:.3f}"


def _metric_cells(runs: list[TeamRun], get) -> list[str]:
    out = []
    for run in runs:
        try:
            out.append(_fmt(get(run.metrics)) if run.metrics is not None else "—")
        except (KeyError, IndexError, TypeError):
            out.append("—")
    return out


def _team_section(names: list[str], runs: list[TeamRun]) -> str:
    rows = [
        ("robots", [str(len(r.estimates)) for r in runs]),
        ("frames per robot", _metric_cells(runs, lambda m: m["frames_per_robot"])),
        ("consensus", _metric_cells(runs, lambda m: m["consensus"])),
        ("communication graph", _metric_cells(runs, lambda m: m["graph"])),
        ("link loss rate", _metric_cells(runs, lambda m: m["loss"])),
        ("objects in map per robot", _metric_cells(runs, lambda m: m["objects_in_map"])),
        ("wall time [s]", _metric_cells(runs, lambda m: m["wall_seconds"])),
        ("directory", [str(r.shown_directory or r.directory or "—") for r in runs]),
    ]
    parts = ["<section id='team'><h2>Team</h2><div class='row'>", _table(names, rows, "team-table")]
    from teamslam.eval.figures import figure_png, graph_figure

    graphs = []
    drawn: list[np.ndarray] = []
    for name, run in zip(names, runs, strict=True):
        adjacency = graph_adjacency(run)
        if adjacency is None:
            continue
        if any(a.shape == adjacency.shape and np.array_equal(a, adjacency) for a in drawn):
            continue
        drawn.append(adjacency)
        label = (run.metrics or {}).get("graph", name)
        graphs.append(
            _img(figure_png(graph_figure(adjacency, str(label))), "communication graph", label)
        )
    parts += graphs
    parts.append("</div></section>")
    return "".join(parts)


def _accuracy_section(
    names: list[str], runs: list[TeamRun], evaluations: list[TeamEvaluation]
) -> str:
    from teamslam.eval.figures import (
        ape_over_time_figure,
        ape_path_figure,
        figure_png,
        trajectories_figure,
    )

    stats = [ev.statistics() for ev in evaluations]
    metric_rows = [
        ("trajectory RMSE avg [m]", _metric_cells(runs, lambda m: m["trajectory_rmse_avg_m"])),
        ("trajectory RMSE max [m]", _metric_cells(runs, lambda m: m["trajectory_rmse_max_m"])),
        ("odometry-only RMSE avg [m]", _metric_cells(runs, lambda m: m["odometry_rmse_avg_m"])),
        ("object error avg [m]", _metric_cells(runs, lambda m: m["object_error_avg_m"])),
        (
            "object disagreement avg [m]",
            _metric_cells(runs, lambda m: m["object_disagreement_avg_m"]),
        ),
    ]
    return "".join(
        [
            "<section id='accuracy'><h2>Accuracy</h2>",
            "<p>Absolute (APE) and relative (RPE) pose errors against the ground truth, every "
            "robot's frames pooled for the team.</p>",
            _stats_tables(names, stats),
            "<p>The run's own measures (no alignment; objects against the true map).</p>",
            _table(names, metric_rows, "metrics-table"),
            _img(
                figure_png(trajectories_figure(names, evaluations)),
                "trajectories",
                "Every robot's estimate (colour) and ground truth (grey): top view and 3D.",
            ),
            _img(
                figure_png(ape_over_time_figure(names, evaluations)),
                "position error over time",
                "Position error of each robot over time.",
            ),
            _img(
                figure_png(ape_path_figure(names, evaluations)),
                "APE along the path",
                "Each path coloured by its position error, one colour scale for every run.",
            ),
            "</section>",
        ]
    )


def _consistency_section(names: list[str], runs: list[TeamRun]) -> str:
    from teamslam.eval.figures import figure_png, nees_band, nees_figure

    n_robots = max(len(r.estimates) for r in runs)
    rows = [
        (
            f"robot {k} pose NEES / 6 mean | median",
            [
                f"{c1} | {c2}"
                for c1, c2 in zip(
                    _metric_cells(runs, lambda m, k=k: m["nees_pose_avg"][k]),
                    _metric_cells(runs, lambda m, k=k: m["nees_pose_median"][k]),
                    strict=True,
                )
            ],
        )
        for k in range(n_robots)
    ]
    lo, hi = nees_band(6)
    parts = [
        "<section id='consistency'><h2>Consistency</h2>",
        f"<p>Pose NEES / 6 (1 when the covariance is right); a consistent robot stays within "
        f"[{lo:.2f}, {hi:.2f}] 95% of the time.</p>",
        _table(names, rows, "consistency-table"),
    ]
    series = [r.series for r in runs]
    if any(s for s in series):
        parts.append(
            _img(
                figure_png(nees_figure(names, series)),
                "NEES over time",
                "Pose NEES / 6 per robot (colour) and team average (black) with 95% χ² bands.",
            )
        )
    parts.append("</section>")
    return "".join(parts)


def _health_section(names: list[str], runs: list[TeamRun]) -> str:
    from teamslam.msckf.settings.health import health_warnings

    rows = []
    for sensor in ("features", "objects"):
        rows.append((f"{sensor} NIS / dof", _metric_cells(runs, lambda m, s=sensor: m["nis"][s])))
        rows.append(
            (
                f"{sensor} gate rejected",
                [
                    c if c == "—" else f"{100 * float(c):.1f}%"
                    for c in _metric_cells(runs, lambda m, s=sensor: m["gate_rejection_rate"][s])
                ],
            )
        )
    for part in ("translation", "rotation"):
        rows.append(
            (
                f"odometry residual ratio ({part})",
                _metric_cells(runs, lambda m, p=part: m["odometry_residual_ratio"][p]),
            )
        )
    warnings = []
    for name, run in zip(names, runs, strict=True):
        m = run.metrics or {}
        if "nis" in m:
            lines = health_warnings(
                {
                    "nis": m["nis"],
                    "gate_rejection_rate": m.get("gate_rejection_rate", {}),
                    "odometry_residual_ratio": m.get("odometry_residual_ratio"),
                }
            )
            warnings += [f"<p class='warn'>{_esc(name)}: {_esc(line)}</p>" for line in lines]
    return "".join(
        [
            "<section id='health'><h2>Sensor health</h2>",
            "<p>Mean NIS / dof of each sensor (≈ 1 when its σ is right), the share of its "
            "measurements the χ² gate rejected, and the odometry's smoothed-residual ratio.</p>",
            _table(names, rows, "health-table"),
            *(warnings or ["<p>No sensor outside its healthy range.</p>"]),
            "</section>",
        ]
    )


def _timing_section(names: list[str], runs: list[TeamRun]) -> str:
    from teamslam.eval.figures import figure_png, stage_times_figure

    rows = [
        (
            f"{stage} [ms/robot/frame]",
            _metric_cells(runs, lambda m, s=stage: m["time_per_robot_step_ms"][s]),
        )
        for stage in (*STAGES, "total")
    ]
    parts = ["<section id='timing'><h2>Timing</h2>", _table(names, rows, "timing-table")]
    series = [r.series for r in runs]
    if any(s for s in series):
        parts.append(
            _img(
                figure_png(stage_times_figure(names, series)),
                "time per frame",
                "Milliseconds per robot per frame in each stage (mean over robots).",
            )
        )
    parts.append("</section>")
    return "".join(parts)


def _messages_section(names: list[str], runs: list[TeamRun]) -> str:
    n_robots = max(len(r.estimates) for r in runs)
    rows = [
        (
            "messages sent, team",
            _metric_cells(runs, lambda m: sum(c["messages"] for c in m["counters"])),
        ),
        (
            "MB sent, team",
            _metric_cells(runs, lambda m: sum(c["bytes"] for c in m["counters"]) / 1e6),
        ),
    ]
    rows += [
        (
            f"robot {k} messages | MB",
            [
                f"{a} | {b}"
                for a, b in zip(
                    _metric_cells(runs, lambda m, k=k: m["counters"][k]["messages"]),
                    _metric_cells(runs, lambda m, k=k: m["counters"][k]["bytes"] / 1e6),
                    strict=True,
                )
            ],
        )
        for k in range(n_robots)
    ]
    for key in ("updates", "objects_initialised", "objects_averaged", "rejected_objects_gate"):
        rows.append(
            (
                f"{key.replace('_', ' ')}, team",
                _metric_cells(runs, lambda m, key=key: sum(c[key] for c in m["counters"])),
            )
        )
    table = _table(names, rows, "messages-table")
    return f"<section id='messages'><h2>Messages</h2>{table}</section>"


def _settings(metrics: dict | None) -> dict:
    """A run's recorded settings by ``group.name`` (its ``config``: one mapping per group)."""
    config = (metrics or {}).get("config") or {}
    out = {}
    for group, values in config.items():
        if isinstance(values, dict):
            out.update({f"{group}.{name}": value for name, value in values.items()})
    return out


def _configuration_section(names: list[str], runs: list[TeamRun]) -> str:
    recorded = [_settings(r.metrics) for r in runs]
    keys = sorted({k for settings in recorded for k in settings})
    if not keys:
        return (
            "<section id='configuration'><h2>Configuration</h2>"
            "<p>Not recorded with these runs.</p></section>"
        )
    rows = []
    for key in keys:
        cells = []
        for run, settings in zip(runs, recorded, strict=True):
            if key not in settings:
                cells.append("—")
                continue
            source = ((run.metrics or {}).get("config_sources") or {}).get(key, "?")
            cells.append(f"{_fmt(settings[key])} ({source})")
        rows.append((key, cells))
    calibration = []
    for name, run in zip(names, runs, strict=True):
        c = (run.metrics or {}).get("calibration")
        if isinstance(c, dict):
            summary = ", ".join(
                f"{k}: {_fmt(v)}" for k, v in c.items() if isinstance(v, int | float | str)
            )
            calibration.append(f"<p>{_esc(name)}: calibrated from the data ({_esc(summary)})</p>")
    return "".join(
        [
            "<section id='configuration'><h2>Configuration</h2>",
            "<p>Every setting and the layer it came from (default &lt; dataset &lt; calibration "
            "&lt; file &lt; flag).</p>",
            _table(names, rows, "configuration-table"),
            *calibration,
            "</section>",
        ]
    )


def _summary_section(
    names: list[str], runs: list[TeamRun], evaluations: list[TeamEvaluation]
) -> str:
    stats = [ev.statistics() for ev in evaluations]
    rows = [
        (
            f"APE translation RMSE, team [m] (align {stats[0]['align']})",
            [_fmt(s["team"]["ape_translation_m"]["rmse"]) for s in stats],
        ),
        ("object error avg [m]", _metric_cells(runs, lambda m: m["object_error_avg_m"])),
        (
            "object disagreement avg [m]",
            _metric_cells(runs, lambda m: m["object_disagreement_avg_m"]),
        ),
        (
            "pose NEES / 6, mean of robots",
            _metric_cells(runs, lambda m: float(np.mean(m["nees_pose_avg"]))),
        ),
        (
            "time total [ms/robot/frame]",
            _metric_cells(runs, lambda m: m["time_per_robot_step_ms"]["total"]),
        ),
        (
            "MB sent, team",
            _metric_cells(runs, lambda m: sum(c["bytes"] for c in m["counters"]) / 1e6),
        ),
    ]
    table = _table(names, rows, "summary-table")
    return f"<section id='summary'><h2>Summary</h2>{table}</section>"


def _association_section(names: list[str], runs: list[TeamRun]) -> str:
    """Which objects the robots found they share (runs with ``association.mode = own``); empty when
    no run associated objects itself."""
    found = [(r.metrics or {}).get("association") for r in runs]
    if not any(found):
        return ""

    def team(key, fmt="{}"):
        return [
            "—" if a is None or a["team"].get(key) is None else fmt.format(a["team"][key])
            for a in found
        ]

    rows = [
        ("correspondences held, team", team("held")),
        (
            "proposed | accepted | revoked",
            [
                "—" if a is None else "{proposed} | {accepted} | {revoked}".format(**a["team"])
                for a in found
            ],
        ),
        (
            "correct | wrong (ground truth)",
            [
                "—"
                if a is None or "correct" not in a["team"]
                else f"{a['team']['correct']} | {a['team']['wrong']}"
                for a in found
            ],
        ),
        ("precision", team("precision", "{:.3f}")),
        ("recall (objects both maps hold)", team("recall", "{:.3f}")),
        ("summary bytes / robot / frame", team("summary_bytes_per_robot_step", "{:.0f}")),
        (
            "association share of step time",
            [
                "—" if a is None else f"{100 * a['team']['association_time_share']:.1f}%"
                for a in found
            ],
        ),
    ]
    links = sorted(
        {k for a in found if a for k in a["links"]}, key=lambda k: tuple(map(int, k.split("-")))
    )
    for key in links:
        cells = []
        for a in found:
            link = None if a is None else a["links"].get(key)
            if link is None:
                cells.append("—")
            elif "precision" in link:
                cells.append(
                    f"{link.get('held', 0)} held, {link.get('revoked', 0)} revoked, "
                    f"P {_ratio(link['precision'])} R {_ratio(link['recall'])}"
                )
            else:
                cells.append(f"{link.get('held', 0)} held, {link.get('revoked', 0)} revoked")
        rows.append((f"link {key}", cells))
    table = _table(names, rows, "association-table")
    return (
        "<section id='association'><h2>Association</h2>"
        "<p>Objects without shared ids: each link finds which objects the two robots share from "
        "exchanged object summaries; consensus averages the matched pairs.</p>"
        f"{table}</section>"
    )


def build_report(runs: list[TeamRun], evaluations: list[TeamEvaluation]) -> str:
    """The HTML text of the report, a column per run."""
    from teamslam import __version__

    if not runs:
        raise InputError("a report needs at least one run")
    names = unique_names(runs)
    title = "teamslam report: " + ", ".join(names)
    body = [
        f"<h1>{_esc(title)}</h1>",
        f"<p class='sub'>{len(runs)} run(s), written by teamslam {_esc(__version__)}</p>",
        _summary_section(names, runs, evaluations),
        _team_section(names, runs),
        _accuracy_section(names, runs, evaluations),
        _consistency_section(names, runs),
        _health_section(names, runs),
        _timing_section(names, runs),
        _messages_section(names, runs),
        _association_section(names, runs),
        _configuration_section(names, runs),
    ]
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{_esc(title)}</title><style>{_STYLE}</style></head><body>"
        + "\n".join(body)
        + "</body></html>\n"
    )


def write_report(
    specs: list[str | Path],
    out: str | Path,
    references: list[Trajectory] | None = None,
    **options,
) -> Path:
    """Read the runs ``specs`` name (:func:`~teamslam.eval.runs.load_runs`), write the report.

    ``options`` are those of :func:`~teamslam.eval.trajectory.evaluate_team`.
    """
    runs = [run for spec in specs for run in load_runs(spec)]
    return _write_report(runs, out, references, **options)


def _write_report(runs: list[TeamRun], out: str | Path, references=None, **options) -> Path:
    evaluations = evaluate_runs(runs, references, **options)
    text = build_report(runs, evaluations)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)
    return out


def write_run_report(
    out: str | Path, dataset, results: dict, final: str | Path | None = None
) -> Path:
    """What ``teamslam run --out DIR`` adds to its directory: ``series.npz`` per run, and
    ``report.html``.

    Parameters
    ----------
    out
        The run directory being written (``metrics.json`` and the TUM trajectories already
        written, ``run.json`` not yet).
    dataset
        The team dataset the runs estimated.
    results
        ``{"separate": TeamResult, "consensus": TeamResult}`` or one of them.
    final
        Where ``out`` goes once written (its writer stages it, :mod:`teamslam.staging`): the
        name and directory the report shows (default: ``out``).
    """
    from teamslam.eval.metrics import pose_nees

    out = Path(out)
    for name, result in results.items():
        prefix = out if len(results) == 1 else out / name
        nees = [
            pose_nees(result.poses[i], result.pose_covs[i], robot.T_world_body)
            for i, robot in enumerate(dataset.robots)
        ]
        write_series(prefix, nees, result.frame_times)
    runs = load_runs(out, None if final is None else Path(final).resolve().name, writing=True)
    if final is not None:
        for run in runs:
            run.shown_directory = Path(final) / run.directory.relative_to(out)
    return _write_report(runs, out / "report.html")
