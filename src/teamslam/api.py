"""The workflows of ``teamslam``, as library calls: the command line only parses and prints.

* :func:`run` — the distributed MSCKF (or separate MSCKFs, both, or the centralised filter)
  over a team dataset, in this process or one process per robot; returns a :class:`Run` whose
  ``metrics`` are what ``metrics.json`` holds, and writes the run directory when given one;
* :func:`write_run` / :func:`load_run` — that directory (``metrics.json``, TUM trajectories,
  estimates, results, figures, report) and back;
* :func:`launch` — a team file's robots as processes, gathered into a :class:`Run`;
  :func:`run_robot` — one of them (``teamslam agent``);
* :func:`calibrate` — a dataset's sensor model from its data;
* :func:`evaluate` — APE/RPE of runs against ground truth;
* :func:`export` — a run directory as MCAP.

Example::

    import teamslam

    run = teamslam.run("results/team5", mode="compare", settings={"filter.window": 10})
    teamslam.write_run(run, "results/team5-run")
    print(run.metrics["trajectory_rmse_avg_m"])

A run directory is written whole or not at all (:func:`teamslam.eval.outputs.stage_run_directory`):
it is checked before any data is read (a file, a non-empty directory that is no run, an earlier
run without ``overwrite``, a parent that cannot be written are refused), written into a staging
folder beside it with ``run.json`` last, and moved into place at the end; an interrupted write
leaves what was there before.

When a filter fails mid-run (:class:`~teamslam.errors.EstimationError`, naming robot and frame),
what was computed is not lost: with an output directory the frames done are written first
(result files and ``run.json`` marked ``complete: false``, TUM trajectories), then the error is
raised.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from teamslam._optional import require
from teamslam.errors import EstimationError, InputError

if TYPE_CHECKING:
    from teamslam.sim.detector import DetectorConfig
    from teamslam.sim.render import RenderedTeam

__all__ = [
    "MODES",
    "Run",
    "calibrate",
    "evaluate",
    "export",
    "foxglove_ports",
    "launch",
    "load_run",
    "require_extras",
    "run",
    "run_robot",
    "simulate_images",
    "write_run",
]

#: Runs of :func:`run`'s ``mode``: which filters it runs, by the name of their column.
MODES = {
    "consensus": ("consensus",),
    "separate": ("separate",),
    "compare": ("separate", "consensus"),
    "centralised": ("centralised",),
}


@dataclass
class Run:
    """A run of the filter over a team dataset.

    Attributes
    ----------
    dataset
        The team dataset (``None`` when a loaded run's dataset is not at hand).
    results
        :class:`~teamslam.msckf.team.TeamResult` per filter: ``consensus``, ``separate``,
        ``centralised``.
    by_mode
        Per filter its metrics (:func:`~teamslam.eval.metrics.team_metrics` and the effective
        settings): a row of the table.
    graph, loss
        The communication graph's name and the link loss.
    exit_codes
        Per robot process its exit status (runs as processes only).
    notes
        What the user should know (robots that ran alone, lost neighbours), one line each.
    warnings
        What went wrong without stopping the run (robot processes that failed), one line each.
    source
        The dataset's directory, when the run was given one.
    written
        What :func:`write_run` wrote: ``directory``, ``report``, ``mcap`` (its summary).
    """

    dataset: Any
    results: dict = field(default_factory=dict)
    by_mode: dict = field(default_factory=dict)
    graph: str = ""
    loss: float = 0.0
    exit_codes: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    source: Path | None = None
    written: dict = field(default_factory=dict)

    @property
    def metrics(self) -> dict:
        """What ``metrics.json`` holds: one filter's metrics, or with ``compare`` the
        consensus run's with the separate run's under ``"separate"``."""
        if len(self.by_mode) == 1:
            return next(iter(self.by_mode.values()))
        return {**self.by_mode["consensus"], "separate": self.by_mode["separate"]}

    @property
    def exit_status(self) -> int:
        """0 when every robot finished; 2 when one stopped on a configuration error; else 1."""
        codes = set(self.exit_codes.values())
        if codes <= {0}:
            return 0
        return 2 if 2 in codes else 1


def _dataset(dataset):
    from teamslam.datasets import load_dataset

    return load_dataset(dataset) if isinstance(dataset, str | os.PathLike) else dataset


def run(
    dataset,
    mode: str = "consensus",
    graph: str = "complete",
    loss: float = 0.0,
    seed: int = 0,
    settings=None,
    out: str | Path | None = None,
    report: bool = True,
    mcap: str | Path | bool | None = None,
    processes: bool = False,
    base_port: int = 17400,
    secure: bool = False,
    progress: bool | None = None,
    source: str | Path | None = None,
    association: str | None = None,
    overwrite: bool = False,
) -> Run:
    """Run the filter over a team dataset: what ``teamslam run`` computes.

    Parameters
    ----------
    dataset
        A :class:`~teamslam.datasets.model.TeamDataset` or its directory (a directory is
        needed with ``processes``).
    mode
        One of :data:`MODES`.
    graph
        Communication graph kind (:data:`teamslam.graph.GRAPH_KINDS`).
    loss
        Per-frame link loss rate (injected message loss with ``processes``).
    seed
        Seed of the link loss and of a random graph.
    settings
        An :class:`~teamslam.msckf.settings.sources.EffectiveConfig`
        (:func:`~teamslam.msckf.configure.build_settings`), or flags for it
        (``{"group.name": value}`` or ``["group.name=value", …]``), or ``None`` (the
        dataset's sensor model; a calibration where it lacks noise levels).
    out
        Run directory to write (:func:`write_run`); also where the frames done go when a
        filter fails.
    report, mcap
        With ``out``: write ``report.html``; write MCAP (``True``: ``out/run.mcap``).
    processes
        One process per robot over Zenoh on loopback (consensus only; needs ``out``).
    base_port, secure
        With ``processes``: the first TCP port; mutual TLS with throw-away certificates.
    progress
        Show a progress bar (default: when standard error is a terminal).
    source
        The directory of a ``dataset`` given loaded (what ``processes`` need).
    association
        Which objects of two robots are the same: ``oracle`` (equal ids; only where the
        dataset's ids are global) or ``own`` (each link finds its correspondences,
        :mod:`teamslam.association`); ``None``: the ``association.mode`` setting (default ``oracle``
        with global ids, ``own`` with per-robot ids).
    overwrite
        Replace an earlier run at ``out`` (entirely); without it an earlier run is refused.

    Raises
    ------
    InputError
        A wrong argument or setting, or an ``out`` that cannot take the run (exit status 2),
        found before anything runs (``out`` before any data is read).
    EstimationError
        A filter failed (naming robot and frame); with ``out`` what was computed is written
        first.
    """
    from teamslam.graph import make
    from teamslam.msckf.configure import build_settings
    from teamslam.msckf.settings.sources import EffectiveConfig

    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if mcap and out is None:
        raise InputError("MCAP output needs a run directory (out)")
    if secure and not processes:
        raise InputError("secure needs processes (robots as processes on loopback)")
    if processes and (out is None or mode != "consensus"):
        raise InputError("processes need a run directory (out) and run consensus only")
    require_extras(processes=processes, secure=secure, mcap=bool(mcap))
    path = dataset if isinstance(dataset, str | os.PathLike) else source
    if processes and path is None:
        raise InputError("processes need the dataset's directory, not a dataset object")
    stage = None
    if out is not None:  # before any data is read
        from teamslam.eval.outputs import stage_run_directory

        stage = stage_run_directory(out, overwrite)
    try:
        dataset = _dataset(dataset)
        effective = (
            settings
            if isinstance(settings, EffectiveConfig)
            else build_settings(dataset, flags=settings)
        )
        if association is not None:
            effective = with_association(effective, dataset, association)
        comm = make(graph, dataset.n_robots, seed=seed)
        if processes:
            result = _run_processes(
                path, dataset, effective, comm, loss, stage, base_port, secure, progress
            )
            result.source = Path(path)
            return result
        source = None if path is None else Path(path)
        result = Run(dataset, graph=comm.name, loss=loss, source=source)
        for name in MODES[mode]:
            try:
                result.results[name] = _run_one(
                    name, dataset, effective, comm, loss, seed, progress
                )
            except EstimationError as exc:
                if stage is not None:
                    _write_partial(stage, result, exc, MODES[mode])
                raise
            result.by_mode[name] = _metrics(dataset, result.results[name], effective)
        if stage is not None:
            _write_run_into(stage, result, report=report, mcap=mcap)
        return result
    finally:
        if stage is not None:
            stage.discard()  # nothing left behind unless moved into place


def require_extras(processes=False, secure=False, mcap=False, ros2=False, foxglove=False) -> None:
    """Check that the optional extras a workflow needs are installed, before it starts.

    Raises
    ------
    teamslam._optional.MissingExtra
        An :class:`InputError` naming the feature, the extra and how to install it.
    """
    if processes:
        require("zenoh", "network", "running robots as processes")
    if secure:
        require("cryptography", "network", "a secured team")
    if mcap:
        require("rosbags", "ros2", "MCAP output")
    if ros2:
        require("rosbags", "ros2", "publishing ROS 2 topics")
        require("xxhash", "ros2", "publishing ROS 2 topics")
    if foxglove:
        from teamslam.viz.foxglove import WHAT

        require("foxglove", "foxglove", WHAT)


def with_association(effective, dataset, association: str):
    """``effective`` with ``association.mode`` (``oracle`` | ``own``) on every robot.

    Raises
    ------
    InputError
        An unknown kind, or ``oracle`` on a dataset whose object ids are not team-wide.
    """
    from dataclasses import replace

    if association not in ("oracle", "own"):
        raise InputError(f"association must be oracle or own, not {association!r}")
    if association == "oracle" and dataset.object_id_scope != "global":
        raise InputError(
            f"association oracle needs team-wide object ids; this dataset's object ids are "
            f"{dataset.object_id_scope!r} (use own)"
        )
    sources = {**effective.sources, "association.mode": "flag"}
    change = {"association.mode": association}
    return replace(
        effective,
        config=effective.config.with_(change),
        robots=[c.with_(change) for c in effective.robots],
        sources=sources,
    )


def _run_one(name, dataset, effective, graph, loss, seed, progress):
    from teamslam.msckf.team import run_team

    if name == "centralised":
        from teamslam.msckf.centralised import run_centralised

        return run_centralised(dataset, effective.robots, progress=progress)
    return run_team(
        dataset, effective.robots, graph, name == "consensus", loss, seed, progress=progress
    )


def _metrics(dataset, result, effective) -> dict:
    from teamslam.eval.metrics import team_metrics

    return {**team_metrics(dataset, result), **effective.to_json()}


def _write_partial(stage, run: Run, exc: EstimationError, names) -> None:
    """The frames done of runs that stopped early, moved into place with ``run.json``
    (``complete: false``)."""
    from teamslam.eval.outputs import write_partial_outputs
    from teamslam.msckf.team import PartialRunError

    results = dict(run.results)
    if isinstance(exc, PartialRunError):
        results[next(n for n in names if n not in run.results)] = exc.result
    write_partial_outputs(stage.path, run.dataset, results, list(names))
    _write_run_file(stage.path, run, list(results), complete=False)
    stage.commit()


def _write_run_file(directory: Path, run: Run, modes: list[str], complete: bool) -> None:
    """``run.json``, the last file of a run directory: what ran, and whether it finished."""
    from teamslam.eval.outputs import RUN_FILE, write_json

    write_json(
        directory / RUN_FILE,
        {
            "dataset": None if run.dataset is None else run.dataset.name,
            "dataset_path": None if run.source is None else str(run.source),
            "modes": modes,
            "graph": run.graph,
            "loss": run.loss,
            "complete": complete,
        },
    )


def write_run(
    run: Run,
    directory: str | Path,
    report: bool = True,
    mcap: str | Path | bool | None = None,
    overwrite: bool = False,
) -> dict:
    """Write a run directory: ``metrics.json``, per filter TUM trajectories, ``estimates.npz``
    and result files, the figures, MCAP and ``report.html`` if asked, and last ``run.json``;
    whole or not at all (staged beside ``directory``, moved into place at the end).

    Returns ``{"directory", "mcap", "report"}`` (also kept as ``run.written``).

    Parameters
    ----------
    overwrite
        Replace an earlier run at ``directory`` (entirely); without it one is refused.

    Raises
    ------
    InputError
        ``directory`` is a file, a non-empty directory that is no run, an earlier run without
        ``overwrite``, or cannot be written (named), found before anything is written.
    OutputError
        Something cannot be written (named).
    """
    from teamslam.eval.outputs import stage_run_directory

    stage = stage_run_directory(directory, overwrite)
    try:
        return _write_run_into(stage, run, report, mcap)
    finally:
        stage.discard()


def _write_run_into(stage, run: Run, report: bool, mcap) -> dict:
    """Write ``run`` into the staging folder ``stage`` (``run.json`` last), move it into place."""
    from teamslam.eval.outputs import write_team_outputs

    work, out = stage.path, stage.target
    write_team_outputs(work, run.dataset, run.results, run.metrics)
    written: dict[str, Any] = {"directory": out, "mcap": None, "report": None}
    if mcap:
        target = work / "run.mcap" if mcap is True or mcap == "" else Path(mcap)
        inside = _inside(target, out)
        if inside is not None:  # a file of the run directory: staged with it
            target = work / inside
        with _writing(target):
            from teamslam.ros2.mcap_export import export_mcap

            summary = export_mcap(work, target, writing=True)
        if inside is not None or target.is_relative_to(work):
            summary["path"] = str(out / target.relative_to(work))
        written["mcap"] = summary
    if report:
        from teamslam.eval.report import write_run_report

        path = write_run_report(work, run.dataset, run.results, final=out)
        written["report"] = out / path.relative_to(work)
    _write_run_file(work, run, list(run.results), complete=True)
    stage.commit()
    run.written = written
    return written


def _inside(path: Path, directory: Path) -> Path | None:
    """``path`` relative to ``directory`` when it lies in it, else ``None``."""
    try:
        return path.resolve().relative_to(directory.resolve())
    except ValueError:
        return None


def _writing(path: Path):
    from teamslam.eval.outputs import writing

    return writing(path)


def load_run(directory: str | Path, dataset=None) -> Run:
    """The :class:`Run` :func:`write_run` wrote (``dataset``: the team dataset, if at hand).

    Raises
    ------
    InputError
        Not a run directory (no ``run.json``: never a run, or its write did not finish), a run
        that stopped early (no metrics), or a file in it cannot be read (named).
    """
    from teamslam.eval.runs import require_run_file
    from teamslam.msckf.team import load_result

    out = Path(directory)
    meta_path = require_run_file(out)
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{meta_path}: cannot read ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("modes"), list):
        raise InputError(f"{meta_path}: not a run description (no list of modes)")
    if meta.get("complete") is False:
        raise InputError(
            f"{out}: the run stopped early ({meta_path.name}: complete false); it holds the "
            "frames done (TUM trajectories, result files), no metrics"
        )
    try:
        metrics = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{out / 'metrics.json'}: cannot read ({exc})") from None
    names = meta["modes"]
    results = {n: load_result(out if len(names) == 1 else out / n) for n in names}
    if len(names) == 1:
        by_mode = {names[0]: metrics}
    else:
        by_mode = {
            "separate": metrics["separate"],
            "consensus": {k: v for k, v in metrics.items() if k != "separate"},
        }
    source = meta.get("dataset_path")
    return Run(
        None if dataset is None else _dataset(dataset),
        results,
        by_mode,
        meta.get("graph", ""),
        meta.get("loss", 0.0),
        source=None if source is None else Path(source),
        written={"directory": out},
    )


# ---------------------------------------------------------------------- processes
def _run_processes(
    path, dataset, effective, graph, loss, stage, base_port, secure, progress=None
) -> Run:
    """Write a loopback team file into the staging folder ``stage``, launch it, gather."""
    from teamslam.runtime.team_file import write_team_file

    out = stage.path
    name = f"run-{os.getpid()}"
    settings = {
        "base_port": base_port,
        "message_loss": loss,
        "settings": effective.config.to_json(),
    }
    if not secure:
        team_path = write_team_file(out / "team.yaml", name, path, graph.adjacency, **settings)
        return _launch_into(stage, team_path, effective, progress)
    from teamslam.runtime.security import SecuritySection, make_team_certificates

    keys = out / "certs"
    robots = {i: (f"robot-{i}", "127.0.0.1") for i in range(dataset.n_robots)}
    written = make_team_certificates(name, robots, keys, days=1, reuse_ca=False)
    try:
        security = SecuritySection(written.ca_certificate, written.robots)
        team_path = write_team_file(
            out / "team.yaml", name, path, graph.adjacency, security=security, **settings
        )
        result = _launch_into(stage, team_path, effective, progress, keys)
        result.notes.insert(
            0,
            "secured team: mutual TLS, access control; throw-away certificates "
            f"(in {stage.target / keys.name} while it ran)",
        )
        return result
    finally:
        shutil.rmtree(keys, ignore_errors=True)


def validate_team(team) -> None:
    """Every robot's settings as its process will resolve them, without calibrating.

    Raises
    ------
    InputError
        The first robot whose dataset or settings are wrong (named).
    """
    from teamslam.runtime.agent_process import robot_setup

    for r in team.robots:
        robot_setup(team, r.id, calibrate="never")


def launch(
    team_path: str | Path,
    out: str | Path,
    settings=None,
    progress=None,
    overwrite: bool = False,
    foxglove: tuple[str, int] | None = None,
) -> Run:
    """Run every robot of a team file as its own process; gather their results.

    ``out`` is checked first and written whole or not at all (as :func:`write_run`: robots
    write into a staging folder beside it, moved into place when they have ended, with
    ``run.json`` last). The settings are checked for every robot before anything starts.
    Metrics cover the robots that finished (on the team's dataset); ``exit_codes`` says how
    each process ended and :attr:`Run.exit_status` sums it up.

    Parameters
    ----------
    settings
        The :class:`~teamslam.msckf.settings.sources.EffectiveConfig` to report with the metrics.
    overwrite
        Replace an earlier run at ``out`` (entirely); without it one is refused.
    foxglove
        ``(host, base port)``: robot ``i`` serves its estimates over the Foxglove WebSocket
        protocol on ``base port + i`` (``teamslam agent --foxglove``); base port 0: each robot
        on a free port of its own (its log says which).

    Raises
    ------
    InputError
        ``out`` cannot take the run (see :func:`write_run`), a wrong team file or setting, a
        Foxglove base port whose robots' ports go past 65535.
    """
    from teamslam.eval.outputs import stage_run_directory

    stage = stage_run_directory(out, overwrite)
    try:
        return _launch_into(stage, Path(team_path), settings, progress, foxglove=foxglove)
    finally:
        stage.discard()


def foxglove_ports(robots: list[int], host: str, base_port: int) -> dict[int, str]:
    """Each robot's ``HOST:PORT`` of ``team launch --foxglove``: robot ``i`` on ``base_port +
    i`` (base 0: a free port each); a port past 65535 is an InputError."""
    if base_port and base_port + max(robots, default=0) > 65535:
        raise InputError(
            f"--foxglove {base_port}: robot {max(robots)} would be on port "
            f"{base_port + max(robots)}, past 65535"
        )
    where = f"[{host}]" if ":" in host else host
    return {r: f"{where}:{base_port + r if base_port else 0}" for r in robots}


def _launch_into(
    stage,
    team_path: Path,
    settings,
    progress,
    keep_out: Path | None = None,
    foxglove: tuple[str, int] | None = None,
) -> Run:
    """Launch the team file's robots into the staging folder ``stage``, gather, write the run
    (``run.json`` last; ``complete`` when every robot finished) and move it into place;
    ``keep_out``: a folder of ``stage`` not to move (secrets); ``foxglove``: ``(host, base
    port)`` of the robots' Foxglove views."""
    from teamslam.eval.outputs import write_team_outputs
    from teamslam.runtime.launch import exit_summary, gather, launch_team
    from teamslam.runtime.team_file import load_team_file

    work, out = stage.path, stage.target
    team = load_team_file(team_path)
    require_extras(processes=True, secure=team.security is not None, ros2=team.ros2 is not None)
    validate_team(team)
    extra_args = None
    if foxglove is not None:
        require_extras(foxglove=True)
        ports = foxglove_ports([r.id for r in team.robots], *foxglove)
        extra_args = {r: ["--foxglove", where] for r, where in ports.items()}
    codes = launch_team(team, team_path, work, progress=progress, extra_args=extra_args)
    if keep_out is not None:
        shutil.rmtree(keep_out, ignore_errors=True)
    finished = [r for r, c in sorted(codes.items()) if c == 0]
    result = Run(None, graph=f"team file {team.team}", loss=team.message_loss, exit_codes=codes)
    result.written = {"directory": out}
    if len(finished) < team.n:
        result.warnings.append(f"{exit_summary(codes)} (see {out}/robot_N.log)")
    if not finished or team.dataset is None or any(r.dataset for r in team.robots):
        if finished:
            result.notes.append(f"robots ran on their own datasets; per-robot results are in {out}")
        _write_run_file(work, result, [], complete=len(finished) == team.n)
        stage.commit()
        return result
    dataset = _dataset(team.dataset)
    result.source = Path(team.dataset)
    gathered = gather(team, work, finished)
    if len(finished) < team.n:
        result.notes.append(
            f"robots {', '.join(str(r) for r in finished)} finished; metrics cover them only"
        )
        dataset = dataset.subset(finished)
    result.notes.extend(
        f"robot {s['robot']} lost neighbour(s) {s['lost_neighbours']}"
        for s in gathered.extra["per_robot"]
        if s["lost_neighbours"]
    )
    metrics = _metrics_of_team(dataset, gathered, settings)
    result.dataset = dataset
    result.results = {"consensus": gathered}
    result.by_mode = {"consensus": metrics}
    write_team_outputs(work, dataset, result.results, result.metrics)
    from teamslam.eval.report import write_run_report

    report = write_run_report(work, dataset, result.results, final=out)
    result.written = {"directory": out, "report": out / report.relative_to(work)}
    _write_run_file(work, result, ["consensus"], complete=len(finished) == team.n)
    stage.commit()
    return result


def _metrics_of_team(dataset, result, settings) -> dict:
    from teamslam.eval.metrics import team_metrics

    metrics = team_metrics(dataset, result)
    metrics["transport"] = result.extra["per_robot"]
    if settings is not None:
        metrics.update(settings.to_json())
    return metrics


def run_robot(
    team_path: str | Path,
    robot: int,
    out: str | Path,
    resume: bool = False,
    ros2: bool = False,
    ros2_options: dict | None = None,
    live: dict | None = None,
    foxglove: tuple[str, int] | None = None,
) -> dict:
    """Run one robot of a team file in this process (``teamslam agent``); its summary.

    Parameters
    ----------
    ros2
        Publish ROS 2 topics over rmw_zenoh (also done when the team file has a ``ros2``
        section).
    ros2_options
        Overrides of the team file's ``ros2`` section (``domain_id``, ``connect``, ``listen``,
        ``period``; ``None`` values are ignored).
    live
        Run on live topics (``teamslam agent --live``,
        :func:`~teamslam.live.run_live`): ``flags`` (overrides of the team file's
        ``ros2.inputs``), ``frames``, ``idle_timeout_s``, ``budget_ms``.
    foxglove
        ``(host, port)``: serve the robot's estimates there over the Foxglove WebSocket
        protocol while it runs (:class:`~teamslam.viz.foxglove.FoxgloveView`, the
        ``foxglove`` extra; over a dataset: pose, path, map and ``/tf``).

    Raises
    ------
    InputError
        A wrong robot id, credentials or settings (exit status 2), before anything runs.
    EstimationError
        The filter failed; the frames done are written first.
    """
    from teamslam.runtime.agent_process import run_agent
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(team_path)
    if not 0 <= robot < team.n:
        raise InputError(f"robot must lie in 0..{team.n - 1}, got {robot}")
    require_extras(
        processes=True,
        secure=team.security is not None,
        ros2=ros2 or team.ros2 is not None,
        foxglove=foxglove is not None,
    )
    if team.security is not None:
        from teamslam.runtime.security import check_credentials

        check_credentials(team.security, robot)  # one line naming a missing/unreadable key
    if live is not None:
        from teamslam.live import run_live

        require_extras(ros2=True)
        return run_live(
            team,
            robot,
            Path(out),
            live.get("flags"),
            resume=resume,
            frames=live.get("frames"),
            idle_timeout_s=live.get("idle_timeout_s", 5.0),
            budget_ms=live.get("budget_ms"),
            foxglove=foxglove,
            ros2_options={k: v for k, v in (ros2_options or {}).items() if k != "period"},
        )
    publishers = _Publishers()
    try:
        if ros2 or team.ros2 is not None:
            publishers.add(_ros2_publisher(team, robot, ros2_options or {}))
        if foxglove is not None:
            publishers.add(_foxglove_view(team, robot, foxglove, ros2_options or {}))
        return run_agent(team, robot, Path(out), resume=resume, publisher=publishers.one_or_none())
    finally:
        publishers.close()


class _Publishers:
    """The publishers of a robot over a dataset, fed as one (``publish(t, poses, state)``)."""

    def __init__(self) -> None:
        self.publishers: list = []

    def add(self, publisher) -> None:
        self.publishers.append(publisher)

    def one_or_none(self):
        return self if self.publishers else None

    def publish(self, t: int, poses, state) -> None:
        for publisher in self.publishers:
            publisher.publish(t, poses, state)

    def close(self) -> None:
        for publisher in self.publishers:
            publisher.close()


def _frame_stamps(team, robot: int, period: float | None):
    from teamslam.datasets import load_dataset
    from teamslam.eval.estimates import stamps_ns

    dataset_path, index = team.dataset_of(robot)
    sequence = load_dataset(dataset_path).robots[index]
    return stamps_ns(sequence.timestamps, sequence.frames, period)


def _foxglove_view(team, robot: int, address: tuple[str, int], options: dict):
    from teamslam.ros2.rmw_zenoh import ros2_settings
    from teamslam.viz.foxglove import FoxgloveView

    section = {k: v for k, v in (team.ros2 or {}).items() if k != "inputs"}
    period = ros2_settings(section, **options)["period"]
    view = FoxgloveView(robot, *address, stamps_ns=_frame_stamps(team, robot, period))
    print(f"robot {robot}: Foxglove view at {view.url}", file=sys.stderr, flush=True)
    return view


def _ros2_publisher(team, robot: int, options: dict):
    from teamslam.ros2.rmw_zenoh import Ros2Publisher, ros2_settings

    section = {k: v for k, v in (team.ros2 or {}).items() if k != "inputs"}  # live robots'
    settings = ros2_settings(section, **options)
    return Ros2Publisher(
        robot=robot,
        stamps_ns=_frame_stamps(team, robot, settings["period"]),
        domain_id=settings["domain_id"],
        connect=settings["connect"],
        listen=settings["listen"],
        path_every=settings["path_every"],
        objects_every=settings["objects_every"],
        wait_s=settings["wait_s"],
    )


# ---------------------------------------------------------------------- other workflows
def calibrate(
    dataset,
    settings=None,
    config_file: str | Path | None = None,
    frames: int | None = None,
    odometry_per_axis: bool = False,
    write: bool = False,
    source: str | Path | None = None,
):
    """Estimate a dataset's sensor model from its data (no ground truth).

    Every setting comes from the usual layers, but the estimated noise levels start from the
    camera-scaled defaults, not from what the dataset says. With ``write`` the result becomes
    the dataset's sensor model (what calibration does not estimate is kept); the dataset must
    then be given as its directory (or ``source``, the directory of a loaded one).

    Returns
    -------
    CalibrationResult
        :class:`~teamslam.msckf.calibration.CalibrationResult`.
    """
    from teamslam.datasets import save_dataset
    from teamslam.msckf.calibration import calibrate as run_calibration
    from teamslam.msckf.configure import build_settings
    from teamslam.msckf.settings.sources import calibration_start

    path = dataset if isinstance(dataset, str | os.PathLike) else source
    dataset = _dataset(dataset)
    effective = build_settings(dataset, config_file, settings, calibrate="never")
    start = calibration_start(dataset, effective.config)
    result = run_calibration(dataset, start, frames=frames, odometry_per_axis=odometry_per_axis)
    if write:
        if path is None:
            raise InputError("write needs the dataset's directory, not a dataset object")
        model = result.sensor_model
        if dataset.sensor_model is not None:  # keep what calibration does not estimate
            model = replace(model, team=dataset.sensor_model.team.merged(model.team))
        save_dataset(replace(dataset, sensor_model=model), path)
    return result


def evaluate(runs: Sequence[str | Path], references=None, out: str | Path | None = None, **options):
    """APE/RPE of runs (run directories, trajectory files) against ground truth.

    Parameters
    ----------
    runs
        What ``teamslam eval`` takes: run directories, trajectory files, files joined by
        commas.
    references
        Per robot reference trajectories (default: what each run recorded).
    out
        Directory for ``eval.json`` and the figures.
    options
        ``align``, ``scope``, ``rpe_delta``, ``rpe_unit``, ``max_time_diff``
        (:func:`teamslam.eval.report.evaluate_runs`).

    Returns
    -------
    dict
        ``{"runs": {name: statistics}}`` (what ``eval.json`` holds) and, not written,
        ``names``, ``statistics`` and ``evaluations``.
    """
    from teamslam.eval.outputs import write_json, writing
    from teamslam.eval.report import evaluate_runs, unique_names
    from teamslam.eval.runs import load_runs

    loaded = [r for spec in runs for r in load_runs(spec)]
    evaluations = evaluate_runs(loaded, references, **options)
    names = unique_names(loaded)
    stats = [ev.statistics() for ev in evaluations]
    payload = {"runs": dict(zip(names, stats, strict=True))}
    if out is not None:
        from teamslam.eval.figures import (
            ape_over_time_figure,
            ape_path_figure,
            save_figure,
            trajectories_figure,
        )

        out = Path(out)
        write_json(out / "eval.json", payload)
        with writing(out):
            save_figure(trajectories_figure(names, evaluations), out / "trajectories.png")
            save_figure(ape_over_time_figure(names, evaluations), out / "ape_over_time.png")
            save_figure(ape_path_figure(names, evaluations), out / "ape_path.png")
    return {**payload, "names": names, "statistics": stats, "evaluations": evaluations}


def export(result_dir: str | Path, out: str | Path, path_messages: int = 100) -> dict:
    """Write a run directory as one MCAP file with ROS 2 schemas; a summary of what was
    written (``path``, ``messages``, ``topics``, ``bytes``, ``seconds``)."""
    from teamslam.eval.outputs import writing
    from teamslam.ros2.mcap_export import export_mcap

    require_extras(mcap=True)
    with writing(Path(out)):
        return export_mcap(result_dir, out, path_messages=path_messages)


# ---------------------------------------------------------------------- planar FEJ-EKF
def fej_environment(
    env: int = 1, features: int = 20, files: Sequence[str | Path] = (), layout: int = 0
):
    """The planar environment of ``teamslam fej table``: generated (``env``, ``features``,
    ``layout``: 0 is the tables' layout, others new environments of the same kind), or from
    files — one teamslam JSON file, or the published MATLAB pair (waypoints file and features
    file; the noise levels of environment ``env``)."""
    from teamslam.ekf2d.environments import environment, load_environment, load_matlab_environment

    if not files:
        return environment(env, features, layout)
    if layout:
        raise InputError("a layout applies to generated environments only, not to files")
    paths = [Path(f) for f in files]
    for f in paths:
        if not f.is_file():
            raise InputError(f"environment file {f} does not exist")
    if len(paths) == 1 and paths[0].suffix == ".json":
        return load_environment(paths[0])
    base = environment(env, 20)  # the chosen environment's noise levels
    return load_matlab_environment(
        paths,
        odometry_std=base.odometry_std,
        observation_std=base.observation_std,
        name="+".join(f.stem for f in paths),
    )


def fej_table(environment, runs: int = 100, seed: int = 0, workers=None, out=None, scheduler=None):
    """Monte Carlo NEES/RMSE of the standard, first-estimate and ideal planar EKFs; with
    ``out`` also ``table.json``, ``nees_rmse.png`` and ``sigma_bounds.png``. With
    ``scheduler`` (a Dask scheduler's address, the ``cluster`` extra) each run is a task there
    instead of in one of ``workers`` processes; the table is the same, bit for bit.

    Returns
    -------
    MonteCarloResult
        :class:`~teamslam.ekf2d.experiments.MonteCarloResult` (``table``: per filter).
    """
    from teamslam.ekf2d.experiments import monte_carlo
    from teamslam.eval.outputs import write_json, writing

    result = monte_carlo(environment, runs=runs, seed=seed, workers=workers, scheduler=scheduler)
    if out is not None:
        from teamslam.eval.plots import plot_monte_carlo, plot_sigma_bounds

        out = Path(out)
        write_json(
            out / "table.json",
            {
                "environment": environment.name,
                "runs": runs,
                "steps": result.steps,
                "filters": result.table,
            },
        )
        with writing(out):
            plot_monte_carlo(result, out / "nees_rmse.png")
            plot_sigma_bounds(result, out / "sigma_bounds.png")
    return result


VICTORIA_PARK_LABELS = {"std": "Std-EKF", "fej": "FEJ-EKF"}


def victoria_park(data: str | Path, per_measurement_noise: bool = False, out=None) -> dict:
    """The two-robot split of Victoria Park with the standard and the first-estimate EKF,
    against the reference batch solution; with ``out`` also ``metrics.json`` and the map.

    Returns
    -------
    dict
        Per filter (``std``, ``fej``): ``position_rmse_m`` and ``heading_rmse_rad`` per robot,
        ``feature_rmse_m``, ``seconds`` — what ``metrics.json`` holds.
    """
    from teamslam.datasets.victoria_park import load_victoria_park
    from teamslam.ekf2d.victoria_park import run_victoria_park
    from teamslam.eval.outputs import write_json, writing

    split = load_victoria_park(data)
    results = {p: run_victoria_park(split, p, per_measurement_noise) for p in ("std", "fej")}
    summary = {
        name: {
            "position_rmse_m": r.position_rmse.tolist(),
            "heading_rmse_rad": r.heading_rmse.tolist(),
            "feature_rmse_m": r.feature_rmse,
            "seconds": r.seconds,
        }
        for name, r in results.items()
    }
    if out is not None:
        from teamslam.eval.plots import plot_planar_map

        out = Path(out)
        write_json(out / "metrics.json", summary)
        trajectories = {"reference (Gauss–Newton)": [r.reference_poses for r in split.robots]}
        features = {"reference (Gauss–Newton)": split.reference_features}
        for name, r in results.items():
            label = VICTORIA_PARK_LABELS[name]
            trajectories[label] = [r.poses[:, i] for i in range(r.poses.shape[1])]
            features[label] = r.features
        with writing(out):
            plot_planar_map(trajectories, features, out / "victoria_park.png", "Victoria Park")
    return summary


def victoria_park_table(summary: dict) -> str:
    """The table ``teamslam fej victoria-park`` prints of :func:`victoria_park`'s summary."""
    head = (
        f"{'EKF':<6} {'R1 pos RMSE':>12} {'R2 pos RMSE':>12} {'R1 head':>9} {'R2 head':>9} "
        f"{'feat RMSE':>10} {'time [s]':>9}"
    )
    lines = [
        "Victoria Park, two-robot split (poses 719–3264 and 3265–5810), errors against the",
        "reference batch Gauss–Newton solution:",
        head,
        "-" * len(head),
    ]
    for name, r in summary.items():
        pos, heading = r["position_rmse_m"], r["heading_rmse_rad"]
        lines.append(
            f"{name:<6} {pos[0]:12.3f} {pos[1]:12.3f} {heading[0]:9.4f} {heading[1]:9.4f} "
            f"{r['feature_rmse_m']:10.3f} {r['seconds']:9.2f}"
        )
    return "\n".join(lines)


def simulate_images(
    out: str | Path,
    robots: int = 3,
    steps: int = 200,
    seed: int = 0,
    bag: bool = True,
    progress: bool = True,
    detector: DetectorConfig | None = None,
    **overrides,
) -> RenderedTeam:
    """Render a team as image folders (:func:`teamslam.sim.render.render_team`) and, with
    ``bag``, also as a ROS 2 bag ``out/images.mcap``
    (:func:`teamslam.ros2.image_bags.images_to_bag`, topics ``/robot_k/{left,right}/image_raw``,
    ``…/camera_info``, ``/robot_k/odom``, ``/robot_k/ground_truth``, and with a detector
    ``/robot_k/detections``, its left-image boxes as ``vision_msgs/msg/Detection2DArray``).

    Parameters
    ----------
    out
        Output directory.
    robots, steps, seed
        Team size, motion steps per robot, seed.
    bag
        Also write the bag.
    progress
        Show progress bars.
    detector
        With objects (``objects="shapes"``), the simulated detector whose boxes are written
        per robot (:func:`~teamslam.sim.render.render_team`).
    **overrides
        Any other :class:`~teamslam.sim.render.RenderConfig` field.
    """
    from teamslam.datasets.images import rendered_team_inputs
    from teamslam.ros2.image_bags import images_to_bag
    from teamslam.sim.render import RenderConfig, render_team

    require("cv2", "images", "rendering images")
    if bag:
        require("rosbags", "ros2", "the ROS 2 bag of rendered images")
    config = RenderConfig(robots=robots, steps=steps, seed=seed, **overrides)
    team = render_team(config, out, progress=progress, detector=detector)
    if bag:
        inputs = rendered_team_inputs(out)
        images_to_bag(
            inputs["left_dirs"],
            inputs["right_dirs"],
            inputs["camera"],
            inputs["timestamps"],
            Path(out) / "images.mcap",
            odometry=inputs["odometry"],
            ground_truth=inputs["ground_truth"],
            robot_names=inputs["robot_names"],
            progress=progress,
            detections=inputs.get("detections"),
        )
    return team
