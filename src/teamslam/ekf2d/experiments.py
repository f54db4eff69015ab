"""Monte Carlo comparison of the standard, ideal and first-estimate EKFs (Tables 1–2, Figs. 4–5).

Every run draws fresh noise on the environment's fixed ground truth and runs all filters on the
*same* data. Reported per filter, like the paper's tables: average NEES (eq. 25, normalised by
the dimension) of each robot's pose and of the features, and position/heading/feature RMSE,
each averaged over steps of the per-step value over runs. Beside each mean NEES: the median
over runs of the run's time-averaged NEES, and how many runs have a time-averaged NEES above
the single-step 97.5% χ² bound (a run that far off has diverged; one such run can dominate a
mean).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np
from scipy import stats

from teamslam.ekf2d.environments import PlanarEnvironment
from teamslam.ekf2d.linearization import policy as make_policy
from teamslam.ekf2d.run import RunMetrics, run_filter
from teamslam.ekf2d.simulate import PlanarTruth, simulate, truth_of
from teamslam.errors import InputError
from teamslam.parallel import run_parallel

__all__ = [
    "FILTERS",
    "MonteCarloResult",
    "format_table",
    "monte_carlo",
    "run_seeds",
    "run_seeds_of",
    "summarise_runs",
]

FILTERS = ("std", "ideal", "fej")
LABELS = {"std": "Standard", "ideal": "Ideal", "fej": "FEJ"}


def _one_run(
    seed: int,
    env: PlanarEnvironment,
    truth: PlanarTruth,
    filters: tuple[str, ...],
    observation_noise_scale: tuple[float, float] = (1.0, 1.0),
) -> dict[str, RunMetrics]:
    run = simulate(env, truth, np.random.default_rng(seed), observation_noise_scale)
    return {name: run_filter(env, run, make_policy(name)) for name in filters}


@dataclass
class MonteCarloResult:
    """Per-filter Monte Carlo statistics of one environment.

    ``curves[filter][metric]`` holds per-step values over runs (``pose_nees`` ``(K+1, N)``,
    ``position_rmse``, ``heading_rmse`` ``(K+1, N)``, ``feature_nees``, ``feature_rmse``
    ``(K+1,)``); ``table[filter]`` the averages; ``example[filter]`` the first run's metrics;
    ``run_pose_nees[filter]`` each run's pose NEES averaged over its steps ``(runs, N)`` (what
    the table's medians and counts above the χ² bound are taken over).
    """

    environment: str
    runs: int
    steps: int
    n_robots: int
    curves: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    table: dict[str, dict[str, float]] = field(default_factory=dict)
    example: dict[str, RunMetrics] = field(default_factory=dict)
    run_pose_nees: dict[str, np.ndarray] = field(default_factory=dict)


def _summarise(metrics: list[RunMetrics], n_robots: int) -> tuple[dict, dict, np.ndarray]:
    pose_nees = np.stack([m.pose_nees for m in metrics])[:, 1:]  # (R, K, N); step 0 anchored
    position_sq = np.stack([m.position_sq for m in metrics])
    heading_sq = np.stack([m.heading_sq for m in metrics])
    feature_nees = np.stack([m.feature_nees for m in metrics])  # (R, K+1)
    feature_sq = np.stack([m.feature_sq for m in metrics])
    curves = {
        "pose_nees": np.vstack([np.full((1, n_robots), np.nan), pose_nees.mean(axis=0)]),
        "position_rmse": np.sqrt(position_sq.mean(axis=0)),
        "heading_rmse": np.sqrt(heading_sq.mean(axis=0)),
        "feature_nees": np.nanmean(feature_nees, axis=0),
        "feature_rmse": np.sqrt(np.nanmean(feature_sq, axis=0)),
    }
    bound3 = stats.chi2.ppf(0.975, 3) / 3
    bound2 = stats.chi2.ppf(0.975, 2) / 2
    table: dict[str, float] = {}
    per_run_pose = pose_nees.mean(axis=1)  # (R, N)
    for i in range(n_robots):
        r = f"r{i + 1}"
        table[f"{r}_pose_nees"] = float(np.nanmean(curves["pose_nees"][1:, i]))
        table[f"{r}_position_rmse"] = float(curves["position_rmse"][1:, i].mean())
        table[f"{r}_heading_rmse"] = float(curves["heading_rmse"][1:, i].mean())
        table[f"{r}_pose_nees_median"] = float(np.median(per_run_pose[:, i]))
        # the mean's Monte Carlo standard error, from the spread of the runs' averages
        table[f"{r}_pose_nees_sem"] = float(
            np.std(per_run_pose[:, i], ddof=1) / np.sqrt(len(per_run_pose))
            if len(per_run_pose) > 1
            else np.nan
        )
        table[f"{r}_runs_above_bound"] = int(np.sum(per_run_pose[:, i] > bound3))
    per_run_feat = np.nanmean(feature_nees, axis=1)
    table["feature_nees"] = float(np.nanmean(curves["feature_nees"]))
    table["feature_rmse"] = float(np.nanmean(curves["feature_rmse"]))
    table["feature_nees_median"] = float(np.median(per_run_feat))
    table["feature_runs_above_bound"] = int(np.sum(per_run_feat > bound2))
    return curves, table, per_run_pose


def monte_carlo(
    env: PlanarEnvironment,
    runs: int = 100,
    seed: int = 0,
    filters: tuple[str, ...] = FILTERS,
    workers: int | None = None,
    progress: bool | None = None,
    observation_noise_scale: tuple[float, float] = (1.0, 1.0),
    scheduler: str | None = None,
) -> MonteCarloResult:
    """Run ``runs`` seeded Monte Carlo runs of every filter on ``env`` (the data's observation
    noise scaled per axis by ``observation_noise_scale``, see
    :func:`~teamslam.ekf2d.simulate.simulate`), over ``workers`` processes or, with
    ``scheduler`` (a Dask scheduler's address), each run a task there: the same result either
    way, bit for bit (:func:`~teamslam.parallel.run_parallel`)."""
    if runs < 1:
        raise InputError("runs must be positive")
    for name in filters:
        make_policy(name)
    job = partial(
        _one_run,
        env=env,
        truth=truth_of(env),
        filters=tuple(filters),
        observation_noise_scale=tuple(observation_noise_scale),
    )
    seeds = run_seeds_of(runs, seed)
    results = run_parallel(
        job, seeds, workers, progress, description=f"{env.name} Monte Carlo", scheduler=scheduler
    )
    return summarise_runs(env, results, filters)


def run_seeds_of(runs: int, seed: int = 0) -> list[int]:
    """The seeds of the ``runs`` Monte Carlo runs of :func:`monte_carlo` with ``seed``."""
    return [seed * 100_003 + k for k in range(runs)]


def run_seeds(
    seeds: list[int], env: PlanarEnvironment, filters: tuple[str, ...] = FILTERS
) -> list[dict[str, RunMetrics]]:
    """The Monte Carlo runs of ``seeds`` (a part of :func:`monte_carlo`'s runs, for a
    scheduler of many experiments): per run, per filter its metrics."""
    truth = truth_of(env)
    return [_one_run(s, env, truth, filters) for s in seeds]


def summarise_runs(
    env: PlanarEnvironment, results: list[dict[str, RunMetrics]], filters: tuple[str, ...] = FILTERS
) -> MonteCarloResult:
    """:func:`monte_carlo`'s result from its runs (:func:`run_seeds`, in seed order)."""
    steps = results[0][filters[0]].position_sq.shape[0] - 1
    out = MonteCarloResult(env.name, len(results), steps, env.n_robots)
    for name in filters:
        metrics = [r[name] for r in results]
        out.curves[name], out.table[name], out.run_pose_nees[name] = _summarise(
            metrics, env.n_robots
        )
        out.example[name] = metrics[0]
    return out


def format_table(result: MonteCarloResult) -> str:
    """The paper's table layout, with median NEES and runs above the bound."""
    cols = []
    for i in range(result.n_robots):
        r = f"r{i + 1}"
        cols += [
            (f"R{i + 1} pose NEES", f"{r}_pose_nees"),
            (f"R{i + 1} pos RMSE", f"{r}_position_rmse"),
            (f"R{i + 1} head RMSE", f"{r}_heading_rmse"),
        ]
    cols += [("feat NEES", "feature_nees"), ("feat RMSE", "feature_rmse")]
    width = 13
    head = f"{'EKF':<9}" + "".join(f"{c:>{width}}" for c, _ in cols)
    lines = [
        f"{result.environment}: {result.runs} Monte Carlo runs, {result.steps} steps",
        head,
        "-" * len(head),
    ]
    for name, table in result.table.items():
        lines.append(
            f"{LABELS.get(name, name):<9}" + "".join(f"{table[k]:>{width}.4f}" for _, k in cols)
        )
    lines.append("")
    lines.append("median over runs of each run's average NEES (runs above the 97.5% χ² bound):")
    for name, table in result.table.items():
        parts = [
            f"R{i + 1} {table[f'r{i + 1}_pose_nees_median']:.3f} "
            f"({table[f'r{i + 1}_runs_above_bound']})"
            for i in range(result.n_robots)
        ]
        parts.append(
            f"features {table['feature_nees_median']:.3f} ({table['feature_runs_above_bound']})"
        )
        lines.append(f"  {LABELS.get(name, name):<9}" + ", ".join(parts))
    return "\n".join(lines)
