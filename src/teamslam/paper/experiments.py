"""The experiments behind the papers' tables and figures, as library calls.

Each runs what ``teamslam run`` (or ``teamslam fej``) would run — the settings resolved from the
data by :func:`teamslam.api.resolve_settings`, no noise level set by hand — and returns plain
numbers. ``benchmarks/msckf_team.py`` calls the same functions.

* :func:`kitti_pair` — separate and consensus MSCKFs on the published KITTI 00 team (DVI Tables
  I–III, Fig. 3);
* :func:`team_pairs` — separate and consensus on simulated Lissajous teams (DVI Table IV);
* :func:`loss_sweep` — consensus under link loss (DVI Fig. 4);
* :func:`fej_tables` — Monte Carlo of the standard, ideal and FEJ planar EKFs (FEJ Tables 1–2,
  Figs. 4–5).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from teamslam.errors import InputError

__all__ = [
    "TEAM_FILTERS",
    "PaperSettings",
    "fej_tables",
    "kitti_pair",
    "loss_sweep",
    "settings_summary",
    "stage_statistics",
    "team_pairs",
]

#: The two filters of every distributed-MSCKF table: without and with consensus averaging.
TEAM_FILTERS = ("separate", "consensus")

# what a team run's metrics keep for the tables and figures
_KEPT = (
    "trajectory_rmse_m",
    "trajectory_rmse_avg_m",
    "odometry_rmse_m",
    "object_error_m",
    "object_error_avg_m",
    "object_disagreement_m",
    "object_disagreement_avg_m",
    "time_per_robot_step_ms",
    "frames_per_robot",
    "nees_pose_avg",
)


@dataclass(frozen=True)
class PaperSettings:
    """How large the experiments are.

    Attributes
    ----------
    team_sizes
        Robots of the simulated teams (DVI Table IV and Fig. 4; the paper: 3, 5, 10, 15).
    seeds
        Simulated teams per size (different maps, paths and noise), averaged.
    steps
        Motion steps of each simulated robot.
    loss_rates
        Link loss rates of DVI Fig. 4.
    fej_runs
        Monte Carlo runs per FEJ environment and feature count (the paper: 100).
    fej_features
        Feature counts of the FEJ environments (the paper: 20, 60, 100).
    frames
        Only the first ``frames`` frames of each robot of the real data (``None``: all).
    workers
        Processes for the parallel runs (``None``: all cores).
    progress
        Progress bars (``None``: when standard error is a terminal).
    label
        A name for the output (``full``, ``quick``, ``custom``).
    """

    team_sizes: tuple[int, ...] = (3, 5, 10, 15)
    seeds: int = 3
    steps: int = 300
    loss_rates: tuple[float, ...] = (0.0, 0.3, 0.6, 0.9)
    fej_runs: int = 100
    fej_features: tuple[int, ...] = (20, 60, 100)
    frames: int | None = None
    workers: int | None = None
    progress: bool | None = None
    label: str = "full"

    def __post_init__(self) -> None:
        if not self.team_sizes or min(self.team_sizes) < 2:
            raise InputError("team sizes must be at least 2 robots")
        if self.seeds < 1 or self.steps < 2 or self.fej_runs < 1:
            raise InputError("seeds and Monte Carlo runs must be ≥ 1, steps ≥ 2")
        if not self.loss_rates or not all(0.0 <= r <= 1.0 for r in self.loss_rates):
            raise InputError("loss rates must be in [0, 1]")
        if not set(self.fej_features) <= {20, 60, 100}:
            raise InputError("FEJ feature counts are 20, 60 or 100")
        if self.frames is not None and self.frames < 2:
            raise InputError("frames must be at least 2")

    @classmethod
    def quick(cls, **changes) -> PaperSettings:
        """Fewer Monte Carlo runs and seeds, shorter simulated teams: every table and figure
        in minutes (what ``--quick`` runs)."""
        base = {
            "seeds": 1,
            "steps": 60,
            "loss_rates": (0.0, 0.5, 0.9),
            "fej_runs": 10,
            "label": "quick",
        }
        return cls(**{**base, **changes})

    def describe(self) -> str:
        """One line: the sizes used."""
        frames = "all frames" if self.frames is None else f"first {self.frames} frames"
        return (
            f"{self.label}: simulated teams of {', '.join(map(str, self.team_sizes))} robots, "
            f"{self.steps} steps, {self.seeds} seed(s); loss rates "
            f"{', '.join(f'{r:g}' for r in self.loss_rates)}; FEJ {self.fej_runs} Monte Carlo "
            f"runs (paper: 100); real data: {frames}"
        )


def _kept(metrics: dict) -> dict:
    return {k: metrics[k] for k in _KEPT}


def stage_statistics(result) -> dict[str, list[float]]:
    """Per stage and ``total``: mean, median and 95th percentile of the ms per robot per frame
    of a :class:`~teamslam.msckf.team.TeamResult` (frame 0 excluded)."""
    import numpy as np

    from teamslam.eval.runs import STAGES

    times = 1e3 * np.concatenate([f[1:] for f in result.frame_times])  # (robot-steps, stages)
    columns = {s: times[:, k] for k, s in enumerate(STAGES)}
    columns["total"] = times.sum(axis=1)
    return {
        s: [float(c.mean()), float(np.median(c)), float(np.percentile(c, 95))]
        for s, c in columns.items()
    }


def _team_run(dataset, mode: str, effective, loss: float = 0.0, seed: int = 0) -> dict:
    from teamslam import api

    run = api.run(dataset, mode=mode, settings=effective, loss=loss, seed=seed, progress=False)
    return {**_kept(run.by_mode[mode]), "stage_ms": stage_statistics(run.results[mode])}


def _kitti_job(k: int, dataset, effective) -> dict:
    return _team_run(dataset, TEAM_FILTERS[k], effective)


def settings_summary(dataset, effective) -> str:
    """The settings that matter for the tables, and where they came from."""
    config = effective.config
    sources = effective.sources
    tracks = sum(r.features.ids.size for r in dataset.robots)
    features = "on" if config.use_geometric_features else "off"
    parts = [
        f"window {config.window} ({sources.get('window', 'default')})",
        f"geometric features {features}" if tracks else "no geometric features in the data",
        f"noise levels from the {sources.get('odometry_std', 'default')}",
    ]
    return ", ".join(parts)


@dataclass
class KittiPair:
    """Separate and consensus on the KITTI 00 team: per filter the run's metrics."""

    metrics: dict[str, dict]
    settings: str
    frames: list[int] = field(default_factory=list)


