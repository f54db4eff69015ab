"""Every table and figure of both papers, from our runs, with the paper's numbers beside ours.

:data:`ITEMS` lists what can be reproduced; :class:`Reproducer` runs the experiments each needs
(each experiment once, shared by the tables and figures that use it) and builds
:class:`~teamslam.paper.compare.Reproduction` objects; :func:`reproduce_all` writes them all
with ``report.html``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from teamslam.errors import InputError, InternalError
from teamslam.paper import experiments as ex
from teamslam.paper.compare import Cell, Reproduction
from teamslam.paper.values import paper_values

if TYPE_CHECKING:
    from teamslam.eval.studies import RunStore

__all__ = [
    "ITEMS",
    "NEEDS",
    "TASKS_DIR",
    "Item",
    "Reproducer",
    "item_key",
    "reproduce_all",
    "task_store",
]


@dataclass(frozen=True)
class Item:
    """A table or figure of a paper."""

    key: str
    paper: str
    kind: str
    number: str
    title: str
    data: str


_ITEM_ROWS = (
    ("dvi-table-1", "dvi", "table", "1", "Trajectory RMSE [m] on KITTI (Table I)", "KITTI 00"),
    ("dvi-table-2", "dvi", "table", "2", "Object errors [m] on KITTI (Table II)", "KITTI 00"),
    (
        "dvi-table-3",
        "dvi",
        "table",
        "3",
        "Object position differences across robots [m] on KITTI (Table III)",
        "KITTI 00",
    ),
    (
        "dvi-table-4",
        "dvi",
        "table",
        "4",
        "Errors and consensus averaging time vs team size, simulation (Table IV)",
        "simulated teams",
    ),
    (
        "dvi-figure-3",
        "dvi",
        "figure",
        "3",
        "Time per component per robot per frame (Fig. 3)",
        "KITTI 00, simulated teams",
    ),
    (
        "dvi-figure-4",
        "dvi",
        "figure",
        "4",
        "Effect of link loss on the errors (Fig. 4)",
        "simulated teams",
    ),
    (
        "fej-table-1",
        "fej",
        "table",
        "1",
        "EKFs on environment 1, 20/60/100 features (Table 1)",
        "environment 1",
    ),
    (
        "fej-table-2",
        "fej",
        "table",
        "2",
        "EKFs on environment 2, 20/60/100 features (Table 2)",
        "environment 2",
    ),
    (
        "fej-figure-4",
        "fej",
        "figure",
        "4",
        "NEES and RMSE over time, environment 1 (Figure 4)",
        "environment 1",
    ),
    (
        "fej-figure-5",
        "fej",
        "figure",
        "5",
        "NEES and RMSE over time, environment 2 (Figure 5)",
        "environment 2",
    ),
    (
        "fej-figure-6",
        "fej",
        "figure",
        "6",
        "Victoria Park trajectories and features (Figure 6)",
        "Victoria Park",
    ),
    (
        "fej-victoria-park",
        "fej",
        "table",
        "victoria-park",
        "Victoria Park two-robot split: RMSE against the batch reference",
        "Victoria Park",
    ),
)
ITEMS = {row[0]: Item(*row) for row in _ITEM_ROWS}

ROMAN = {"1": "I", "2": "II", "3": "III", "4": "IV"}
FEJ_FILTERS = {"Standard": "std", "Ideal": "ideal", "FEJ": "fej"}
FEJ_COLUMNS = {
    "Robot 1 Pose NEES": "r1_pose_nees",
    "Robot 1 Position RMSE": "r1_position_rmse",
    "Robot 1 Heading RMSE": "r1_heading_rmse",
    "Robot 2 Pose NEES": "r2_pose_nees",
    "Robot 2 Position RMSE": "r2_position_rmse",
    "Robot 2 Heading RMSE": "r2_heading_rmse",
    "Feature Position NEES": "feature_nees",
    "Feature Position RMSE": "feature_rmse",
}
# DVI Tables I–III: the rows of KITTI 00 and the metric of each
KITTI_ROWS = {
    "I": {
        "libviso2 [38]": ("separate", "odometry_rmse_m"),
        "00 Separate": ("separate", "trajectory_rmse_m"),
        "00 Consensus": ("consensus", "trajectory_rmse_m"),
    },
    "II": {
        "00 Separate": ("separate", "object_error_m"),
        "00 Consensus": ("consensus", "object_error_m"),
    },
    "III": {
        "00 Separate": ("separate", "object_disagreement_m"),
        "00 Consensus": ("consensus", "object_disagreement_m"),
    },
}
TABLE4_ROWS = {
    "Separate trajectory RMSE (m)": ("separate", "trajectory_rmse_avg_m", 1.0),
    "Consensus trajectory RMSE (m)": ("consensus", "trajectory_rmse_avg_m", 1.0),
    "Separate object error (m)": ("separate", "object_error_avg_m", 1.0),
    "Consensus object error (m)": ("consensus", "object_error_avg_m", 1.0),
    "Consensus averaging time (s)": ("consensus", "consensus_ms", 1e-3),
}


def item_key(paper: str, kind: str, number: str) -> str:
    """The key of a paper's table or figure (``dvi``, ``table``, ``1`` → ``dvi-table-1``).

    Raises
    ------
    InputError
        The paper has no such table or figure.
    """
    key = f"{paper}-victoria-park" if kind == "victoria-park" else f"{paper}-{kind}-{number}"
    if key not in ITEMS:
        have = ", ".join(i.number for i in ITEMS.values() if i.paper == paper and i.kind == kind)
        raise InputError(f"the {paper} paper has no {kind} {number} to reproduce (have: {have})")
    return key


def _finite_mean(values) -> float:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def _finite_max(values) -> float:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(v.max()) if v.size else math.nan


#: The experiments each table or figure needs (:meth:`Reproducer.run`).
NEEDS = {
    "dvi-table-1": ("kitti",),
    "dvi-table-2": ("kitti",),
    "dvi-table-3": ("kitti",),
    "dvi-table-4": ("teams",),
    "dvi-figure-3": ("kitti", "teams"),
    "dvi-figure-4": ("loss",),
    "fej-table-1": ("fej-env1",),
    "fej-table-2": ("fej-env2",),
    "fej-figure-4": ("fej-env1",),
    "fej-figure-5": ("fej-env2",),
    "fej-figure-6": ("victoria-park",),
    "fej-victoria-park": ("victoria-park",),
}


class Reproducer:
    """Runs the experiments behind the papers' tables and figures, each once.

    :meth:`run` runs the tasks of every experiment a set of tables and figures needs in one
    process pool, longest first (:func:`~teamslam.paper.experiments.run_experiments`); a table
    built without it runs what it needs alone.

    Parameters
    ----------
    settings
        Sizes of the experiments (:class:`~teamslam.paper.experiments.PaperSettings`).
    data
        The data directory (``distributed-msckf/kitti00``, ``fej-environments``,
        ``victoria-park``); what is absent is reported in the setting lines, not computed.
    store
        Keeps each task's result as it finishes, and gives back those it holds
        (:func:`task_store`).

    Attributes
    ----------
    seconds
        Per experiment run: the CPU seconds of its tasks (a task two experiments share counts
        for the first).
    schedules
        The :class:`~teamslam.eval.schedule.Schedule` of each pool run: wall time, and the CPU
        time each worker was given.
    """

    def __init__(
        self,
        settings: ex.PaperSettings | None = None,
        data: str | Path | None = None,
        store: RunStore | None = None,
    ):
        self.settings = settings or ex.PaperSettings()
        self.data = None if data is None else Path(data)
        self.store = store
        self.seconds: dict[str, float] = {}
        self.schedules: list = []
        self._cache: dict[str, Any] = {}
        self._charged: set[str] = set()

    # ------------------------------------------------------------------ experiments
    def _path(self, *parts: str) -> Path | None:
        if self.data is None:
            return None
        path = self.data.joinpath(*parts)
        return path if path.exists() else None

    def _define(self, name: str) -> ex.Experiment | None:
        """The experiment ``name`` at these settings (``None``: its data is absent)."""
        s = self.settings
        if name == "kitti":
            path = self._path("distributed-msckf", "kitti00")
            return None if path is None else ex.kitti_experiment(path, s.frames)
        if name == "teams":
            return ex.team_experiment(s.team_sizes, s.seeds, s.steps)
        if name == "loss":
            return ex.loss_experiment(s.team_sizes, s.loss_rates, s.steps, 0)
        if name.startswith("fej-env"):
            env = int(name.removeprefix("fej-env"))
            return ex.fej_experiment(env, s.fej_features, s.fej_runs, self.data, 0)
        if name == "victoria-park":
            path = self._path("victoria-park")
            return None if path is None else ex.victoria_park_experiment(path)
        raise InternalError(f"no experiment {name!r}")

    def run(self, keys: list[str] | None = None) -> None:
        """Run, in one process pool, every experiment the tables and figures ``keys`` (default:
        all) need that has not run yet."""
        names = dict.fromkeys(n for k in (keys or list(ITEMS)) for n in NEEDS[k])
        todo = {}
        for name in names:
            if name in self._cache:
                continue
            experiment = self._define(name)
            if experiment is None:
                self._cache[name] = None
            else:
                todo[name] = experiment
        if not todo:
            return
        s = self.settings
        results, schedule = ex.run_experiments(
            todo, s.workers, s.progress, "paper experiments", s.scheduler, self.store
        )
        self.schedules.append(schedule)
        charged: set = set()
        for name, experiment in todo.items():
            keys_of = {t.key for t in experiment.tasks} - charged
            charged |= keys_of
            self.seconds[name] = sum(schedule.cpu[k] for k in keys_of)
        self._cache.update(results)

    def _get(self, name: str) -> Any:
        if name not in self._cache:
            self.run([k for k, needs in NEEDS.items() if name in needs][:1])
        return self._cache[name]

    def kitti(self) -> ex.KittiPair | None:
        """Separate and consensus on KITTI 00 (``None`` without the data)."""
        return self._get("kitti")

    def teams(self) -> dict:
        """Separate and consensus on the simulated teams."""
        return self._get("teams")

    def loss(self) -> dict:
        """The link-loss sweep."""
        return self._get("loss")

    def fej(self, env: int) -> ex.FejTables:
        """The FEJ Monte Carlo of environment ``env``."""
        return self._get(f"fej-env{env}")

    def victoria_park(self) -> tuple[dict, bytes] | None:
        """Std and FEJ EKFs on the Victoria Park split: summary and the figure's PNG."""
        return self._get("victoria-park")

    def timing(self) -> dict[str, Any]:
        """Wall seconds of the pool runs, the workers, the CPU seconds each worker was given
        and the most of them (per pool run, summed: what the runs would take with a free core
        per worker), and per task its CPU and wall seconds, worker and place in the start
        order."""
        return {
            "wall_seconds": sum(s.seconds for s in self.schedules),
            "workers": max((s.workers for s in self.schedules), default=0),
            "worker_cpu_seconds": [s.worker_cpu() for s in self.schedules],
            "critical_path_seconds": sum(s.critical_path() for s in self.schedules),
            "tasks": [
                {"task": ex.task_label(key), "cpu": s.cpu[key], "wall": s.wall[key]}
                | {"worker": s.worker[key], "start": s.order.index(key)}
                for s in self.schedules
                for key in s.order
            ],
        }

    def time_text(self) -> str:
        """One line: CPU seconds per experiment, the wall time and the most CPU time one
        worker was given."""
        timing = self.timing()
        cpu = ", ".join(f"{k} {v:.0f} s" for k, v in self.seconds.items())
        return (
            f"experiments (CPU): {cpu}; total {sum(self.seconds.values()):.0f} s CPU in "
            f"{timing['wall_seconds']:.0f} s wall on {timing['workers']} worker(s), the most "
            f"CPU one worker was given {timing['critical_path_seconds']:.0f} s"
        )

    # ------------------------------------------------------------------ tables and figures
    def build(self, key: str) -> Reproduction:
        """The table or figure ``key`` of :data:`ITEMS`, its experiments run if not yet."""
        if key not in ITEMS:
            raise InputError(f"unknown table or figure {key!r} (have: {', '.join(ITEMS)})")
        self.run([key])
        result = getattr(self, "_" + key.replace("-", "_"))(ITEMS[key])
        # the CPU time of the experiments this is the first to use
        first = [n for n in NEEDS[key] if n in self.seconds and n not in self._charged]
        self._charged.update(first)
        result.seconds = sum(self.seconds[n] for n in first)
        result.setting.append(self.settings.describe())
        return result

    def _missing(self, what: str, *parts: str) -> str:
        where = (
            "(no data directory given)" if self.data is None else str(self.data.joinpath(*parts))
        )
        return f"{what} not found at {where}: ours not computed (—)"

    def _kitti_table(self, item: Item) -> Reproduction:
        table = ROMAN[item.number]
        pair = self.kitti()
        rows = KITTI_ROWS[table]
        out = Reproduction(item.key, item.title)
        for v in paper_values("dvi", table):
            ours = None
            if pair is not None and v.row in rows:
                mode, metric = rows[v.row]
                per_robot = pair.metrics[mode][metric]
                if v.column.startswith("Robot "):
                    ours = per_robot[int(v.column.split()[1]) - 1]
                else:
                    ours = (_finite_mean if v.column == "Avg" else _finite_max)(per_robot)
            out.cells.append(Cell.of(v, ours, own_data=pair is not None and v.row in rows))
        if pair is None:
            out.setting.append(self._missing("KITTI 00", "distributed-msckf", "kitti00"))
            return out
        out.setting += [
            "KITTI 00 is the paper's own data (difference in brackets); sequences 05, 06 and 08 "
            "are not published with the paper's code: ours —",
            "objects only: the published geometric-feature file of sequence 00 is not available "
            "(the paper used FAST feature tracks and objects)",
            f"settings resolved from the data as `teamslam run` does: {pair.settings}",
            f"frames per robot: {', '.join(map(str, pair.frames))}; complete graph",
        ]
        if table == "I":
            out.setting.append(
                "libviso2 row: the published libviso2 odometry composed from each robot's true "
                "first pose (dead reckoning), RMSE without alignment"
            )
        return out

    _dvi_table_1 = _dvi_table_2 = _dvi_table_3 = _kitti_table

    def _team_average(self, runs: list[dict], metric: str) -> float:
        if metric == "consensus_ms":
            return _finite_mean([r["time_per_robot_step_ms"]["consensus"] for r in runs])
        return _finite_mean([r[metric] for r in runs])

    def _dvi_table_4(self, item: Item) -> Reproduction:
        teams = self.teams()
        out = Reproduction(item.key, item.title)
        values = {(v.row, v.column): v for v in paper_values("dvi", "IV")}
        columns = [v.column for v in paper_values("dvi", "IV") if v.row == next(iter(TABLE4_ROWS))]
        columns += [f"{n} robots" for n in teams if f"{n} robots" not in columns]
        for row, (mode, metric, scale) in TABLE4_ROWS.items():
            for column in columns:
                n = int(column.split()[0])
                v = values.get((row, column))
                ours = scale * self._team_average(teams[n][mode], metric) if n in teams else None
                out.cells.append(
                    Cell(
                        "dvi",
                        "IV",
                        row,
                        column,
                        "s" if scale != 1.0 else "m",
                        None if v is None else v.value,
                        ours,
                        3 if v is None else v.digits,
                    )
                )
        settings = next(iter(teams.values()))["consensus"][0]["settings"]
        s = self.settings
        out.setting += [
            "our simulated teams (Lissajous paths, 210 objects and geometric landmarks, stereo "
            "pixel noise), with the paper's team sizes; the paper's simulated data is not "
            "published, so no difference is given",
            f"{s.steps} steps per robot, mean over {s.seeds} team(s) per size (different paths, "
            f"map and noise), complete graph; settings resolved from the data: {settings}",
            "averaging time: our consensus stage, wall clock per robot per step on this machine "
            "(the paper's is theirs)",
        ]
        return out

    def _dvi_figure_3(self, item: Item) -> Reproduction:
        from teamslam.paper.figures import component_times, stage_bars_figure

        out = Reproduction(item.key, item.title)
        bars = {}
        pair = self.kitti()
        if pair is None:
            out.setting.append(self._missing("KITTI 00", "distributed-msckf", "kitti00"))
        else:
            bars["KITTI 00"] = component_times(pair.metrics["consensus"]["time_per_robot_step_ms"])
        for n, runs in self.teams().items():
            timing = {
                s: _finite_mean([r["time_per_robot_step_ms"][s] for r in runs["consensus"]])
                for s in ("consensus", "propagation", "update", "initialisation")
            }
            bars[f"{n} robots (sim)"] = component_times(timing)
        for label, parts in bars.items():
            for name, ms in parts.items():
                out.cells.append(Cell("dvi", "Fig. 3", label, name, "ms", None, ms, 2))
        out.figure = stage_bars_figure(bars)
        out.setting += [
            "the paper plots KITTI 00, 05, 06, 08; ours: KITTI 00 (objects only) and our "
            "simulated teams (features and objects); the paper's own values are not printed",
            "wall-clock times of this machine, shared with other work (compare the shares, not "
            "the absolute times)",
        ]
        return out

    def _dvi_figure_4(self, item: Item) -> Reproduction:
        from teamslam.paper.figures import loss_figure

        sweep = self.loss()
        rates = [float(r) for r in self.settings.loss_rates]
        out = Reproduction(item.key, item.title)
        consensus, separate = {}, {}
        for n, runs in sweep.items():
            consensus[n] = {
                "trajectory": [runs["consensus"][r]["trajectory_rmse_avg_m"] for r in rates],
                "object": [runs["consensus"][r]["object_error_avg_m"] for r in rates],
            }
            separate[n] = {
                "trajectory": runs["separate"]["trajectory_rmse_avg_m"],
                "object": runs["separate"]["object_error_avg_m"],
            }
            rows = [("separate", separate[n]["trajectory"], separate[n]["object"])]
            rows += [
                (f"consensus, r = {r:g}", t, o)
                for r, t, o in zip(
                    rates, consensus[n]["trajectory"], consensus[n]["object"], strict=True
                )
            ]
            for label, t, o in rows:
                row = f"{n} robots, {label}"
                out.cells.append(Cell("dvi", "Fig. 4", row, "trajectory RMSE", "m", None, t, 3))
                out.cells.append(Cell("dvi", "Fig. 4", row, "object error", "m", None, o, 3))
        out.figure = loss_figure(rates, consensus, separate)
        out.setting += [
            "each link lost independently at each step with probability r (complete graph), "
            "one simulated team per size; dashed: separate filters",
            "the paper's figure prints no numbers: ours only",
        ]
        return out

    def _fej_table(self, item: Item) -> Reproduction:
        env = int(item.number)
        tables = self.fej(env)
        out = Reproduction(item.key, item.title)
        for v in paper_values("fej", item.number):
            count_text, _, ekf = v.row.partition(" features ")
            count = int(count_text)
            result = tables.results.get(count)
            ours = None if result is None else result.table[FEJ_FILTERS[ekf]][FEJ_COLUMNS[v.column]]
            out.cells.append(Cell.of(v, ours, own_data=tables.published.get(count, False)))
        for count, source in tables.sources.items():
            out.setting.append(f"{count} features: {source}")
        runs = next(iter(tables.results.values())).runs
        out.setting += [
            f"{runs} Monte Carlo runs per feature count (the paper: 100), all three EKFs on the "
            "same noise of each run; heading RMSE in rad; NEES normalised by the dimension",
            "where the environment is the paper's own file, ours − theirs is in brackets; "
            "elsewhere the environment is ours (same noise levels, loops and sensing range), "
            "so only the pattern compares",
        ]
        return out

    _fej_table_1 = _fej_table_2 = _fej_table

    def _fej_figure(self, item: Item) -> Reproduction:
        from teamslam.paper.figures import fej_curves_figure

        env = 1 if item.number == "4" else 2
        tables = self.fej(env)
        out = Reproduction(item.key, item.title)
        out.figure = fej_curves_figure(tables.results, f"environment {env}")
        out.setting += [f"{count} features: {src}" for count, src in tables.sources.items()]
        out.setting.append(f"the averages of these curves are fej-table-{env}")
        return out

    _fej_figure_4 = _fej_figure_5 = _fej_figure

    def _fej_victoria_park(self, item: Item) -> Reproduction:
        out = Reproduction(item.key, item.title)
        run = self.victoria_park()
        published = {(v.row, v.column): v for v in paper_values("fej", "victoria-park")}
        labels = {"std": "Std-EKF", "fej": "FEJ-EKF"}
        for name, label in labels.items():
            r = None if run is None else run[0][name]
            columns: list[tuple[str, str, Any]] = [
                ("Robot 1 Position RMSE", "m", None if r is None else r["position_rmse_m"][0]),
                ("Robot 2 Position RMSE", "m", None if r is None else r["position_rmse_m"][1]),
                ("Robot 1 Heading RMSE", "rad", None if r is None else r["heading_rmse_rad"][0]),
                ("Robot 2 Heading RMSE", "rad", None if r is None else r["heading_rmse_rad"][1]),
                ("Feature Position RMSE", "m", None if r is None else r["feature_rmse_m"]),
            ]
            for column, unit, ours in columns:
                v = published.get((label, column))
                out.cells.append(
                    Cell(
                        "fej",
                        "victoria-park",
                        label,
                        column,
                        unit,
                        None if v is None else v.value,
                        ours,
                        {"rad": 4}.get(unit, 3) if v is None else v.digits + 1,
                        own_data=v is not None and r is not None,
                        source="published code",
                    )
                )
        if run is None:
            out.setting.append(self._missing("Victoria Park", "victoria-park"))
            return out
        out.figure = run[1]
        seconds = ", ".join(f"{labels[k]} {v['seconds']:.1f} s" for k, v in run[0].items())
        out.setting += [
            "the paper prints no numbers for Victoria Park (only Figure 6); beside ours: the "
            "published MATLAB code's RMSE on the same split (23–27 s per filter in Octave)",
            "errors against the reference batch Gauss–Newton solution of the whole run (the "
            "true poses are unknown); each robot's mean noise covariance",
            f"our time per filter: {seconds}",
        ]
        return out

    def _fej_figure_6(self, item: Item) -> Reproduction:
        out = Reproduction(item.key, item.title)
        run = self.victoria_park()
        if run is None:
            out.setting.append(self._missing("Victoria Park", "victoria-park"))
            return out
        out.figure = run[1]
        out.setting.append(
            "reference (Gauss–Newton), Std-EKF and FEJ-EKF side by side; RMSE in fej-victoria-park"
        )
        return out


