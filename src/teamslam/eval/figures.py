"""Figures of team runs, one column per run so runs compare side by side.

* :func:`trajectories_figure` — every robot's estimate with the ground truth, top view and 3D;
* :func:`ape_over_time_figure` — each robot's position error over time;
* :func:`ape_path_figure` — the path coloured by its position error (one colour scale for all
  runs, so separate vs consensus read at a glance);
* :func:`nees_figure` — pose NEES / 6 over time per robot with the 95% χ² band of one robot
  (6 dof) and the team average with its own band (6·R dof);
* :func:`stage_times_figure` — time per robot per frame in each stage, stacked;
* :func:`graph_figure` — the communication graph.

Matplotlib with the Agg backend: no display needed.
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize

from teamslam.eval.runs import STAGES
from teamslam.eval.trajectory import TeamEvaluation
from teamslam.gaussian import chi2_band

__all__ = [
    "ape_over_time_figure",
    "ape_path_figure",
    "figure_png",
    "graph_figure",
    "nees_band",
    "nees_figure",
    "save_figure",
    "stage_times_figure",
    "trajectories_figure",
]

_COLUMN_WIDTH = 4.6


def _colour(k: int):
    return plt.get_cmap("tab10")(k % 10)


def figure_png(fig, dpi: int = 80) -> bytes:
    """The figure as PNG bytes (and closed)."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Write the figure as PNG (atomically) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    tmp.replace(path)
    return path


def trajectories_figure(names: list[str], evaluations: list[TeamEvaluation]):
    """Top view (first row) and 3D view (second row) of every robot and the ground truth."""
    n = len(names)
    fig = plt.figure(figsize=(_COLUMN_WIDTH * n, 8.4))
    for c, (name, ev) in enumerate(zip(names, evaluations, strict=True)):
        top = fig.add_subplot(2, n, c + 1)
        view = fig.add_subplot(2, n, n + c + 1, projection="3d")
        for k, robot in enumerate(ev.robots):
            gt, est = robot.reference[:, :3, 3], robot.estimate[:, :3, 3]
            label_gt = "ground truth" if k == 0 else None
            top.plot(gt[:, 0], gt[:, 1], color="0.65", lw=1.4, label=label_gt)
            top.plot(est[:, 0], est[:, 1], color=_colour(k), lw=0.9, label=robot.name)
            view.plot(gt[:, 0], gt[:, 1], gt[:, 2], color="0.65", lw=1.2)
            view.plot(est[:, 0], est[:, 1], est[:, 2], color=_colour(k), lw=0.8)
        top.set_aspect("equal", adjustable="datalim")
        top.set_title(f"{name}\ntop view (align: {ev.align}, {ev.scope})", fontsize=9)
        top.set_xlabel("x [m]")
        top.set_ylabel("y [m]")
        top.legend(fontsize=6, loc="best")
        view.set_xlabel("x [m]", fontsize=7)
        view.set_ylabel("y [m]", fontsize=7)
        view.set_zlabel("z [m]", fontsize=7)
        view.tick_params(labelsize=6)
        view.set_title("3D", fontsize=9)
    fig.tight_layout()
    return fig


def ape_over_time_figure(names: list[str], evaluations: list[TeamEvaluation]):
    """Position error (APE, translation) over time per robot."""
    n = len(names)
    fig, axes = plt.subplots(1, n, figsize=(_COLUMN_WIDTH * n, 3.2), squeeze=False, sharey=True)
    for ax, name, ev in zip(axes[0], names, evaluations, strict=True):
        for k, robot in enumerate(ev.robots):
            ax.plot(robot.timestamps, robot.ape["translation_m"], color=_colour(k), lw=0.9)
        ax.set_title(f"{name}: position error", fontsize=9)
        timed = all(robot.timed for robot in ev.robots)
        ax.set_xlabel("time [s]" if timed else "frame")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("APE [m]")
    fig.tight_layout()
    return fig