def kitti_pair(
    directory: str | Path,
    frames: int | None = None,
    settings: dict | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> KittiPair:
    """Separate and consensus MSCKFs on a published team directory (KITTI 00), as ``teamslam
    data import-reference`` + ``teamslam run --compare`` would run them.

    Parameters
    ----------
    directory
        The published data (``calib``, ``inputs.npz``, ``poses.npz``, …).
    frames
        Only the first ``frames`` frames of each robot.
    settings
        Filter settings on top of those resolved from the data (``{name: value}``, as ``--set``).
    workers, progress
        The two filters run in parallel (:func:`~teamslam.eval.montecarlo.run_parallel`).
    """
    from teamslam import api
    from teamslam.datasets import import_reference
    from teamslam.eval.montecarlo import run_parallel

    dataset = import_reference(directory)
    if frames is not None:
        dataset = dataset.head(frames)
    effective = api.resolve_settings(dataset, settings)
    job = partial(_kitti_job, dataset=dataset, effective=effective)
    results = run_parallel(job, [0, 1], workers, progress, description="KITTI 00")
    return KittiPair(
        dict(zip(TEAM_FILTERS, results, strict=True)),
        settings_summary(dataset, effective),
        [r.frames for r in dataset.robots],
    )


def _simulated(robots: int, steps: int, seed: int):
    from teamslam.sim import lissajous_team

    return lissajous_team(robots=robots, steps=steps, seed=seed)


def _pair_job(k: int, cases: tuple, steps: int, settings: dict | None) -> dict:
    from teamslam import api

    robots, seed, mode, loss = cases[k]
    dataset = _simulated(robots, steps, seed)
    effective = api.resolve_settings(dataset, settings)
    out = _team_run(dataset, mode, effective, loss=loss, seed=1)
    out["settings"] = settings_summary(dataset, effective)
    return out


def _run_cases(cases, steps, settings, workers, progress, description) -> list[dict]:
    from teamslam.eval.montecarlo import run_parallel

    # the largest teams first: the pool ends with the short runs
    order = sorted(range(len(cases)), key=lambda k: -cases[k][0])
    job = partial(_pair_job, cases=tuple(cases[k] for k in order), steps=steps, settings=settings)
    done = run_parallel(job, list(range(len(cases))), workers, progress, description)
    results: list[dict] = [{}] * len(cases)
    for position, k in enumerate(order):
        results[k] = done[position]
    return results


def team_pairs(
    team_sizes: Sequence[int],
    seeds: int,
    steps: int,
    settings: dict | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> dict[int, dict[str, list[dict]]]:
    """Separate and consensus MSCKFs on simulated Lissajous teams (complete graph, no loss).

    Returns
    -------
    dict
        Per team size, per filter (``separate``, ``consensus``) the metrics of each seed.
    """
    cases = [(n, s, m, 0.0) for n in team_sizes for s in range(seeds) for m in TEAM_FILTERS]
    done = _run_cases(cases, steps, settings, workers, progress, "simulated teams")
    out: dict[int, dict[str, list[dict]]] = {n: {m: [] for m in TEAM_FILTERS} for n in team_sizes}
    for (n, _, mode, _), metrics in zip(cases, done, strict=True):
        out[n][mode].append(metrics)
    return out


def loss_sweep(
    team_sizes: Sequence[int],
    rates: Sequence[float],
    steps: int,
    seed: int = 0,
    settings: dict | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> dict[int, dict[str, Any]]:
    """Consensus on simulated teams when each link is lost at each step with probability ``r``
    (complete graph), and the separate filters for reference.

    Returns
    -------
    dict
        Per team size: ``separate`` (metrics) and ``consensus`` (rate → metrics).
    """
    cases = [(n, seed, "separate", 0.0) for n in team_sizes]
    cases += [(n, seed, "consensus", float(r)) for n in team_sizes for r in rates]
    done = _run_cases(cases, steps, settings, workers, progress, "link loss")
    out: dict[int, dict[str, Any]] = {n: {"consensus": {}} for n in team_sizes}
    for (n, _, mode, r), metrics in zip(cases, done, strict=True):
        if mode == "separate":
            out[n]["separate"] = metrics
        else:
            out[n]["consensus"][r] = metrics
    return out


@dataclass
class FejTables:
    """FEJ Monte Carlo of one environment: per feature count the result, and where each
    environment came from."""

    results: dict[int, Any]
    sources: dict[int, str]
    published: dict[int, bool]


def fej_tables(
    env: int,
    features: Sequence[int],
    runs: int,
    data: str | Path | None = None,
    seed: int = 0,
    workers: int | None = None,
    progress: bool | None = None,
) -> FejTables:
    """Monte Carlo of the standard, ideal and FEJ EKFs on FEJ environment ``env`` for each
    feature count, as ``teamslam fej table`` runs it.

    Where ``data/fej-environments`` holds the paper's own environment files for a feature
    count (``RobotsWaypoints_<env>.mat`` and ``CheckedTrueState_<F>features_<env>.mat``) they
    are used; otherwise the generated environment with the paper's parameters.
    """
    from teamslam import api
    from teamslam.ekf2d.experiments import monte_carlo

    results, sources, published = {}, {}, {}
    folder = None if data is None else Path(data) / "fej-environments"
    for count in features:
        files: tuple[Path, ...] = ()
        if folder is not None:
            pair = (
                folder / f"RobotsWaypoints_{env}.mat",
                folder / f"CheckedTrueState_{count}features_{env}.mat",
            )
            files = pair if all(f.is_file() for f in pair) else ()
        environment = api.fej_environment(env, count, files)
        published[count] = bool(files)
        sources[count] = (
            "the published environment files " + " + ".join(f.name for f in files)
            if files
            else f"our generated environment {env} with the paper's parameters"
        )
        results[count] = monte_carlo(
            environment, runs=runs, seed=seed, workers=workers, progress=progress
        )
    return FejTables(results, sources, published)