#: The folder of an output directory each task's result is kept in as it finishes.
TASKS_DIR = "tasks"


def task_store(
    out: str | Path, settings: ex.PaperSettings, data: str | Path | None, resume: bool = False
) -> RunStore:
    """The :class:`~teamslam.eval.studies.RunStore` of ``out/tasks``: one pickle per finished
    task, of a study named by the sizes of ``settings`` (not the workers or the scheduler),
    the data directory and teamslam's version.

    Raises
    ------
    InputError
        ``resume`` and the folder holds tasks of other settings (named), or ``settings`` asks
        for a scheduler without the ``cluster`` extra (checked before anything is written).
    """
    from dataclasses import asdict

    from teamslam._optional import require
    from teamslam._version import __version__
    from teamslam.eval.studies import RunStore, load_pickle, save_pickle

    if settings.scheduler is not None:
        require("distributed", "cluster", "running on a Dask cluster")
    ignored = ("workers", "progress", "label", "scheduler")
    study = {k: v for k, v in asdict(settings).items() if k not in ignored}
    study |= {"data": None if data is None else str(data), "teamslam": __version__}
    return RunStore(Path(out) / TASKS_DIR, study, resume, ".pkl", save_pickle, load_pickle)


def reproduce_all(
    out: str | Path,
    settings: ex.PaperSettings | None = None,
    data: str | Path | None = None,
    keys: list[str] | None = None,
    on_done: Callable[[Reproduction], None] | None = None,
    header: str | None = None,
    resume: bool = False,
    keep_tasks: bool | None = None,
) -> tuple[list[Reproduction], Reproducer]:
    """Every table and figure (or those of ``keys``), each written into ``out`` (Markdown,
    JSON, PNG), then ``out/report.html`` and ``out/paper.json`` (every cell).

    With ``keep_tasks`` (default: when resuming or on a Dask cluster) each task's result is
    kept in ``out/tasks`` as it finishes (:func:`task_store`); with ``resume`` those kept there
    are read back, not run again. ``on_done`` is called with each reproduction as soon as it is
    built; ``header``, if given, is the first line of every Markdown file
    (:meth:`Reproduction.write`).
    """
    from teamslam.eval.outputs import write_json
    from teamslam.paper.report import write_paper_report

    settings = settings or ex.PaperSettings()
    if keep_tasks is None:
        keep_tasks = resume or settings.scheduler is not None
    store = task_store(out, settings, data, resume) if keep_tasks or resume else None
    reproducer = Reproducer(settings, data, store)
    reproducer.run(keys)
    done = []
    for key in keys or list(ITEMS):
        result = reproducer.build(key)
        result.write(out, header)
        done.append(result)
        if on_done is not None:
            on_done(result)
    write_json(
        Path(out) / "paper.json",
        {
            "settings": reproducer.settings.describe(),
            "seconds": reproducer.seconds,
            "schedule": reproducer.timing(),
            "cells": [r for item in done for r in item.records()],
        },
    )
    write_paper_report(Path(out) / "report.html", done, reproducer)
    return done, reproducer