def ape_path_figure(names: list[str], evaluations: list[TeamEvaluation]):
    """Top view of each robot's path coloured by its position error; one scale for all runs."""
    n = len(names)
    top = max(
        (
            float(r.ape["translation_m"].max())
            for ev in evaluations
            for r in ev.robots
            if len(r.ape["translation_m"])
        ),
        default=1.0,
    )
    norm = Normalize(0.0, top if top > 0 else 1.0)
    fig, axes = plt.subplots(1, n, figsize=(_COLUMN_WIDTH * n + 0.8, 4.2), squeeze=False)
    mappable = None
    for ax, name, ev in zip(axes[0], names, evaluations, strict=True):
        lows, highs = [], []
        for robot in ev.robots:
            xy = robot.estimate[:, :2, 3]
            ax.plot(*robot.reference[:, :2, 3].T, color="0.8", lw=1.0)
            if len(xy) < 2:
                continue
            segments = np.stack([xy[:-1], xy[1:]], axis=1)
            err = robot.ape["translation_m"]
            lines = LineCollection(segments, cmap="viridis", norm=norm, lw=1.6)
            lines.set_array(0.5 * (err[:-1] + err[1:]))
            mappable = ax.add_collection(lines)
            lows.append(xy.min(axis=0))
            highs.append(xy.max(axis=0))
        if lows:
            lo, hi = np.min(lows, axis=0), np.max(highs, axis=0)
            pad = 0.05 * max(float(np.max(hi - lo)), 1e-9)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(f"{name}: APE along the path", fontsize=9)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    if mappable is not None:
        fig.colorbar(mappable, ax=list(axes[0]), label="APE [m]", shrink=0.85)
    return fig


def nees_band(dof: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` interval of NEES / dof for a consistent estimator
    (:func:`~teamslam.gaussian.chi2_band` of one sample)."""
    return chi2_band(dof, 1, probability)


def nees_figure(names: list[str], series: list[dict | None]):
    """Pose NEES / 6 over frames, per robot and team average, with 95% χ² bands."""
    n = len(names)
    fig, axes = plt.subplots(1, n, figsize=(_COLUMN_WIDTH * n, 3.4), squeeze=False, sharey=True)
    for ax, name, s in zip(axes[0], names, series, strict=True):
        ax.set_title(f"{name}: pose NEES / 6", fontsize=9)
        ax.set_xlabel("frame")
        if not s or not s["nees"]:
            ax.text(0.5, 0.5, "not recorded", ha="center", va="center", transform=ax.transAxes)
            continue
        lo, hi = nees_band(6)
        ax.axhspan(lo, hi, color="tab:green", alpha=0.12, label="95% band, one robot")
        for k, v in enumerate(s["nees"]):
            ax.plot(np.arange(1, len(v)), v[1:], color=_colour(k), lw=0.6, alpha=0.8)
        frames = min(len(v) for v in s["nees"])
        team = np.mean([v[1:frames] for v in s["nees"]], axis=0)
        ax.plot(np.arange(1, frames), team, color="k", lw=1.2, label="team average")
        lo_t, hi_t = nees_band(6 * len(s["nees"]))
        ax.axhline(lo_t, color="k", ls=":", lw=0.8)
        ax.axhline(hi_t, color="k", ls=":", lw=0.8, label="95% band, team average")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6, loc="upper right")
    fig.tight_layout()
    return fig


def stage_times_figure(names: list[str], series: list[dict | None]):
    """Milliseconds per robot per frame in each stage (mean over robots), stacked."""
    n = len(names)
    fig, axes = plt.subplots(1, n, figsize=(_COLUMN_WIDTH * n, 3.2), squeeze=False, sharey=True)
    for ax, name, s in zip(axes[0], names, series, strict=True):
        ax.set_title(f"{name}: time per robot per frame", fontsize=9)
        ax.set_xlabel("frame")
        if not s or not s["frame_times"]:
            ax.text(0.5, 0.5, "not recorded", ha="center", va="center", transform=ax.transAxes)
            continue
        frames = min(len(t) for t in s["frame_times"])
        mean_ms = 1e3 * np.mean([t[:frames] for t in s["frame_times"]], axis=0)
        ax.stackplot(np.arange(frames), mean_ms.T, labels=STAGES, alpha=0.85)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, loc="upper left")
    axes[0, 0].set_ylabel("ms")
    fig.tight_layout()
    return fig


def graph_figure(adjacency: np.ndarray, title: str = ""):
    """Robots on a circle and their communication links."""
    n = len(adjacency)
    angle = 2 * np.pi * np.arange(n) / max(n, 1) + np.pi / 2
    xy = np.column_stack([np.cos(angle), np.sin(angle)])
    fig, ax = plt.subplots(figsize=(2.6, 2.6))
    for i, j in zip(*np.nonzero(np.triu(adjacency)), strict=True):
        ax.plot(*xy[[i, j]].T, color="0.5", lw=1.0, zorder=1)
    for k in range(n):
        ax.scatter(*xy[k], s=260, color=_colour(k), zorder=2)
        ax.text(*xy[k], str(k), ha="center", va="center", color="white", fontsize=9)
    ax.set_xlim(-1.35, 1.35)
    ax.set_ylim(-1.35, 1.35)
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=9)
    return fig
