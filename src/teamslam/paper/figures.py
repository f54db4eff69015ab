"""The papers' figures from our runs (matplotlib, Agg backend), as PNG bytes.

* :func:`stage_bars_figure` — DVI Fig. 3: time per robot per frame in each component;
* :func:`loss_figure` — DVI Fig. 4: errors against the link loss rate, separate dashed;
* :func:`fej_curves_figure` — FEJ Figs. 4–5: per feature count and robot, pose NEES, position
  and heading RMSE over steps of each EKF.
"""

from __future__ import annotations

import numpy as np

from teamslam.eval.figures import figure_png
from teamslam.eval.plots import COLOURS, LABELS

__all__ = ["fej_curves_figure", "loss_figure", "stage_bars_figure"]

# DVI Fig. 3's components and the stages of ours that make each
COMPONENTS = {
    "MSCKF update": ("update",),
    "consensus averaging": ("consensus",),
    "other (prediction, landmark initialisation)": ("propagation", "initialisation"),
}


def component_times(timing_ms: dict) -> dict[str, float]:
    """DVI Fig. 3's components (ms per robot per frame) from a run's stage times."""
    return {name: sum(timing_ms[s] for s in stages) for name, stages in COMPONENTS.items()}


def stage_bars_figure(bars: dict[str, dict[str, float]]) -> bytes:
    """Stacked bars: per run (label) the ms per robot per frame of each component."""
    import matplotlib.pyplot as plt

    labels = list(bars)
    fig, ax = plt.subplots(figsize=(1.2 * len(labels) + 3.0, 3.6))
    bottom = np.zeros(len(labels))
    for name in COMPONENTS:
        values = np.array([bars[k][name] for k in labels])
        ax.bar(labels, values, bottom=bottom, label=name)
        bottom += values
    ax.set_ylabel("ms per robot per frame")
    ax.set_title("time per component (consensus runs)")
    ax.legend(fontsize=7)
    ax.tick_params(axis="x", labelsize=8, rotation=20)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return figure_png(fig, dpi=100)


def loss_figure(
    rates: list[float],
    consensus: dict[int, dict[str, list[float]]],
    separate: dict[int, dict[str, float]],
) -> bytes:
    """Trajectory RMSE and object error against the loss rate per team size; the separate
    filters' values dashed."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3.6))
    panels = (("trajectory", "trajectory RMSE [m]"), ("object", "object error [m]"))
    for ax, (key, title) in zip(axes, panels, strict=True):
        for k, n in enumerate(consensus):
            colour = plt.get_cmap("tab10")(k % 10)
            ax.plot(rates, consensus[n][key], "o-", color=colour, label=f"{n} robots")
            ax.axhline(separate[n][key], color=colour, ls="--", lw=0.9)
        ax.set_xlabel("loss rate r")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return figure_png(fig, dpi=100)


def fej_curves_figure(results: dict, title: str) -> bytes:
    """Per feature count and robot a row: pose NEES, position RMSE, heading RMSE over steps."""
    import matplotlib.pyplot as plt

    counts = list(results)
    n_robots = next(iter(results.values())).n_robots
    rows = len(counts) * n_robots
    fig, axes = plt.subplots(rows, 3, figsize=(12, 2.2 * rows), squeeze=False, sharex=True)
    metrics = (
        ("pose_nees", "pose NEES"),
        ("position_rmse", "position RMSE [m]"),
        ("heading_rmse", "heading RMSE [rad]"),
    )
    for c, count in enumerate(counts):
        result = results[count]
        steps = np.arange(result.steps + 1)
        for i in range(n_robots):
            row = axes[c * n_robots + i]
            for name, curves in result.curves.items():
                for ax, (key, _) in zip(row, metrics, strict=True):
                    ax.plot(
                        steps,
                        curves[key][:, i],
                        color=COLOURS.get(name),
                        lw=0.8,
                        label=LABELS.get(name, name),
                    )
            for ax, (_, label) in zip(row, metrics, strict=True):
                ax.set_title(f"{count} features, R{i + 1}: {label}", fontsize=8)
                ax.grid(alpha=0.3)
            row[0].axhline(1.0, color="k", lw=0.6, ls=":")
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("step")
    runs = next(iter(results.values())).runs
    fig.suptitle(f"{title}: {runs} Monte Carlo runs", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    return figure_png(fig, dpi=80)
