"""Figures (matplotlib, Agg backend: no display needed).

The 3D team figures count robots from 0 (``robot 0``), as every table, file and topic of a team
run does; the planar FEJ-EKF figures name them R1, R2 as the FEJ paper and its tables
(``teamslam fej``) do.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

__all__ = ["plot_monte_carlo", "plot_planar_map", "plot_sigma_bounds"]

COLOURS = {"std": "tab:red", "ideal": "tab:green", "fej": "tab:blue"}
LABELS = {"std": "Std-EKF", "ideal": "Ideal-EKF", "fej": "FEJ-EKF"}


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)
    tmp.replace(path)
    return path


def plot_monte_carlo(result, path: str | Path) -> Path:
    """NEES and RMSE over time per filter (paper Figs. 4–5): a row per robot plus features."""
    n = result.n_robots
    fig, axes = plt.subplots(n + 1, 3, figsize=(13, 3.0 * (n + 1)), squeeze=False)
    steps = np.arange(result.steps + 1)
    for name, c in result.curves.items():
        kw = {"color": COLOURS.get(name), "label": LABELS.get(name, name), "lw": 1.0}
        for i in range(n):
            axes[i, 0].plot(steps, c["pose_nees"][:, i], **kw)
            axes[i, 1].plot(steps, c["position_rmse"][:, i], **kw)
            axes[i, 2].plot(steps, c["heading_rmse"][:, i], **kw)
        axes[n, 0].plot(steps, c["feature_nees"], **kw)
        axes[n, 1].plot(steps, c["feature_rmse"], **kw)
    for i in range(n):
        axes[i, 0].set_ylabel(f"R{i + 1}")
        axes[i, 0].set_title("pose NEES (normalised)")
        axes[i, 1].set_title("position RMSE [m]")
        axes[i, 2].set_title("heading RMSE [rad]")
        axes[i, 0].axhline(1.0, color="k", lw=0.6, ls="--")
    axes[n, 0].set_title("feature NEES (normalised)")
    axes[n, 0].axhline(1.0, color="k", lw=0.6, ls="--")
    axes[n, 1].set_title("feature RMSE [m]")
    axes[n, 2].axis("off")
    for ax in axes.ravel():
        ax.set_xlabel("step")
    axes[0, 0].legend()
    fig.suptitle(f"{result.environment}: {result.runs} Monte Carlo runs")
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return _save(fig, path)


def plot_sigma_bounds(result, path: str | Path, robot: int = 0) -> Path:
    """One run's pose errors with the filters' ±3σ bounds."""
    fig, axes = plt.subplots(
        3, len(result.example), figsize=(4.5 * len(result.example), 8), squeeze=False, sharex=True
    )
    for col, (name, m) in enumerate(result.example.items()):
        steps = np.arange(m.pose_error.shape[0])
        for row, label in enumerate(("x [m]", "y [m]", "φ [rad]")):
            ax = axes[row, col]
            ax.plot(steps, m.pose_error[:, robot, row], color=COLOURS.get(name), lw=0.9)
            ax.plot(steps, 3 * m.pose_sigma[:, robot, row], "k--", lw=0.7)
            ax.plot(steps, -3 * m.pose_sigma[:, robot, row], "k--", lw=0.7)
            ax.set_ylabel(label)
            if row == 0:
                ax.set_title(f"{LABELS.get(name, name)}: R{robot + 1} error and ±3σ")
        axes[-1, col].set_xlabel("step")
    fig.tight_layout()
    return _save(fig, path)


def plot_planar_map(
    trajectories: dict[str, list[np.ndarray]],
    features: dict[str, np.ndarray],
    path: str | Path,
    title: str = "",
) -> Path:
    """Top view of planar robot trajectories and feature maps, one panel per estimator."""
    names = list(trajectories)
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 5.5), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        for i, traj in enumerate(trajectories[name]):
            ax.plot(traj[:, 0], traj[:, 1], ls="-" if i == 0 else "--", lw=0.8, label=f"R{i + 1}")
        f = features.get(name)
        if f is not None and len(f):
            ax.plot(f[:, 0], f[:, 1], "k^", ms=3, label="features")
        ax.set_title(name)
        ax.set_aspect("equal")
        ax.legend(loc="best", fontsize=7)
    fig.suptitle(title)
    return _save(fig, path)


def plot_team_topview(dataset, results: dict, path: str | Path) -> Path:
    """Top view per run: ground truth, odometry and estimated trajectories, estimated objects."""
    from teamslam.eval.metrics import dead_reckoning

    names = list(results)
    fig, axes = plt.subplots(1, len(names), figsize=(6.5 * len(names), 6.0), squeeze=False)
    colours = plt.get_cmap("tab10")
    for ax, name in zip(axes[0], names, strict=True):
        result = results[name]
        ax.plot(
            dataset.object_positions[:, 0],
            dataset.object_positions[:, 1],
            "k.",
            ms=2,
            alpha=0.4,
            label="true objects",
        )
        for i, robot in enumerate(dataset.robots):
            c = colours(i % 10)
            gt = robot.T_world_body[:, :3, 3]
            odo = dead_reckoning(robot.T_world_body[0], robot.odometry)[:, :3, 3]
            est = result.poses[i][:, :3, 3]
            ax.plot(
                gt[:, 0], gt[:, 1], color="0.6", lw=0.8, label="ground truth" if i == 0 else None
            )
            ax.plot(
                odo[:, 0], odo[:, 1], ":", color=c, lw=0.8, label="odometry" if i == 0 else None
            )
            ax.plot(est[:, 0], est[:, 1], "-", color=c, lw=1.0, label=f"robot {i}")
            if len(result.objects[i]):
                ax.plot(result.objects[i][:, 0], result.objects[i][:, 1], "^", color=c, ms=2.5)
        ax.set_aspect("equal")
        ax.set_title(name)
        ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def plot_team_errors(dataset, results: dict, path: str | Path) -> Path:
    """Position error over time per robot, one panel per run, with odometry for reference."""
    from teamslam.eval.metrics import dead_reckoning

    names = list(results)
    fig, axes = plt.subplots(
        1, len(names), figsize=(6.5 * len(names), 4.0), squeeze=False, sharey=True
    )
    colours = plt.get_cmap("tab10")
    for ax, name in zip(axes[0], names, strict=True):
        for i, robot in enumerate(dataset.robots):
            c = colours(i % 10)
            gt = robot.T_world_body[:, :3, 3]
            odo = dead_reckoning(robot.T_world_body[0], robot.odometry)[:, :3, 3]
            est = results[name].poses[i][:, :3, 3]
            ax.plot(np.linalg.norm(est - gt, axis=1), color=c, lw=1.0, label=f"robot {i}")
            ax.plot(np.linalg.norm(odo - gt, axis=1), ":", color=c, lw=0.8)
        ax.set_title(f"{name}: position error (dotted: odometry)")
        ax.set_xlabel("frame")
        ax.set_ylabel("error [m]")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)
