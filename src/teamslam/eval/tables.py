"""Text tables of team runs (separate vs consensus side by side)."""

from __future__ import annotations

import math

__all__ = ["team_table"]


def team_table(runs: dict[str, dict]) -> str:
    """Side-by-side summary of team runs (separate vs consensus); ``—`` where a metric had
    nothing to measure."""
    names = list(runs)
    rows = [
        ("trajectory RMSE avg [m]", "trajectory_rmse_avg_m"),
        ("trajectory RMSE max [m]", "trajectory_rmse_max_m"),
        ("odometry-only RMSE avg [m]", "odometry_rmse_avg_m"),
        ("object error avg [m]", "object_error_avg_m"),
        ("object disagreement avg [m]", "object_disagreement_avg_m"),
    ]
    width = max(14, *(len(n) + 2 for n in names))
    lines = [f"{'':<36}" + "".join(f"{n:>{width}}" for n in names)]
    for label, key in rows:
        lines.append(f"{label:<36}" + "".join(_number(runs[n][key], width, 3) for n in names))
    n_robots = runs[names[0]]["robots"]
    for i in range(n_robots):
        lines.append(
            f"{f'robot {i} trajectory RMSE [m]':<36}"
            + "".join(_number(runs[n]["trajectory_rmse_m"][i], width, 3) for n in names)
        )
    linearization = runs[names[0]].get("config", {}).get("filter", {}).get("linearization", "std")
    for i in range(n_robots):
        lines.append(
            f"{f'robot {i} pose NEES / 6 ({linearization})':<36}"
            + "".join(_number(runs[n]["nees_pose_avg"][i], width, 2) for n in names)
        )
    for sensor, label in (("features", "features"), ("objects", "objects")):
        if any(runs[n].get("nis", {}).get(sensor) is not None for n in names):
            lines.append(
                f"{f'{label} NIS/dof | gate rejected':<36}"
                + "".join(_health_cell(runs[n], sensor, width) for n in names)
            )
    if any(runs[n].get("odometry_residual_ratio") for n in names):
        lines.append(
            f"{'odometry residual ratio (t | r)':<36}"
            + "".join(_odometry_cell(runs[n], width) for n in names)
        )
    once = {n: _one_off(runs[n]) for n in names}
    mark = " *" if any(once.values()) else ""
    for stage in ("consensus", "propagation", "update", "initialisation", "total"):
        lines.append(
            f"{f'time {stage} [ms/robot/frame]{mark}':<36}"
            + "".join(f"{runs[n]['time_per_robot_step_ms'][stage]:>{width}.2f}" for n in names)
        )
    if mark:
        lines.append(
            "  * include one-off costs: " + "; ".join(f"{n} {w}" for n, w in once.items() if w)
        )
    for key, rows in (("association", _ASSOCIATION_ROWS), ("tracking", _TRACKING_ROWS)):
        if not any(key in runs[n] for n in names):
            continue
        for label, cell in rows:
            lines.append(
                f"{label:<36}"
                + "".join(
                    f"{cell(runs[n][key]['team']):>{width}}"
                    if key in runs[n]
                    else f"{'—':>{width}}"
                    for n in names
                )
            )
    return "\n".join(lines)


def _one_off(run: dict) -> str:
    """What a run's stage times include that the next run will not pay (numba's compilation
    of kernels, their loading from its cache), or ``""``."""
    compiled, loaded = run.get("compilations", 0), run.get("kernels_loaded", 0)
    parts = []
    if compiled:
        parts.append(f"compiling {compiled} kernel{'s' if compiled > 1 else ''} (first run only)")
    if loaded:
        parts.append(
            f"loading {loaded} compiled kernel{'s' if loaded > 1 else ''} from the cache "
            "(first run of a process)"
        )
    return ", ".join(parts)


def _number(value, width: int, digits: int) -> str:
    """A number right-aligned in ``width``; ``—`` when there was nothing to measure (``None``,
    NaN: no object shared, no frame to score)."""
    if value is None or not math.isfinite(value):
        return f"{'—':>{width}}"
    return f"{value:>{width}.{digits}f}"


def _share(team: dict, key: str, digits: int) -> str:
    value = team.get(key)
    return "—" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


#: rows of the run table when a run associated objects itself (``association.mode = own``)
_ASSOCIATION_ROWS = (
    (
        "correspondences held | revoked",
        lambda t: f"{t.get('held', 0)} | {t.get('revoked', 0)}",
    ),
    ("association precision", lambda t: _share(t, "precision", 3)),
    ("association recall", lambda t: _share(t, "recall", 3)),
    ("summary bytes / robot / frame", lambda t: f"{t['summary_bytes_per_robot_step']:.0f}"),
    ("association share of step time", lambda t: f"{100 * t['association_time_share']:.1f}%"),
)


#: rows of the run table when robots tracked their own detections (datasets without ids)
_TRACKING_ROWS = (
    ("tracking IDF1 | MOTA", lambda t: f"{t['idf1']:.3f} | {t['mota']:.3f}"),
    ("tracking id switches", lambda t: f"{t['id_switches']}"),
    (
        "objects created | true | false",
        lambda t: f"{t['objects_created']} | {t['objects_true']} | {t['false_objects']}",
    ),
    ("object merges right | wrong", lambda t: _merges(t.get("merges"))),
)


def _merges(audit: dict | None) -> str:
    """The tracker's merges judged by the truth (:func:`~teamslam.eval.tracking.merge_audit`),
    ``—`` where the run recorded none."""
    return "—" if audit is None else f"{audit['right']} | {audit['wrong']}"


def _health_cell(run: dict, sensor: str, width: int) -> str:
    nis = run.get("nis", {}).get(sensor)
    rejected = run.get("gate_rejection_rate", {}).get(sensor)
    if nis is None:
        return f"{'—':>{width}}"
    cell = f"{nis:.2f} | {100 * rejected:.1f}%"
    return f"{cell:>{width}}"


def _odometry_cell(run: dict, width: int) -> str:
    ratio = run.get("odometry_residual_ratio")
    if not ratio:
        return f"{'—':>{width}}"
    cell = f"{ratio['translation']:.2f} | {ratio['rotation']:.2f}"
    return f"{cell:>{width}}"
