"""Writing a team run's results: metrics.json, TUM trajectories and figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

__all__ = ["json_safe", "write_json", "write_team_outputs"]


def json_safe(value):
    """NaN and infinities become ``null`` (strict JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def write_json(path: Path, payload: dict) -> None:
    """Write JSON atomically: a partial file never replaces a complete one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(json_safe(payload), indent=2, sort_keys=True) + "\n")
    tmp.replace(path)


def write_team_outputs(
    out: Path, dataset, results: dict, metrics: dict, report: bool = True
) -> None:
    """metrics.json, per-robot TUM trajectories (estimate and truth), estimates.npz, the
    top-view and error figures and (unless ``report`` is false) report.html, whose path is
    printed last."""
    from teamslam.datasets import write_tum
    from teamslam.eval.estimates import save_estimates
    from teamslam.eval.plots import plot_team_errors, plot_team_topview

    names = list(results)
    payload = (
        metrics[names[0]]
        if len(names) == 1
        else {**metrics["consensus"], "separate": metrics["separate"]}
    )
    write_json(out / "metrics.json", payload)
    for name, result in results.items():
        prefix = out if len(names) == 1 else out / name
        save_estimates(prefix / "estimates.npz", dataset, result)
        for i, robot in enumerate(dataset.robots):
            write_tum(prefix / f"robot_{i}.tum", result.poses[i], robot.timestamps)
            write_tum(prefix / f"robot_{i}_groundtruth.tum", robot.T_world_body, robot.timestamps)
    plot_team_topview(dataset, results, out / "topview.png")
    plot_team_errors(dataset, results, out / "errors.png")
    print(f"\nwrote {out}/metrics.json, TUM trajectories, topview.png, errors.png")
    if report:
        from teamslam.eval.report import write_run_report

        print(f"report: {write_run_report(out, dataset, results)}")
